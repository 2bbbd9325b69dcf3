"""Which range owns each pulse, in bounded memory whatever the file's size.

A pulse is the set of points sharing one packet key (descriptor, byte offset)
and belongs to the range of its first point. Finding a pulse's first point
needs every point of that key together, and a key's points may lie anywhere
in the file. Planning therefore spreads the (key, point) pairs over buckets by
a hash of the key, so that all the points of a pulse meet in one bucket, and
sorts one bucket at a time: memory is bounded by the bucket and the chunk,
never by the file. Beyond one bucket the buckets wait on disk (16 bytes a
point, in the temporary directory: `TMPDIR`).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

KEY_SHIFT = np.int64(48)  # key = descriptor index << 48 | byte offset
BUCKET_POINTS = 2_000_000  # points one planning step sorts at once: ~100 MB of working memory
_PAIR = np.dtype([("key", "<i8"), ("point", "<i8")])
_FIBONACCI = np.uint64(0x9E3779B97F4A7C15)  # multiplicative hashing: any key pattern spreads evenly


@dataclasses.dataclass(frozen=True)
class PulseOwnership:
    """What planning needs to know of a file's pulses, whatever its size."""

    pulses_per_range: np.ndarray  # pulses each range owns
    straying: np.ndarray  # points whose pulse another range owns, in point order
    stray_owner: np.ndarray  # the range that owns each straying point's pulse
    descriptor_points: np.ndarray  # points per descriptor index (256: LAS's index is one byte)
    descriptor_pulses: np.ndarray  # pulses (distinct packets) per descriptor index


def pulse_ownership(key_chunks: Iterable[tuple[int, np.ndarray]], n_points: int, points_per_range: int,
                    bucket_points: int = BUCKET_POINTS) -> PulseOwnership:
    """Each pulse's owner (the range of its first point) from the packet keys, given chunk by chunk in
    point order as (first point, keys); a key < 0 is a point without a packet, part of no pulse."""
    n_ranges = -(-n_points // points_per_range)
    bits = math.ceil(math.log2(n_points / bucket_points)) if n_points > bucket_points else 0
    descriptor_points, descriptor_pulses = np.zeros(256, np.int64), np.zeros(256, np.int64)
    pulses_per_range = np.zeros(n_ranges, np.int64)
    straying, stray_owner = [], []
    with _KeyBuckets(bits) as buckets:
        for first, keys in key_chunks:
            has_packet = keys >= 0
            descriptor_points += np.bincount(keys[has_packet] >> KEY_SHIFT, minlength=256)[:256]
            buckets.add(keys[has_packet], first + np.flatnonzero(has_packet))
        for keys, points in buckets:
            pulse_keys, owner_of_pulse, away, away_owner = _owners(keys, points, points_per_range)
            pulses_per_range += np.bincount(owner_of_pulse, minlength=n_ranges)
            descriptor_pulses += np.bincount(pulse_keys >> KEY_SHIFT, minlength=256)[:256]
            straying.append(away)
            stray_owner.append(away_owner)
    straying = np.concatenate(straying) if straying else np.zeros(0, np.int64)
    stray_owner = np.concatenate(stray_owner) if stray_owner else np.zeros(0, np.int64)
    by_point = np.argsort(straying, kind="stable")
    return PulseOwnership(pulses_per_range, straying[by_point], stray_owner[by_point], descriptor_points,
                          descriptor_pulses)


def _owners(keys: np.ndarray, points: np.ndarray, points_per_range: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For points in point order: each pulse's key and owner, and the points another range owns, with that
    range."""
    order = np.argsort(keys, kind="stable")  # the points of one pulse together, first point first
    keys, points = keys[order], points[order]
    new_pulse = np.empty(keys.size, dtype=bool)
    new_pulse[:1] = True
    np.not_equal(keys[1:], keys[:-1], out=new_pulse[1:])
    first = np.flatnonzero(new_pulse)
    owner_of_pulse = points[first] // points_per_range
    owner = np.repeat(owner_of_pulse, np.diff(np.append(first, keys.size)))
    away = owner != points // points_per_range
    return keys[first], owner_of_pulse, points[away], owner[away]


class _KeyBuckets:
    """(key, point) pairs in 2**bits buckets by a hash of the key, each in point order: one bucket stays in
    memory, more go to temporary files, read back one at a time."""

    def __init__(self, bits: int):
        self.bits = bits
        self.memory: list[np.ndarray] = []
        self.folder = tempfile.TemporaryDirectory(prefix="fwl-plan-") if bits else None
        self.files = [open(Path(self.folder.name) / f"{b}.pairs", "wb") for b in range(1 << bits)] if bits else []

    def __enter__(self) -> _KeyBuckets:
        return self

    def __exit__(self, *exc) -> None:
        for f in self.files:
            f.close()
        if self.folder is not None:
            self.folder.cleanup()

    def add(self, keys: np.ndarray, points: np.ndarray) -> None:
        pairs = np.empty(keys.size, _PAIR)
        pairs["key"], pairs["point"] = keys, points
        if not self.bits:
            self.memory.append(pairs)
            return
        bucket = (keys.astype(np.uint64) * _FIBONACCI) >> np.uint64(64 - self.bits)
        order = np.argsort(bucket, kind="stable")  # stable: point order within each bucket
        ends = np.cumsum(np.bincount(bucket, minlength=len(self.files)))
        pairs = pairs[order]
        for f, lo, hi in zip(self.files, np.append(0, ends[:-1]), ends):
            pairs[lo:hi].tofile(f)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        if not self.bits:
            pairs = np.concatenate(self.memory) if self.memory else np.zeros(0, _PAIR)
            self.memory = []
            yield pairs["key"], pairs["point"]
            return
        for f in self.files:
            f.close()
            pairs = np.fromfile(f.name, _PAIR)
            yield pairs["key"], pairs["point"]
