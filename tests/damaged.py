"""Damaged variants of the bundled Leica sample, seeded: what a survey's worst files look like.

    write_variants(sample_dir, folder, seed, rounds) -> [Variant]   each as <name>.las (+ .wdp) or <name>.laz

Beside the variants, what a pattern like "*.las" also matches in a survey's folder: a folder named
`dir.las` and a link to a file that is gone (`missing.las`), returned by `not_inputs(folder)`. With
rounds > 1, each damage drawn at random is drawn again (`<name>_r2`, ...): 64 variants with rounds=3.

The sample is LAS 1.3, point format 4 (57-byte records, 1125 points, 924 pulses), with its
packets in leica_a.wdp. Byte positions below are those of the LAS 1.3 header and of point
format 4, so that a damage hits the field it names.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np

SAMPLE_POINTS, SAMPLE_PULSES = 1125, 924
HEADER_SIZE, POINT_SIZE = 235, 57
LEGACY_POINT_COUNT, X_SCALE = 107, 131  # header byte offsets (uint32; 3 doubles)
# point format 4 fields: (offset in the record, struct format)
POINT_FIELDS = {"X": (0, "<i"), "Y": (4, "<i"), "Z": (8, "<i"), "gps_time": (20, "<d"),
                "wavepacket_index": (28, "<B"), "wavepacket_offset": (29, "<Q"), "wavepacket_size": (37, "<I"),
                "return_point_wave_location": (41, "<f"), "x_t": (45, "<f"), "y_t": (49, "<f"), "z_t": (53, "<f")}
DESCRIPTOR_PAYLOAD = 26  # bits, compression, samples (u32), spacing ps (u32), gain, offset (doubles)
# descriptor fields: (offset in its payload, struct format)
DESCRIPTOR_FIELDS = {"bits": (0, "<B"), "samples": (2, "<I"), "spacing": (6, "<I"), "gain": (10, "<d")}
NOT_INPUTS = ("dir.las", "missing.las")  # matched by *.las, neither is a file to read


@dataclasses.dataclass(frozen=True)
class Variant:
    name: str  # the input's stem
    suffix: str  # .las or .laz
    damage: str  # what was done, in a line
    pulses_intact: bool  # point records and their packet fields intact: each of the 924 pulses must be accounted for

    @property
    def file_name(self) -> str:
        return self.name + self.suffix


def _point_data_offset(las: bytes) -> int:
    return struct.unpack_from("<I", las, 96)[0]


def _descriptor_payload_offset(las: bytes) -> int:
    """Where the first waveform packet descriptor's 26 bytes start (VLR record id 100-354)."""
    at = HEADER_SIZE
    for _ in range(struct.unpack_from("<I", las, 100)[0]):
        user, record, length = las[at + 2:at + 18].rstrip(b"\0"), struct.unpack_from("<H", las, at + 18)[0], \
            struct.unpack_from("<H", las, at + 20)[0]
        if user == b"LASF_Spec" and 100 <= record < 355:
            return at + 54
        at += 54 + length
    raise ValueError("no waveform packet descriptor")


def _set_point_field(las: bytearray, points: np.ndarray, field: str, value) -> None:
    offset, fmt = POINT_FIELDS[field]
    base = _point_data_offset(las)
    for p in points:
        struct.pack_into(fmt, las, base + int(p) * POINT_SIZE + offset, value)


def _flip(data: bytearray, lo: int, hi: int, n: int, rng: np.random.Generator) -> None:
    """n random bytes of [lo, hi) replaced by random values that differ from them."""
    for at in rng.choice(np.arange(lo, hi), size=n, replace=False):
        data[at] ^= int(rng.integers(1, 256))


def _with_descriptor(las: bytes, descriptor: int, field: str, value, fmt: str | None = None) -> bytes:
    changed = bytearray(las)
    offset, default = DESCRIPTOR_FIELDS[field]
    struct.pack_into(fmt or default, changed, descriptor + offset, value)
    return bytes(changed)


def write_not_inputs(folder: Path) -> None:
    """A folder named dir.las (holding a note) and a link named missing.las to a file that is not there."""
    (folder / "dir.las").mkdir(exist_ok=True)
    (folder / "dir.las" / "notes.txt").write_text("not a flight line\n")
    link = folder / "missing.las"
    if not link.is_symlink():
        link.symlink_to(folder / "gone.las")


def write_variants(sample: Path, folder: Path, seed: int = 0, rounds: int = 1) -> list[Variant]:
    """Write the damaged variants (and one undamaged copy, `good`) into `folder`, and the matches that are no
    input (write_not_inputs)."""
    rng = np.random.default_rng(seed)
    las = (sample / "leica_a.las").read_bytes()
    wdp = (sample / "leica_a.wdp").read_bytes()
    laz = (sample / "leica_a.laz").read_bytes()
    points = _point_data_offset(las)
    descriptor = _descriptor_payload_offset(las)
    folder.mkdir(parents=True, exist_ok=True)
    variants: list[Variant] = []

    def add(name: str, damage: str, las_bytes: bytes | None, wdp_bytes: bytes | None = wdp,
            pulses_intact: bool = True, laz_bytes: bytes | None = None) -> None:
        if laz_bytes is not None:
            (folder / f"{name}.laz").write_bytes(laz_bytes)
            (folder / f"{name}.wdp").write_bytes(wdp)
            variants.append(Variant(name, ".laz", damage, pulses_intact))
            return
        (folder / f"{name}.las").write_bytes(las_bytes)
        if wdp_bytes is not None:
            (folder / f"{name}.wdp").write_bytes(wdp_bytes)
        variants.append(Variant(name, ".las", damage, pulses_intact))

    add("good", "none", las)
    # truncations: inside the header, inside the VLRs, inside the point records (mid-record)
    add("cut_header", "cut at byte 100 of the 235-byte header", las[:100], pulses_intact=False)
    add("cut_vlrs", "cut inside the VLRs", las[:int(rng.integers(HEADER_SIZE + 10, points - 10))],
        pulses_intact=False)
    cut = points + 1000 * POINT_SIZE + int(rng.integers(1, POINT_SIZE))
    add("cut_points", "cut inside point record 1000 of 1125", las[:cut], pulses_intact=False)
    # header fields
    huge = bytearray(las)
    struct.pack_into("<I", huge, LEGACY_POINT_COUNT, 10**9)
    add("huge_count", "header point count 1e9 (file: 1125)", bytes(huge), pulses_intact=False)
    low = bytearray(las)
    struct.pack_into("<I", low, LEGACY_POINT_COUNT, 1000)
    add("low_count", "header point count 1000 (file: 1125)", bytes(low))
    zero = bytearray(las)
    struct.pack_into("<d", zero, X_SCALE, 0.0)
    add("x_scale_zero", "x scale 0", bytes(zero))
    flipped = bytearray(las)
    _flip(flipped, 0, HEADER_SIZE, 8, rng)
    add("flip_header", "8 random bytes of the header", bytes(flipped), pulses_intact=False)
    # the waveform packet descriptor: random bytes, and a non-finite gain
    flipped = bytearray(las)
    _flip(flipped, descriptor, descriptor + DESCRIPTOR_PAYLOAD, 4, rng)
    add("flip_descriptor", "4 random bytes of the waveform packet descriptor", bytes(flipped))
    nan_gain = bytearray(las)
    struct.pack_into("<d", nan_gain, descriptor + 10, float("nan"))
    add("nan_gain", "descriptor gain NaN", bytes(nan_gain))
    # point records: non-finite beam directions, random flips in fields and anywhere
    some = rng.choice(SAMPLE_POINTS, size=40, replace=False)
    for field, value in (("x_t", float("nan")), ("y_t", float("inf")), ("z_t", float("-inf"))):
        bad = bytearray(las)
        _set_point_field(bad, some, field, value)
        add(f"{field}_not_finite", f"{field} = {value} in 40 point records", bytes(bad))
    flipped = bytearray(las)
    for field in ("wavepacket_offset", "wavepacket_size", "wavepacket_index", "return_point_wave_location"):
        offset, fmt = POINT_FIELDS[field]
        for p in rng.choice(SAMPLE_POINTS, size=10, replace=False):
            at = points + int(p) * POINT_SIZE + offset + int(rng.integers(0, struct.calcsize(fmt)))
            flipped[at] ^= int(rng.integers(1, 256))
    add("flip_packet_fields", "random bytes of 40 points' packet fields", bytes(flipped), pulses_intact=False)
    flipped = bytearray(las)
    _flip(flipped, points, len(las), 200, rng)
    add("flip_points", "200 random bytes anywhere in the point records", bytes(flipped), pulses_intact=False)
    # the packets: random samples (still readable), empty, missing
    flipped = bytearray(wdp)
    _flip(flipped, 60, len(wdp), 500, rng)
    add("flip_packets", "500 random bytes of the .wdp packets", las, bytes(flipped))
    add("empty_wdp", "empty .wdp", las, b"")
    add("missing_wdp", "no .wdp", las, None)
    # empty and foreign files, a damaged LAZ
    add("empty", "empty .las", b"", None, pulses_intact=False)
    add("foreign_text", "a text file named .las", b"flight notes: nothing to see here\n" * 20, None,
        pulses_intact=False)
    add("foreign_binary", "random bytes named .las", rng.integers(0, 256, 5000, dtype=np.uint8).tobytes(), None,
        pulses_intact=False)
    add("foreign_csv", "a NEON waveform CSV named .las", b"waveform_id,n_samples,s0,s1\n1,2,10,12\n", None,
        pulses_intact=False)
    add("foreign_wdp", "a .wdp packet file named .las", wdp, None, pulses_intact=False)
    add("empty_laz", "an empty .laz", None, pulses_intact=False, laz_bytes=b"")
    add("cut_laz", "a LAZ cut at half", None, pulses_intact=False, laz_bytes=laz[:len(laz) // 2])
    flipped = bytearray(laz)
    _flip(flipped, _point_data_offset(laz) + 64, len(laz), 50, rng)
    add("flip_laz", "50 random bytes of a LAZ's compressed points", None, pulses_intact=False,
        laz_bytes=bytes(flipped))
    flipped = bytearray(las)
    _flip(flipped, HEADER_SIZE, points, 12, rng)
    add("flip_vlrs", "12 random bytes of the VLRs", bytes(flipped), pulses_intact=False)
    add("cut_packets", "a .wdp cut at a third", las, wdp[:len(wdp) // 3], pulses_intact=False)
    _descriptor_variants(add, las, descriptor)
    for r in range(2, rounds + 1):
        _random_variants(add, las, wdp, laz, descriptor, rng, f"_r{r}")
    write_not_inputs(folder)
    return variants


def _descriptor_variants(add, las: bytes, descriptor: int) -> None:
    """The waveform packet descriptor saying what its packets are not: samples, spacing, gain, bits."""
    for n in (0, 1, 3, 257):
        add(f"samples_{n}", f"descriptor: {n} samples (packets: 256)", _with_descriptor(las, descriptor, "samples", n))
    add("spacing_0", "descriptor: sample spacing 0 ps", _with_descriptor(las, descriptor, "spacing", 0))
    add("spacing_negative", "descriptor: sample spacing -2000 ps (as a signed 32-bit integer)",
        _with_descriptor(las, descriptor, "spacing", -2000, "<i"))
    add("inf_gain", "descriptor gain infinite", _with_descriptor(las, descriptor, "gain", float("inf")))
    for bits in (0, 12, 136):  # 136 does not fit the byte: 136 % 256 is stored as is
        add(f"bits_{bits}", f"descriptor: {bits} bits per sample (packets: 8)",
            _with_descriptor(las, descriptor, "bits", bits % 256))


def _random_variants(add, las: bytes, wdp: bytes, laz: bytes, descriptor: int, rng: np.random.Generator,
                     tag: str) -> None:
    """Another draw of each damage drawn at random: cuts and byte flips of every part, random bytes."""
    points = _point_data_offset(las)
    add("cut_vlrs" + tag, "cut inside the VLRs", las[:int(rng.integers(HEADER_SIZE + 10, points - 10))],
        pulses_intact=False)
    add("cut_points" + tag, "cut inside the point records",
        las[:int(rng.integers(points + POINT_SIZE, len(las) - 1))], pulses_intact=False)
    for name, lo, hi, n in (("flip_header", 0, HEADER_SIZE, 8), ("flip_vlrs", HEADER_SIZE, points, 12),
                            ("flip_descriptor", descriptor, descriptor + DESCRIPTOR_PAYLOAD, 4),
                            ("flip_points", points, len(las), 200)):
        flipped = bytearray(las)
        _flip(flipped, lo, hi, n, rng)
        add(name + tag, f"{n} random bytes in [{lo}, {hi})", bytes(flipped), pulses_intact=False)
    flipped = bytearray(wdp)
    _flip(flipped, 60, len(wdp), 500, rng)
    add("flip_packets" + tag, "500 random bytes of the .wdp packets", las, bytes(flipped))
    add("cut_packets" + tag, "a .wdp cut at random", las, wdp[:int(rng.integers(1, len(wdp) - 1))],
        pulses_intact=False)
    add("foreign_binary" + tag, "random bytes named .las", rng.integers(0, 256, 5000, dtype=np.uint8).tobytes(), None,
        pulses_intact=False)
    add("cut_laz" + tag, "a LAZ cut at random", None, pulses_intact=False,
        laz_bytes=laz[:int(rng.integers(1, len(laz) - 1))])
    flipped = bytearray(laz)
    _flip(flipped, _point_data_offset(laz) + 64, len(laz), 50, rng)
    add("flip_laz" + tag, "50 random bytes of a LAZ's compressed points", None, pulses_intact=False,
        laz_bytes=bytes(flipped))
