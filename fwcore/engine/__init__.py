"""The engine: waveforms in, echoes out; it knows no file.

    config.py       the method's settings (enums, presets, the optimizer table, KernelParams, CLI metadata)
    decompose.py    orchestration: decompose_batch(batch, config, pulse)
    preprocess.py   baseline, noise, smoothing, the initial guess (peaks, inflections)
    filter.py       the low-pass filters applied before fitting
    model.py        the echo formula and its Jacobian, written once
    noise_model.py  the per-sample noise variance the fit weighs by
    bounds.py       each parameter's lower and upper bound
    selection.py    model selection: how many echoes a waveform keeps
    records.py      the result dtype, declared once
    optimizers/     the catalogue of fitting methods (local, evolutionary, deconvolution)

Nothing is imported here: import the module you need.
"""
