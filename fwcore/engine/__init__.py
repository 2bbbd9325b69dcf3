"""The engine: waveforms in, echoes out; it knows no file.

    config.py       the method's settings (enums, presets, the optimizer table, KernelParams, CLI metadata)
    decompose.py    orchestration: decompose_batch(batch, config, pulse)
    smoothing.py    denoising, the noise sigma and the baseline
    estimate.py     the initial echoes (peaks, inflections), peeled off one by one
    filter.py       the spurious-echo filter applied after fitting: the echoes kept, and why the others are not
    model.py        the echo formula and its Jacobian, written once; EchoShape, the tabulated echo it evaluates
    noise_model.py  the per-sample noise variance the fit weighs by
    bounds.py       each parameter's lower and upper bound
    selection.py    model selection: how many echoes a waveform keeps
    records.py      the result dtype, declared once
    optimizers/     the catalogue of fitting methods (local, evolutionary, deconvolution)

Nothing is imported here: import the module you need.
"""
