"""Waveform packet descriptors: the VLRs with record ids 100 to 354 (index = record id - 99)."""

from __future__ import annotations

import dataclasses
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

    @property
    def container_bytes(self) -> int:
        """Bytes per stored sample: widths other than 8, 16, 32 are padded to the next of those."""
        return 1 if self.bits_per_sample <= 8 else 2 if self.bits_per_sample <= 16 else 4

    @property
    def packet_bytes(self) -> int:
        return self.n_samples * self.container_bytes

    def ensure_supported(self, source: str, lastools_compressed: bool = False) -> None:
        """Raise with the file's name if we cannot read packets of this descriptor."""
        if not 1 <= self.bits_per_sample <= 32:
            raise ValueError(f"{source}: waveform descriptor {self.index} has {self.bits_per_sample} bits per sample "
                             "(1 to 32 are readable)")
        if self.compression != 0 and not (self.compression == 1 and lastools_compressed):
            raise ValueError(f"{source}: waveform descriptor {self.index} has unknown compression type "
                             f"{self.compression} (only 0, uncompressed, is defined)")
        if self.n_samples <= 0 or self.sample_spacing_ps <= 0:
            raise ValueError(f"{source}: waveform descriptor {self.index} has {self.n_samples} samples at "
                             f"{self.sample_spacing_ps} ps spacing")

    def to_record_data(self) -> bytes:
        return _STRUCT.pack(self.bits_per_sample, self.compression, self.n_samples, int(self.sample_spacing_ps),
                            self.gain, self.offset)

    @classmethod
    def from_record_data(cls, index: int, data: bytes, source: str) -> "WaveformDescriptor":
        if len(data) < _STRUCT.size:
            raise ValueError(f"{source}: waveform descriptor {index} is {len(data)} bytes, expected {_STRUCT.size}")
        bits, compression, n, spacing, gain, offset = _STRUCT.unpack_from(data)
        return cls(index, bits, compression, n, float(spacing), gain, offset)


def read_descriptors(vlrs, source: str, lastools_compressed: bool = False) -> dict[int, WaveformDescriptor]:
    """Descriptors by index from a header's VLRs, each checked."""
    found = {}
    for vlr in vlrs:
        if vlr.user_id.rstrip("\0") == "LASF_Spec" and vlr.record_id in WAVEFORM_RECORD_IDS:
            data = vlr.record_data_bytes() if hasattr(vlr, "record_data_bytes") else vlr.record_data
            descriptor = WaveformDescriptor.from_record_data(vlr.record_id - 99, bytes(data), source)
            descriptor.ensure_supported(source, lastools_compressed)
            found[descriptor.index] = descriptor
    return found
