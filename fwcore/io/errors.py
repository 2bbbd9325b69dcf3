"""The errors fwcore.io raises, in one module (as laspy's `errors`). Each is a ValueError whose message names
the file and the problem; a missing file stays a FileNotFoundError."""

from __future__ import annotations

from pathlib import Path


class InputFileError(ValueError):
    """An input fwcore.io cannot read as it was asked to; the message names the file and the problem."""


class WaveformFileError(InputFileError):
    """A file that cannot be read as a flight line of full waveforms (LAS/LAZ or PulseWaves), or a file of
    another kind given where one was wanted."""


class WaveformCsvError(InputFileError):
    """A file that cannot be read as a NEON-layout waveform CSV; the message names the file (and line)."""


class ForeignFileError(InputFileError):
    """A file that is not of its reader's format at all. The reader knows what it wanted, not what the file is:
    fwcore.io.formats, which knows every kind of file, raises it again saying what the file is and which command
    reads it (`detail`: the reader's own reason, such as laspy's error)."""

    def __init__(self, message: str, path: str | Path, wanted: str, detail: str = ""):
        super().__init__(message)
        self.path, self.wanted, self.detail = Path(path), wanted, detail


class ForeignWaveformFileError(ForeignFileError, WaveformFileError):
    """A file given as LAS/LAZ that is no LAS/LAZ file (its first bytes are not LAS's)."""


class ForeignCsvError(ForeignFileError, WaveformCsvError):
    """A file given as a NEON-layout waveform CSV that is no such CSV (its first line is not NEON's header)."""


class PacketError(InputFileError):
    """A packet of one pulse cannot be read: the pulse is rejected, the file goes on."""


class WdzError(PacketError):
    """A compressed packet that cannot be decoded (truncated or not LASzip-coded); its reader adds the file."""
