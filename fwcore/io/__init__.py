"""fwcore.io: the full-waveform formats, read and written; never imports the engine.

LAS/LAZ 1.3/1.4 (point formats 4, 5, 9, 10; packets in .wdp, .wdz or internal) and
PulseWaves (.pls + .wvs). `plan_point_ranges` and `read_pulses` take either: they
dispatch on the file's format, and both give the same PulseBatch.
"""

from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.formats import (InputSummary, crs_wkt, describe_file, input_summary, is_pulsewaves, needs_packet_file,
                               open_input, packet_file, plan_point_ranges, read_pulses)
from fwcore.io.geolocate import geolocate
from fwcore.io.reader import WaveformFile, WaveformFileError, open_waveform_file
from fwcore.io.records import PointRange, PulseBatch, pulse_identity

__all__ = ["InputSummary", "PointRange", "PulseBatch", "WaveformDescriptor", "WaveformFile", "WaveformFileError",
           "crs_wkt", "describe_file", "geolocate", "input_summary", "is_pulsewaves", "needs_packet_file", "open_input",
           "open_waveform_file", "packet_file", "plan_point_ranges", "pulse_identity", "read_pulses"]
