"""fwcore.io: the full-waveform formats, read and written; never imports the engine.

LAS/LAZ 1.3/1.4 (point formats 4, 5, 9, 10; packets in .wdp, .wdz or internal: `las.py`),
PulseWaves (.pls + .wvs: `pulsewaves.py`) and NEON-layout CSV (`neon.py`), one entry each in
the table of formats (`formats.py`). `plan_point_ranges` and `read_pulses` take either flight-line
format: they look it up there, and both give the same PulseBatch; `info.py` describes files. A file they
cannot read raises one of `errors.py`'s errors, which name the file and the problem.
"""

from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.formats import (FORMATS, Format, InputCrs, InputSummary, crs_wkt, describe_file, format_of,
                               input_crs, input_summary, kind_of, needs_packet_file, open_input, packet_file,
                               plan_point_ranges, read_pulses)
from fwcore.io.geolocate import geolocate
from fwcore.io.errors import WaveformFileError
from fwcore.io.las import WaveformFile, open_waveform_file
from fwcore.io.records import PointRange, PulseBatch, pulse_identity

__all__ = ["FORMATS", "Format", "InputCrs", "InputSummary", "PointRange", "PulseBatch", "WaveformDescriptor",
           "WaveformFile", "WaveformFileError", "crs_wkt", "describe_file", "format_of", "geolocate", "input_crs",
           "input_summary", "kind_of", "needs_packet_file", "open_input", "open_waveform_file", "packet_file",
           "plan_point_ranges", "pulse_identity", "read_pulses"]
