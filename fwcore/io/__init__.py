"""fwcore.io: full-waveform LAS/LAZ reading (.wdp, internal, .wdz), geolocation and writing."""

from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.geolocate import geolocate
from fwcore.io.reader import (PointRange, WaveformFile, WaveformFileError, open_waveform_file,
                              plan_point_ranges, read_pulses)
from fwcore.io.records import PulseBatch

__all__ = ["PointRange", "PulseBatch", "WaveformDescriptor", "WaveformFile", "WaveformFileError", "geolocate",
           "open_waveform_file", "plan_point_ranges", "read_pulses"]
