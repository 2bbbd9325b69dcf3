"""The errors fwcore.io raises, in one module (as laspy's `errors`). Each is a ValueError whose message names
the file and the problem; a missing file stays a FileNotFoundError."""

from __future__ import annotations


class InputFileError(ValueError):
    """An input fwcore.io cannot read as it was asked to; the message names the file and the problem."""


class WaveformFileError(InputFileError):
    """A file that cannot be read as a flight line of full waveforms (LAS/LAZ or PulseWaves), or a file of
    another kind given where one was wanted."""


class WaveformCsvError(InputFileError):
    """A file that cannot be read as a NEON-layout waveform CSV; the message names the file (and line)."""


class PacketError(InputFileError):
    """A packet of one pulse cannot be read: the pulse is rejected, the file goes on."""


class WdzError(PacketError):
    """A compressed packet that cannot be decoded (truncated or not LASzip-coded); its reader adds the file."""
