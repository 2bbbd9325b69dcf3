"""Measuring an instrument: what a file does not record about its system's pulse, measured on its waveforms.

    peak.py      a peak's vertex, its half-height width and crossings, its main lobe, one strong isolated echo
    response.py  SystemResponse: the instrument's response as data, shipped, from a file, or a Gaussian's
    shape.py     echo_shape: the response as the kernels' table of broadened echoes (fwcore.engine.model.EchoShape)
    width.py     the pulse's FWHM: outgoing waveforms, single returns, isolated echoes, a CSV's outgoing pulses
    pulse.py     SystemPulse (a file's pulse, passed to the engine beside the method's settings), PulseOverrides
    measure.py   a file's SystemPulse measured: response, width, shape tolerance, range offset, the `auto` model

Two floors: the data (peak, response, shape, pulse) sits below the engine, which imports it; `measure` and
`width` run the engine on a file's waveforms and sit above it. No module is imported here.
"""
