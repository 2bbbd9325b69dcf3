"""Measuring an instrument: what a file does not record about its system's pulse, measured on its waveforms.

    peak.py      a peak's vertex, its half-height width and crossings, its main lobe, one strong isolated echo
    response.py  SystemResponse: the instrument's response, shipped, from a file, or measured on strong returns
    shape.py     EchoShape: the response as the kernels' table of broadened echoes
    width.py     the pulse's FWHM: outgoing waveforms, single returns, isolated echoes, a CSV's outgoing pulses
    pulse.py     SystemPulse (a file's pulse, passed to the engine beside the method's settings), PulseOverrides
    measure.py   a file's SystemPulse measured: width, response, shape tolerance, range offset, the `auto` model

No module is imported here: `measure` runs the engine, which imports `pulse` and `shape`.
"""
