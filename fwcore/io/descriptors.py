"""Waveform packet descriptors: the VLRs with record ids 100 to 354 (index = record id - 99).

A descriptor we cannot use (RIEGL writes a hundred, most of them empty) does
not stop its file: it carries the reason, and only the pulses that point at
it are rejected with that reason.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import struct

WAVEFORM_RECORD_IDS = range(100, 355)
_STRUCT = struct.Struct("<BBIIdd")  # bits, compression, samples, spacing ps, gain, offset


@dataclasses.dataclass(frozen=True)
class WaveformDescriptor:
    index: int  # 1..255, what a point's wavepacket_index refers to
    bits_per_sample: int
    compression: int  # 0: none (the only type the LAS specification defines); 1: LASzip, as LAStools writes it
    n_samples: int
    sample_spacing_ps: float
    gain: float  # volts = offset + gain * raw sample
    offset: float
    problem: str | None = None  # why its packets cannot be read; None: usable

    @property
    def container_bytes(self) -> int:
        """Bytes per stored sample: widths other than 8, 16, 32 are padded to the next of those."""
        return 1 if self.bits_per_sample <= 8 else 2 if self.bits_per_sample <= 16 else 4

    @property
    def packet_bytes(self) -> int:
        return self.n_samples * self.container_bytes

    def check(self, lastools_compressed: bool = False) -> "WaveformDescriptor":
        """This descriptor with `problem` set if we cannot read packets of it."""
        return dataclasses.replace(self, problem=self._problem(lastools_compressed))

    def _problem(self, lastools_compressed: bool) -> str | None:
        name = f"waveform descriptor {self.index}"
        if not 1 <= self.bits_per_sample <= 32:
            return f"{name} has {self.bits_per_sample} bits per sample (1 to 32 are readable)"
        if self.compression != 0 and not (self.compression == 1 and lastools_compressed):
            return f"{name} has unknown compression type {self.compression} (only 0, uncompressed, is defined)"
        if self.compression == 0 and lastools_compressed:
            return f"{name} says uncompressed but its packet file holds LAStools-compressed packets"
        if self.n_samples <= 0 or self.sample_spacing_ps <= 0:
            return f"{name} has {self.n_samples} samples at {self.sample_spacing_ps} ps spacing"
        if not (math.isfinite(self.gain) and math.isfinite(self.offset)):
            return f"{name} has a non-finite digitizer gain ({self.gain}) or offset ({self.offset})"
        return None

    def to_record_data(self) -> bytes:
        return _STRUCT.pack(self.bits_per_sample, self.compression, self.n_samples, int(self.sample_spacing_ps),
                            self.gain, self.offset)

    @classmethod
    def from_record_data(cls, index: int, data: bytes) -> "WaveformDescriptor":
        if len(data) < _STRUCT.size:
            return cls(index, 0, 0, 0, 0.0, 1.0, 0.0,
                       problem=f"waveform descriptor {index} is {len(data)} bytes, expected {_STRUCT.size}")
        bits, compression, n, spacing, gain, offset = _STRUCT.unpack_from(data)
        return cls(index, bits, compression, n, float(spacing), gain, offset)

    @classmethod
    def from_vlr(cls, vlr) -> "WaveformDescriptor":
        """From laspy's parsed WaveformPacketVlr, or from a raw VLR's bytes when laspy left it raw."""
        index = vlr.record_id - 99
        parsed = getattr(vlr, "parsed_record", None)
        if parsed is None:
            return cls.from_record_data(index, bytes(vlr.record_data))
        return cls(index, parsed.bits_per_sample, parsed.waveform_compression_type, parsed.number_of_samples,
                   float(parsed.temporal_sample_spacing), parsed.digitizer_gain, parsed.digitizer_offset)


def read_descriptors(vlrs, lastools_compressed: bool = False) -> dict[int, WaveformDescriptor]:
    """Every descriptor by index from a header's VLRs, each checked (see WaveformDescriptor.problem)."""
    found = {}
    for vlr in vlrs:
        if vlr.user_id.rstrip("\0") == "LASF_Spec" and vlr.record_id in WAVEFORM_RECORD_IDS:
            try:
                descriptor = WaveformDescriptor.from_vlr(vlr)
            except (ValueError, TypeError):  # laspy could not parse it: a short record
                descriptor = WaveformDescriptor.from_record_data(vlr.record_id - 99, b"")
            found[descriptor.index] = descriptor.check(lastools_compressed) if descriptor.problem is None \
                else descriptor
    return found


def warn_unusable(file_name: str, problems: dict[int, str], used, unit: str) -> None:
    """Once per unusable descriptor that records use (how many of `unit` are rejected), one line for the unusable
    ones none uses; never once per pulse. `problems`: index -> why; `used`: records per descriptor index."""
    log = logging.getLogger("fwl")
    for index, problem in sorted(problems.items()):
        if used[index]:
            log.warning("%s: %s: its %d %s are rejected", file_name, problem, used[index], unit)
    unused = sorted(i for i in problems if not used[i])
    if unused:
        log.warning("%s: %d unusable waveform descriptors are not used by any %s (%s)", file_name, len(unused),
                    unit.split()[0].rstrip("'").rstrip("s"), ranges_text(unused))


def ranges_text(values: list[int]) -> str:
    """1, 2, 3, 5 -> '1-3, 5'."""
    out, start = [], None
    for i, v in enumerate(values):
        if start is None:
            start = v
        if i + 1 == len(values) or values[i + 1] != v + 1:
            out.append(f"{start}" if start == v else f"{start}-{v}")
            start = None
    return ", ".join(out)
