"""Where a file's waveform packets live, and reading one packet's samples.

Packet byte offsets count from the start of the waveform data packet record:
the `.wdp`/`.wdz` file for external storage, the record's header for
internal storage (LAS 1.3's "start of waveform data packet record", LAS
1.4's extended VLR 65535). Files are memory-mapped, so a range of pulses
touches only its own packets' pages.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fwcore.io import wdz
from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.errors import PacketError, WdzError

EVLR_HEADER_BYTES = 60
LASTOOLS_SIGNATURE = b"LAStools waveform "


@dataclasses.dataclass(frozen=True)
class PacketStore:
    path: Path  # the file that holds the packets
    record_start: int  # byte of that file where offsets count from
    compressed: bool  # LAStools .wdz

    def open(self) -> np.ndarray:
        return np.memmap(self.path, dtype=np.uint8, mode="r")

    def read(self, data: np.ndarray, descriptor: WaveformDescriptor, offset: int, size: int) -> np.ndarray:
        """Samples of the packet at `offset` (from the record start) as float64 digitizer values."""
        samples, problems = self.read_many(data, descriptor, np.array([offset]), np.array([size]))
        if problems[0] is not None:
            raise PacketError(problems[0])
        return samples[0]

    def read_many(self, data: np.ndarray, descriptor: WaveformDescriptor, offsets: np.ndarray,
                  sizes: np.ndarray) -> tuple[np.ndarray, list[str | None]]:
        """Samples (k, n) of the packets at `offsets` of one descriptor, and per packet None or why it is lost.

        Uncompressed packets are gathered in one fancy index; compressed ones decoded one by one.
        """
        offsets, sizes = np.asarray(offsets, np.int64), np.asarray(sizes, np.int64)
        n, need = descriptor.n_samples, descriptor.packet_bytes
        out = np.zeros((offsets.size, n))
        problems: list[str | None] = [None] * offsets.size
        start = self.record_start + offsets
        if self.compressed:
            for j, at in enumerate(start.tolist()):
                try:
                    out[j] = wdz.decode_packet(data, at, n, descriptor.bits_per_sample)
                except WdzError as err:
                    problems[j] = f"{self.path.name}: {err}"
            return out, problems
        short = (sizes > 0) & (sizes < need)
        beyond = (offsets < 0) | (start + need > data.size)
        for j in np.flatnonzero(short):
            problems[j] = (f"{self.path.name}: packet size {sizes[j]} bytes is less than descriptor "
                           f"{descriptor.index}'s {n} samples x {descriptor.container_bytes} bytes")
        for j in np.flatnonzero(beyond & ~short):
            problems[j] = (f"packet at byte {offsets[j]} ({need} bytes) lies beyond the end of {self.path.name} "
                           f"({data.size - self.record_start} bytes of packets)")
        ok = np.flatnonzero(~short & ~beyond)
        if ok.size:
            raw = np.asarray(data)[start[ok, None] + np.arange(need)]
            dtype = {1: "<u1", 2: "<u2", 4: "<u4"}[descriptor.container_bytes]
            samples = np.ascontiguousarray(raw).view(dtype).astype(np.float64)
            if descriptor.bits_per_sample not in (8, 16, 32):
                samples = np.mod(samples, float(1 << descriptor.bits_per_sample))  # padding bits are not signal
            out[ok] = samples
        return out, problems


def lastools_compression(path: Path) -> bool | None:
    """Whether a LAStools packet file says its packets are compressed (None: no LAStools header)."""
    with open(path, "rb") as f:
        head = f.read(EVLR_HEADER_BYTES + 24 + 2 + 6)
    if head[EVLR_HEADER_BYTES:EVLR_HEADER_BYTES + len(LASTOOLS_SIGNATURE)] != LASTOOLS_SIGNATURE:
        return None
    if len(head) < EVLR_HEADER_BYTES + 24 + 2 + 6:
        return None
    return head[EVLR_HEADER_BYTES + 24 + 2 + 2] == 1  # first descriptor's compression byte


def external_packet_file(las_path: Path) -> Path:
    """The .wdp (or LAStools .wdz) beside a LAS/LAZ file, same base name, either case."""
    laz = las_path.suffix.lower() == ".laz"
    suffixes = (".wdz", ".WDZ", ".wdp", ".WDP") if laz else (".wdp", ".WDP", ".wdz", ".WDZ")
    for suffix in suffixes:
        candidate = las_path.with_suffix(suffix)
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f"{las_path}: waveform packets are external but {las_path.with_suffix('.wdp').name} "
                            "(or .wdz) is missing beside it")
