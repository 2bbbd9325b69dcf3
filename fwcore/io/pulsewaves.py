"""PulseWaves (.pls pulses + .wvs waves), read natively into the same PulseBatch as LAS.

The format: PulseWaves/Specification `specification.rst` (draft 0.3); where the
draft and the files disagree, the files and the reference library's headers
(PulseWaves/PulseWaves `inc/`) win:

- composition record on disk: ..., sample units (f32), compression (u32), scanner index (u32), description;
- direction = (target - anchor) / 1000, the target 1000 sampling units from the anchor;
- the waves header is 60 bytes; durations are signed, counts and samples unsigned;
- lookup tables are records 300001..300255; pulse descriptors 200001..200255;
- the header's AVLR count is not trusted: AVLRs are found walking back from the end of the file.

A row of the batch is one pulse's waveform: of its returning samplings (RIEGL
records a high-power channel beside the low-power one where that saturates)
the one that does not saturate with the highest peak against its full scale,
its segments joined on one sample grid, through its lookup table (a dB table
gives power; its no-value entries, below detection, 0). Sample k of a segment
lies at P = anchor + (d + k * s) * direction, d = scale * D + offset its
duration from the anchor and s the sampling's sample units over the
composition's. In the batch's LAS terms: direction x_t = -direction / unit_ps
and L0 = -d * unit_ps.
"""

from __future__ import annotations

import dataclasses
import re
import struct
from pathlib import Path

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.io.crs import geokeys_from_bytes, looks_earth_centred, wkt_from_epsg, wkt_from_geokeys
from fwcore.io.descriptors import warn_unusable
from fwcore.io.errors import WaveformFileError
from fwcore.io.records import PointRange, PulseBatch, pulse_identity
from fwcore.io.signatures import PULSE_SIGNATURE, WAVES_SIGNATURE

WAVES_HEADER_BYTES = 60
VLR_HEADER_BYTES = 96
OUTGOING, RETURNING = 1, 2
SCANNER_IDS = range(100001, 100256)
DESCRIPTOR_IDS = range(200001, 200256)
TABLE_IDS = range(300001, 300256)
AVLR_TERMINATOR = 0xFFFFFFFF
VARIES = 0x8FFFFFFF  # optical centre to anchor: "no constant offset"
PULSE_HEADER = struct.Struct("<16sII I HH 8s 64s 64s HH BB H qq IIII q Ii dd qq 3d 3d 6d")
PULSE_RECORD = np.dtype([("T", "<i8"), ("offset", "<i8"), ("anchor", "<i4", 3), ("target", "<i4", 3),
                         ("first_returning", "<i2"), ("last_returning", "<i2"), ("descriptor", "u1"),
                         ("flags", "u1"), ("intensity", "u1"), ("classification", "u1")])


@dataclasses.dataclass(frozen=True)
class PulseHeader:
    system_identifier: str
    generating_software: str
    version: str
    header_size: int
    offset_to_pulses: int
    n_pulses: int
    pulse_format: int
    pulse_attributes: int
    pulse_size: int
    pulse_compression: int
    n_vlrs: int
    n_avlrs: int
    t_scale: float
    t_offset: float
    t_min: int
    t_max: int
    scales: tuple[float, float, float]
    offsets: tuple[float, float, float]
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class Sampling:
    type: int  # 1 outgoing, 2 returning
    channel: int
    bits_for_duration: int  # 0, 8, 16, 32 (signed durations)
    duration_scale: float
    duration_offset: float
    bits_for_segments: int  # 0: fixed number_of_segments
    bits_for_samples: int  # 0: fixed number_of_samples
    number_of_segments: int
    number_of_samples: int
    bits_per_sample: int
    lookup_table: int  # 0: none
    sample_units_ns: float
    compression: int
    description: str

    @property
    def kind(self) -> str:
        return {OUTGOING: "outgoing", RETURNING: "returning"}.get(self.type, f"type {self.type}")


@dataclasses.dataclass(frozen=True)
class PulseDescriptor:
    index: int
    optical_center_to_anchor: int  # sampling units; VARIES when not constant
    extra_wave_bytes: int
    sample_units_ns: float
    compression: int
    scanner_index: int
    description: str
    samplings: tuple[Sampling, ...]
    problem: str | None = None  # why its pulses cannot be read; None: usable


DECIBEL_UNIT = 1  # the unit_of_measurement RiPROCESS writes on its dB tables (the draft defines no codes)
NO_VALUE = 1e30  # a table entry of this magnitude or more (RIEGL: -2e37), or not finite, is no measurement


@dataclasses.dataclass(frozen=True)
class LookupTable:
    """A sampling's lookup table: entry k is the physical value of sample code k."""

    index: int
    unit: int
    data_type: int
    description: str
    entries: np.ndarray

    @property
    def no_value(self) -> np.ndarray:
        """Per code: the table says "below detection" (RIEGL writes -2e37 for codes 0-3), not a value."""
        return ~np.isfinite(self.entries) | (np.abs(self.entries) >= NO_VALUE)

    @property
    def decibels(self) -> bool:
        """Its values are levels in dB: its description says so, or its unit code is RiPROCESS's dB code.
        Values alone do not decide (a table of volts may be negative too)."""
        return self.unit == DECIBEL_UNIT or bool(re.search(r"\bdB[mW]?\b|decibel", self.description, re.IGNORECASE))

    def power(self) -> np.ndarray:
        """Per code, what the engine fits: power (10^(dB/10)) for a dB table, the value for a linear one;
        0 where the table has no value (below detection)."""
        valid = ~self.no_value
        values = np.where(valid, self.entries, 0.0)
        if self.decibels:
            values = np.where(valid, 10.0 ** (np.minimum(values, 300.0) / 10.0), 0.0)
        return values

    def saturation_code(self, bits: int) -> int:
        """The first code at which the samples saturate: the digitizer's full scale, or the first code at the
        table's highest value where the table ends in a flat top."""
        full = (1 << bits) - 1
        valid = np.flatnonzero(~self.no_value)
        if valid.size == 0:
            return full
        top = self.entries[valid].max()
        return int(min(full, valid[np.argmax(self.entries[valid] >= top)]))


@dataclasses.dataclass(frozen=True)
class Scanner:
    index: int
    instrument: str
    serial: str
    wavelength_nm: float
    outgoing_pulse_width_ns: float  # FWHM, in ns (the draft says nanometres)
    beam_divergence_mrad: float | None = None  # @ 1/e^2, full angle; None where the record does not say (0 or absent)


@dataclasses.dataclass(frozen=True)
class PulseWavesFile:
    path: Path
    waves_path: Path
    header: PulseHeader
    descriptors: dict[int, PulseDescriptor]
    scanners: dict[int, Scanner]
    lookup_tables: dict[int, LookupTable]
    crs_wkt: str | None
    crs_source: str
    point_count: int  # pulse records present
    problems: tuple[str, ...] = ()

    @property
    def pulse_dtype(self) -> np.dtype:
        extra = self.header.pulse_size - PULSE_RECORD.itemsize
        return np.dtype({"names": list(PULSE_RECORD.names), "formats": [PULSE_RECORD[n] for n in PULSE_RECORD.names],
                         "offsets": [PULSE_RECORD.fields[n][1] for n in PULSE_RECORD.names],
                         "itemsize": PULSE_RECORD.itemsize + max(extra, 0)})

    def records(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Pulse records [start, stop), memory-mapped."""
        stop = self.point_count if stop is None else min(stop, self.point_count)
        if stop <= start:
            return np.zeros(0, self.pulse_dtype)
        return np.memmap(self.path, dtype=self.pulse_dtype, mode="r", offset=self.header.offset_to_pulses,
                         shape=(self.point_count,))[start:stop]


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", "replace").strip()


# ---------------------------------------------------------------- header and records

def _parse_header(path: Path, data: bytes) -> PulseHeader:
    if len(data) < PULSE_HEADER.size:
        raise WaveformFileError(f"{path}: {len(data)} bytes, shorter than a PulseWaves header ({PULSE_HEADER.size})")
    f = PULSE_HEADER.unpack_from(data)
    if f[0] != PULSE_SIGNATURE:
        raise WaveformFileError(f"{path}: not a PulseWaves pulse file (signature {f[0][:15]!r})")
    (_, _, _, _, _, _, _, system, software, _, _, major, minor, header_size, offset_to_pulses, n_pulses,
     pulse_format, attributes, pulse_size, compression, _, n_vlrs, n_avlrs, t_scale, t_offset, t_min, t_max) = f[:27]
    scales, offsets, bounds = f[27:30], f[30:33], f[33:39]
    header = PulseHeader(_text(system), _text(software), f"{major}.{minor}", header_size, offset_to_pulses,
                         n_pulses, pulse_format, attributes, pulse_size, compression, n_vlrs, n_avlrs, t_scale,
                         t_offset, t_min, t_max, tuple(scales), tuple(offsets), tuple(bounds[0::2]),
                         tuple(bounds[1::2]))
    if pulse_format != 0 or compression != 0:
        raise WaveformFileError(f"{path}: pulse format {pulse_format} / compression {compression}: only format 0 "
                                "uncompressed is defined")
    if pulse_size < PULSE_RECORD.itemsize:
        raise WaveformFileError(f"{path}: pulse records of {pulse_size} bytes, less than format 0's "
                                f"{PULSE_RECORD.itemsize}")
    if not all(np.isfinite(scales)) or not all(s != 0 for s in scales) or not all(np.isfinite(offsets)):
        raise WaveformFileError(f"{path}: the header's scales {scales} / offsets {offsets} cannot give coordinates")
    if n_pulses < 0 or offset_to_pulses < header_size:
        raise WaveformFileError(f"{path}: {n_pulses} pulses at byte {offset_to_pulses}: not a consistent header")
    return header


def _records_of(data: bytes, start: int, count: int, end: int) -> list[tuple[str, int, str, bytes]]:
    """(user id, record id, description, payload) of `count` VLRs from `start`, stopping at `end`."""
    out, at = [], start
    for _ in range(count):
        if at + VLR_HEADER_BYTES > end:
            break
        user, record_id, _, length = struct.unpack_from("<16sIIq", data, at)
        payload = data[at + VLR_HEADER_BYTES:at + VLR_HEADER_BYTES + max(length, 0)]
        out.append((_text(user), record_id, _text(data[at + 32:at + 96]), payload))
        at += VLR_HEADER_BYTES + max(length, 0)
    return out


def _appended_records(data: bytes, pulses_end: int) -> list[tuple[str, int, str, bytes]]:
    """AVLRs, walking back from the end of the file to the terminator (or to the pulses' end)."""
    out, at = [], len(data)
    while at - VLR_HEADER_BYTES >= pulses_end:
        footer = at - VLR_HEADER_BYTES
        user, record_id, _, length = struct.unpack_from("<16sIIq", data, footer)
        if not _text(user).startswith("PulseWaves") and record_id != AVLR_TERMINATOR:
            break  # older conversions end without a terminator: whatever is here is no AVLR
        if record_id == AVLR_TERMINATOR or length < 0 or footer - length < pulses_end:
            break
        out.append((_text(user), record_id, _text(data[footer + 32:footer + 96]), data[footer - length:footer]))
        at = footer - length
    return out


def _parse_descriptor(index: int, payload: bytes) -> PulseDescriptor:
    name = f"pulse descriptor {index}"
    if len(payload) < 28:
        return PulseDescriptor(index, 0, 0, 0.0, 0, 0, "", (), f"{name} is {len(payload)} bytes, too short")
    size, _, optical, extra, n_samplings, units, compression, scanner = struct.unpack_from("<IIiHHfII", payload)
    description = _text(payload[28:min(size, len(payload))][-64:]) if size >= 92 else ""
    samplings, at = [], size
    for _ in range(n_samplings):
        if at + 40 > len(payload):
            return PulseDescriptor(index, optical, extra, units, compression, scanner, description, tuple(samplings),
                                   f"{name} declares {n_samplings} samplings but holds {len(samplings)}")
        s_size, _, kind, channel, _, bits_d, scale_d, offset_d, bits_seg, bits_smp, n_seg, n_smp, bits, table, \
            s_units, s_comp = struct.unpack_from("<IIBBBBffBBHIHHfI", payload, at)
        s_description = _text(payload[at + 40:at + 104]) if s_size >= 104 else ""
        samplings.append(Sampling(kind, channel, bits_d, scale_d, offset_d, bits_seg, bits_smp, n_seg, n_smp, bits,
                                  table, s_units, s_comp, s_description))
        at += max(s_size, 40)
    d = PulseDescriptor(index, optical, extra, units, compression, scanner, description, tuple(samplings))
    return dataclasses.replace(d, problem=_descriptor_problem(d))


def _descriptor_problem(d: PulseDescriptor) -> str | None:
    name = f"pulse descriptor {d.index}"
    if d.compression != 0:
        return f"{name} has compression {d.compression} (only 0, none, is defined)"
    if not (np.isfinite(d.sample_units_ns) and d.sample_units_ns > 0):
        return f"{name} has sample units {d.sample_units_ns} ns"
    if not any(s.type == RETURNING for s in d.samplings):
        return f"{name} has no returning sampling"
    for m, s in enumerate(d.samplings):
        what = f"{name} sampling {m} ({s.kind})"
        if s.bits_per_sample not in (8, 16):
            return f"{what} has {s.bits_per_sample} bits per sample (8 and 16 are readable)"
        if s.compression != 0:
            return f"{what} has compression {s.compression} (only 0, none, is defined)"
        if s.bits_for_duration not in (0, 8, 16, 32) or s.bits_for_segments not in (0, 8, 16) \
                or s.bits_for_samples not in (0, 8, 16):
            return (f"{what} stores durations, segment counts or sample counts in {s.bits_for_duration}/"
                    f"{s.bits_for_segments}/{s.bits_for_samples} bits (0, 8, 16 or 32 are defined)")
        if not (np.isfinite(s.sample_units_ns) and s.sample_units_ns > 0 and np.isfinite(s.duration_scale)
                and np.isfinite(s.duration_offset)):
            return f"{what} has sample units {s.sample_units_ns} ns or a non-finite duration scale/offset"
    return None


def _parse_table(index: int, payload: bytes) -> LookupTable | None:
    """A lookup table record: header (size, reserved, number of tables, description), then the first table:
    size, reserved, entries, unit, data type, options, [compression,] description, then the entries. The
    description is the last 64 bytes of the table's `size`: 84 with a compression field before it, 80 as the
    reference library's 0.3 r8 writes it."""
    try:
        size, _, n_tables = struct.unpack_from("<III", payload)
        at = size
        t_size, _, n_entries, unit, data_type, _ = struct.unpack_from("<IIIHBB", payload, at)
        description = _text(payload[at + max(16, t_size - 64):at + max(80, t_size)])
        entries = np.frombuffer(payload, dtype="<f4", count=n_entries, offset=at + t_size) if data_type == 8 \
            else np.zeros(0, np.float32)
        return LookupTable(index, unit, data_type, description, entries.astype(np.float64))
    except (struct.error, ValueError):
        return None


def _parse_scanner(index: int, payload: bytes) -> Scanner | None:
    if len(payload) < 144:
        return None
    _, _ = struct.unpack_from("<II", payload)
    wavelength, width = struct.unpack_from("<ff", payload, 136)
    divergence = struct.unpack_from("<f", payload, 172)[0] if len(payload) >= 176 else 0.0
    divergence = float(divergence) if np.isfinite(divergence) and 0.0 < divergence < 100.0 else None
    return Scanner(index, _text(payload[8:72]), _text(payload[72:136]), wavelength, width, divergence)


def waves_file(path: Path) -> Path:
    for suffix in (".wvs", ".WVS"):
        candidate = path.with_suffix(suffix)
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f"{path}: its waves file {path.with_suffix('.wvs').name} is missing beside it")


def open_pulsewaves(path: str | Path) -> PulseWavesFile:
    """Header, VLRs and AVLRs of a .pls and the check of its .wvs; errors name the file and the problem."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    data = path.read_bytes() if path.stat().st_size < (1 << 20) else _head_and_tail(path)
    if not data:
        raise WaveformFileError(f"{path}: empty file")
    header = _parse_header(path, data)
    size = path.stat().st_size
    vlrs = _records_of(data, header.header_size, header.n_vlrs, header.offset_to_pulses)
    present = max(0, min(header.n_pulses, (size - header.offset_to_pulses) // header.pulse_size))
    problems = []
    if present < header.n_pulses:
        problems.append(f"{path}: truncated: {present} of {header.n_pulses} pulse records present")
    if len(data) == size:
        vlrs += _appended_records(data, header.offset_to_pulses + present * header.pulse_size)
    descriptors, scanners, tables, geokeys = {}, {}, {}, None
    for user, record_id, _, payload in vlrs:
        if user == "PulseWaves_Spec" and record_id in DESCRIPTOR_IDS:
            descriptors[record_id - 200000] = _parse_descriptor(record_id - 200000, payload)
        elif user == "PulseWaves_Spec" and record_id in SCANNER_IDS:
            scanner = _parse_scanner(record_id - 100000, payload)
            if scanner:
                scanners[scanner.index] = scanner
        elif user == "PulseWaves_Spec" and record_id in TABLE_IDS:
            table = _parse_table(record_id - 300000, payload)
            if table:
                tables[table.index] = table
        elif user == "PulseWaves_Proj" and record_id == 34735:
            geokeys = geokeys_from_bytes(payload)
    if not descriptors:
        raise WaveformFileError(f"{path}: no pulse descriptor (records 200001-200255)")
    waves = waves_file(path)
    with open(waves, "rb") as f:
        head = f.read(WAVES_HEADER_BYTES)
    if len(head) < 20 or not head.startswith(WAVES_SIGNATURE):
        raise WaveformFileError(f"{waves}: not a PulseWaves waves file (signature {head[:15]!r})")
    compression = struct.unpack_from("<I", head, 16)[0]
    if compression != 0:
        raise WaveformFileError(f"{waves}: compressed waves (scheme {compression}) are not readable; "
                                "only uncompressed waves are defined")
    if geokeys:
        wkt, source = wkt_from_geokeys(geokeys)
    elif looks_earth_centred(header.bounds_min, header.bounds_max):
        wkt, source = wkt_from_epsg(4978), "none in the file; Earth-centred by its coordinates' magnitude (EPSG:4978)"
    else:
        wkt, source = None, "none"
    return PulseWavesFile(path, waves, header, descriptors, scanners, tables, wkt, source, present, tuple(problems))


def _head_and_tail(path: Path) -> bytes:
    """Large files: the header and VLRs only (AVLRs of large files are read from the tail separately)."""
    with open(path, "rb") as f:
        head = f.read(PULSE_HEADER.size)
        if len(head) < PULSE_HEADER.size:
            return head
        offset_to_pulses = struct.unpack_from("<q", head, 176)[0]
        f.seek(0)
        return f.read(max(offset_to_pulses, PULSE_HEADER.size))


# ---------------------------------------------------------------- waves

@dataclasses.dataclass(frozen=True)
class _Layout:
    """The descriptors as flat arrays for the waves kernel."""

    first: np.ndarray  # per descriptor index (0..255): first sampling row; -1: unusable
    count: np.ndarray
    extra: np.ndarray
    bits_duration: np.ndarray  # per sampling row
    bits_segments: np.ndarray
    bits_samples: np.ndarray
    n_segments: np.ndarray
    n_samples: np.ndarray
    sample_bytes: np.ndarray
    kind: np.ndarray  # per sampling row: 1 outgoing, 2 returning
    channel: np.ndarray
    bits: np.ndarray
    spacing_ps: np.ndarray  # the sampling's sample spacing
    unit_ps: np.ndarray  # its composition's sampling unit
    duration_scale: np.ndarray
    duration_offset: np.ndarray
    optical_center: np.ndarray  # its composition's optical centre to anchor (sampling units)
    lookup_table: np.ndarray  # the sampling's lookup table index (0: none)


def _layout(descriptors: dict[int, PulseDescriptor]) -> _Layout:
    first, count, extra = np.full(256, -1, np.int64), np.zeros(256, np.int64), np.zeros(256, np.int64)
    rows, owners = [], []
    for index, d in descriptors.items():
        if d.problem is None and 0 <= index < 256:
            first[index], count[index], extra[index] = len(rows), len(d.samplings), d.extra_wave_bytes
            rows += d.samplings
            owners += [d] * len(d.samplings)

    def col(f, dtype=np.int64):
        return np.array([f(s) for s in rows], dtype=dtype)

    return _Layout(first, count, extra, col(lambda s: s.bits_for_duration), col(lambda s: s.bits_for_segments),
                   col(lambda s: s.bits_for_samples), col(lambda s: s.number_of_segments),
                   col(lambda s: s.number_of_samples), col(lambda s: s.bits_per_sample // 8),
                   col(lambda s: s.type), col(lambda s: s.channel), col(lambda s: s.bits_per_sample),
                   col(lambda s: s.sample_units_ns * 1000.0, np.float64),
                   np.array([d.sample_units_ns * 1000.0 for d in owners], np.float64),
                   col(lambda s: s.duration_scale, np.float64), col(lambda s: s.duration_offset, np.float64),
                   np.array([d.optical_center_to_anchor for d in owners], np.int64),
                   col(lambda s: s.lookup_table))


@njit(**JIT)
def _unsigned(data, at, bits):
    value = np.int64(0)
    for b in range(bits // 8):
        value |= np.int64(data[at + b]) << (8 * b)
    return value


@njit(**JIT)
def _signed(data, at, bits):
    value = _unsigned(data, at, bits)
    if bits > 0 and value >= (np.int64(1) << (bits - 1)):
        value -= np.int64(1) << bits
    return value


@njit(**JIT)
def _walk_waves(data, offsets, descriptor, first, count, extra, bits_duration, bits_segments, bits_samples,
                n_segments, n_samples, sample_bytes, fill, seg_pulse, seg_sampling, seg_index, seg_duration,
                seg_count, seg_at):
    """Walk each pulse's waves: per sampling its segments (duration, count, samples).

    Returns per pulse the number of segments (or -1: descriptor unusable, -2: runs past the file's end)
    and the byte after its waves; with `fill`, writes each segment's pulse, sampling, index, stored
    duration D, sample count and first byte.
    """
    n = offsets.size
    segments = np.zeros(n, np.int64)
    ends = np.zeros(n, np.int64)
    size = data.size
    k = 0
    for p in range(n):
        d = descriptor[p]
        if first[d] < 0:
            segments[p] = -1
            continue
        at = offsets[p] + extra[d]
        bad = at < 0 or at > size
        found = 0
        for m in range(first[d], first[d] + count[d]):
            if bad:
                break
            nseg = n_segments[m]
            if bits_segments[m] > 0:
                if at + bits_segments[m] // 8 > size:
                    bad = True
                    break
                nseg = _unsigned(data, at, bits_segments[m])
                at += bits_segments[m] // 8
            for s in range(nseg):
                head = (bits_duration[m] + bits_samples[m]) // 8
                if at + head > size:
                    bad = True
                    break
                duration = _signed(data, at, bits_duration[m])
                at += bits_duration[m] // 8
                count_s = n_samples[m]
                if bits_samples[m] > 0:
                    count_s = _unsigned(data, at, bits_samples[m])
                    at += bits_samples[m] // 8
                if at + count_s * sample_bytes[m] > size:
                    bad = True
                    break
                if fill:
                    seg_pulse[k] = p
                    seg_sampling[k] = m - first[d]
                    seg_index[k] = s
                    seg_duration[k] = duration
                    seg_count[k] = count_s
                    seg_at[k] = at
                k += 1
                found += 1
                at += count_s * sample_bytes[m]
        if bad:
            k -= found
            segments[p] = -2
        else:
            segments[p] = found
        ends[p] = at
    return segments, ends


@njit(**JIT)
def _ends_with(data, end, length, other, other_length):
    """Per pulse: whether the `length` bytes before `end` equal the `other_length` bytes at `other`
    (compared when both are at least 16 bytes and fit the data)."""
    out = np.zeros(end.size, np.bool_)
    for p in range(end.size):
        n = other_length[p]
        if n < 16 or length[p] < n or other[p] < 0 or end[p] - n < 0 or other[p] + n > data.size:
            continue
        same = True
        for b in range(n):
            if data[end[p] - n + b] != data[other[p] + b]:
                same = False
                break
        out[p] = same
    return out


def _gather(data: np.ndarray, at: np.ndarray, count: np.ndarray, nbytes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples of segments (first byte, count, bytes per sample) as one float64 array and its offsets."""
    offsets = np.zeros(at.size + 1, np.int64)
    np.cumsum(count, out=offsets[1:])
    out = np.empty(offsets[-1], np.float64)
    _gather_kernel(data, np.asarray(at, np.int64), np.asarray(nbytes, np.int64), offsets, out)
    return out, offsets


@njit(**JIT)
def _gather_kernel(data, at, nbytes, offsets, out):
    for i in range(at.size):
        for j in range(offsets[i + 1] - offsets[i]):
            b = at[i] + nbytes[i] * j
            value = np.int64(data[b])
            if nbytes[i] == 2:
                value |= np.int64(data[b + 1]) << 8
            out[offsets[i] + j] = value


# ---------------------------------------------------------------- plan and read

def plan_pulse_ranges(path: str | Path, pulses_per_range: int = 10_000,
                      pw: PulseWavesFile | None = None) -> list[PointRange]:
    """Ranges of pulse records; a pulse's waves are all in its own record, so ranges never share pulses."""
    pw = pw or open_pulsewaves(path)
    if pulses_per_range < 1:
        raise ValueError(f"pulses per range must be at least 1, not {pulses_per_range}")
    _warn_unusable(pw)
    n = pw.point_count
    if n == 0:
        return [PointRange(str(path), 0, 0, n_pulses=0, problems=pw.problems)] if pw.problems else []
    return [PointRange(str(path), start, min(n, start + pulses_per_range), n_pulses=min(n, start + pulses_per_range)
                       - start, problems=pw.problems if start == 0 else ())
            for start in range(0, n, pulses_per_range)]


def _warn_unusable(pw: PulseWavesFile, chunk_pulses: int = 1_000_000) -> None:
    used = np.zeros(256, np.int64)  # pulses per descriptor index, a chunk at a time: memory bounded
    for at in range(0, pw.point_count, chunk_pulses):
        used += np.bincount(np.asarray(pw.records(at, at + chunk_pulses)["descriptor"]), minlength=256)[:256]
    warn_unusable(pw.path.name, {d.index: d.problem for d in pw.descriptors.values() if d.problem}, used, "pulses")


def read_pulsewaves(point_range: PointRange | str | Path, pw: PulseWavesFile | None = None) -> PulseBatch:
    """One waveform a pulse of a range (see the module's docstring); pulses that cannot be read are rejected."""
    if not isinstance(point_range, PointRange):
        pw = pw or open_pulsewaves(point_range)
        point_range = PointRange(str(point_range), 0, pw.point_count, problems=pw.problems)
    pw = pw or open_pulsewaves(point_range.path)
    header, name = pw.header, pw.path.name
    stop = min(point_range.stop, pw.point_count)
    if point_range.max_pulses is not None:
        stop = min(stop, point_range.start + point_range.max_pulses)
    walked = np.array(pw.records(point_range.start, stop + 1))  # one more: the next pulse's waves bound these
    n = max(0, stop - point_range.start)
    records = walked[:n]
    rejected = [(-1, reason) for reason in point_range.problems]
    anchor, direction, zero_beam, gps_time, pulse_id = _pulse_geometry(records, header)

    data = np.memmap(pw.waves_path, dtype=np.uint8, mode="r")
    layout = _layout(pw.descriptors)
    counts, wave_offsets, descriptor, misfit, (seg_pulse, seg_duration, seg_count, seg_at, row, kind) = \
        _walk_segments(data, walked, layout, n)

    reason = _pulse_reasons(pw, data.size, counts, wave_offsets, descriptor, misfit, zero_beam)
    ok_segment = reason[seg_pulse] == None  # noqa: E711
    returning = ok_segment & (kind == RETURNING) & (seg_count > 0)
    has_return = np.zeros(n, bool)
    has_return[seg_pulse[returning]] = True
    for i in np.flatnonzero(~has_return & (reason == None)):  # noqa: E711
        reason[i] = f"{name}: the pulse has no returning samples"
    rejected += [(int(pulse_id[i]), str(reason[i])) for i in np.flatnonzero(reason != None)]  # noqa: E711

    # one waveform a pulse: the segments of the one returning sampling it is decomposed from, joined
    rows, samples, sample_offsets, joined, dropped = _pulse_waveforms(
        data, np.flatnonzero(returning), seg_pulse, row, seg_duration, seg_count, seg_at, layout, pw.lookup_tables)
    rejected += [(int(pulse_id[p]), f"{name}: {problem}") for p, problem in dropped]
    owner, r = seg_pulse[rows], row[rows]
    unit_ps = layout.unit_ps[r]
    duration = layout.duration_scale[r] * seg_duration[rows] + layout.duration_offset[r]
    bits = layout.bits[r].astype(np.int16)
    segment = (joined - 1).astype(np.int16)  # returning segments the row joins after its first
    outgoing, outgoing_offsets, outgoing_spacing = _outgoing_waveforms(
        data, n, owner, np.flatnonzero(ok_segment & (kind == OUTGOING) & (seg_count > 0)), seg_pulse, seg_count,
        seg_at, row, layout)
    flags = records["flags"][owner]
    zeros = np.zeros(rows.size)
    # the optical centre is oc sampling units back from the anchor, where the descriptor gives a constant oc
    optical_center = layout.optical_center[r]
    varies = (optical_center == VARIES) | (optical_center == VARIES - (1 << 32))
    sensor_location_ps = np.where(varies, np.nan, (-duration - optical_center) * unit_ps)
    return PulseBatch(
        source_file=str(pw.path),
        pulse_id=pulse_id[owner],
        packet_offset=wave_offsets[owner],
        descriptor_index=descriptor[owner].astype(np.int16),
        gps_time=gps_time[owner],
        anchor=anchor[owner],
        anchor_location_ps=-duration * unit_ps,
        sensor_location_ps=sensor_location_ps,
        direction=-direction[owner] / unit_ps[:, None],
        scan_angle=zeros,
        point_source_id=np.zeros(rows.size, np.uint16),
        scan_direction_flag=((flags >> 5) & 1).astype(np.uint8),
        edge_of_flight_line=((flags >> 4) & 1).astype(np.uint8),
        user_data=np.zeros(rows.size, np.uint8),
        sample_spacing_ps=layout.spacing_ps[r],
        digitizer_gain=np.ones(rows.size),
        digitizer_offset=zeros,
        bits_per_sample=bits,
        samples=samples,
        sample_offsets=sample_offsets,
        return_xyz=np.zeros((0, 3)),
        return_number=np.zeros(0, np.uint8),
        return_intensity=np.zeros(0, np.uint16),
        return_location_ps=np.zeros(0),
        return_offsets=np.zeros(rows.size + 1, np.int64),
        classification=records["classification"][owner].astype(np.uint8),
        channel=layout.channel[r].astype(np.int16),
        segment=segment,
        outgoing=outgoing, outgoing_offsets=outgoing_offsets, outgoing_spacing_ps=outgoing_spacing,
        rejected=tuple(rejected),
    )


def _pulse_geometry(records: np.ndarray, header: PulseHeader):
    """Per pulse record: its anchor, direction (world units per sampling unit), whether it has none (target at
    the anchor), GPS time and identity."""
    scales, offsets = np.asarray(header.scales), np.asarray(header.offsets)
    anchor_raw = records["anchor"].astype(np.float64)
    target_raw = records["target"].astype(np.float64)
    direction = ((target_raw - anchor_raw) * scales) / 1000.0
    gps_time = records["T"].astype(np.float64) * header.t_scale + header.t_offset
    pulse_id = pulse_identity(records["T"].astype(np.float64), anchor_raw, target_raw, quantum=1.0)
    return anchor_raw * scales + offsets, direction, ~np.any(target_raw != anchor_raw, axis=1), gps_time, pulse_id


def _walk_segments(data: np.ndarray, walked: np.ndarray, layout: _Layout, n: int):
    """The waves of the first n of the `walked` records (one more bounds their waves): per pulse its segment
    count (or -1, -2: _walk_waves), offset to waves, descriptor and whether its waves are mis-encoded; per
    segment of those n its pulse, stored duration, sample count, first byte, sampling row and kind."""
    wave_offsets = walked["offset"].astype(np.int64)
    descriptor = walked["descriptor"].astype(np.int64)
    args = (layout.first, layout.count, layout.extra, layout.bits_duration, layout.bits_segments,
            layout.bits_samples, layout.n_segments, layout.n_samples, layout.sample_bytes)
    empty = np.zeros(0, np.int64)
    counts, ends = _walk_waves(data, wave_offsets, descriptor, *args, False, empty, empty, empty, empty, empty, empty)
    total = int(counts[counts > 0].sum())
    seg = [np.zeros(total, np.int64) for _ in range(6)]
    _walk_waves(data, wave_offsets, descriptor, *args, True, *seg)
    seg_pulse, seg_sampling, _, seg_duration, seg_count, seg_at = seg
    row = layout.first[descriptor[seg_pulse]] + seg_sampling  # each segment's sampling row in the layout
    kind = layout.kind[row]
    seg_end = seg_at + seg_count * layout.sample_bytes[row]
    misfit = _misencoded(data, n, wave_offsets, counts, ends, seg_pulse, seg_at, seg_count, seg_end, kind,
                         layout.sample_bytes[row])
    keep = seg_pulse < n
    segments = tuple(a[keep] for a in (seg_pulse, seg_duration, seg_count, seg_at, row, kind))
    return counts[:n], wave_offsets[:n], descriptor[:n], misfit, segments


def _pulse_reasons(pw: PulseWavesFile, waves_size: int, counts: np.ndarray, wave_offsets: np.ndarray,
                   descriptor: np.ndarray, misfit: np.ndarray, zero_beam: np.ndarray) -> np.ndarray:
    """Per pulse, why it cannot be read (None: it can): its descriptor, waves past the file's end, waves that
    do not match the descriptor, no direction."""
    name = pw.path.name
    reason = np.full(counts.size, None, dtype=object)
    for i in np.flatnonzero(counts == -1):
        d = pw.descriptors.get(int(descriptor[i]))
        reason[i] = f"{name}: " + (d.problem if d else f"pulse descriptor index {descriptor[i]} has no descriptor")
    for i in np.flatnonzero(counts == -2):
        reason[i] = (f"{name}: the waves at byte {wave_offsets[i]} run past the end of {pw.waves_path.name} "
                     f"({waves_size} bytes) as pulse descriptor {descriptor[i]} lays them out")
    for i in np.flatnonzero(misfit & (reason == None)):  # noqa: E711
        reason[i] = (f"{name}: the waves at byte {wave_offsets[i]} do not match pulse descriptor {descriptor[i]} "
                     "(mis-encoded: they overlap the next pulse's waves or end with its outgoing samples); "
                     "not decomposed")
    for i in np.flatnonzero(zero_beam & (reason == None)):  # noqa: E711
        reason[i] = f"{name}: target equals anchor: the pulse has no direction"
    return reason


def _outgoing_waveforms(data, n, owner, out_seg, seg_pulse, seg_count, seg_at, row, layout: _Layout):
    """The first outgoing segment (`out_seg`: the readable ones) of each row's pulse, where recorded: its
    samples, offsets and sample spacing per row."""
    pulse_out = np.full(n, -1, np.int64)
    pulse_out[seg_pulse[out_seg[::-1]]] = out_seg[::-1]
    pick = pulse_out[owner]
    has = pick >= 0
    safe = np.maximum(pick, 0)
    out_count = np.where(has, seg_count[safe], 0) if seg_count.size else np.zeros(owner.size, np.int64)
    out_at = np.where(has, seg_at[safe], 0) if seg_at.size else np.zeros(owner.size, np.int64)
    out_bytes = layout.sample_bytes[row[safe]] if row.size else np.ones(owner.size, np.int64)
    outgoing, outgoing_offsets = _gather(data, out_at, out_count, out_bytes)
    outgoing_spacing = np.where(has, layout.spacing_ps[row[safe]] if row.size else 0.0, 0.0)
    return outgoing, outgoing_offsets, outgoing_spacing


def _saturation_codes(layout: _Layout, tables: dict[int, LookupTable]) -> np.ndarray:
    """Per sampling row: the first sample code at which it saturates (LookupTable.saturation_code)."""
    codes = (np.int64(1) << layout.bits) - 1
    for m, index in enumerate(layout.lookup_table):
        table = tables.get(int(index))
        if table is not None and table.entries.size:
            codes[m] = table.saturation_code(int(layout.bits[m]))
    return codes


def _one_sampling(raw: np.ndarray, offsets: np.ndarray, pulse: np.ndarray, row: np.ndarray,
                  saturation: np.ndarray) -> np.ndarray:
    """Per returning segment: whether it is of the one sampling its pulse is decomposed from.

    Two channels of one pulse sample the same surfaces at two sensitivities (RIEGL: the low-power channel,
    sensitive, and the high-power one, recorded where the first saturates). Kept: the sampling without a
    saturated sample whose peak is highest against its full scale (the most sensitive that holds the
    signal); where all saturate, the one with the fewest saturated samples; ties, the first sampling.
    """
    # segments come in pulse, sampling order: a pulse has two samplings where one follows another in it
    if not ((pulse[1:] == pulse[:-1]) & (row[1:] != row[:-1])).any():
        return np.ones(pulse.size, bool)  # one returning sampling a pulse: nothing to choose
    starts = offsets[:-1]
    full = saturation[row].astype(np.float64)
    peak = np.maximum.reduceat(raw, starts) / full
    clipped = np.add.reduceat((raw >= np.repeat(full, np.diff(offsets))).astype(np.int64), starts)
    k = int(row.max()) + 1
    groups, inverse = np.unique(pulse * k + row, return_inverse=True)
    g_clipped = np.bincount(inverse, clipped, minlength=groups.size)
    g_peak = np.zeros(groups.size)
    np.maximum.at(g_peak, inverse, peak)
    g_pulse = groups // k
    order = np.lexsort((groups % k, -g_peak, g_clipped, g_pulse))
    first = order[np.r_[True, g_pulse[order][1:] != g_pulse[order][:-1]]]
    chosen = np.zeros(groups.size, bool)
    chosen[first] = True
    return chosen[inverse]


MAX_JOINED_SAMPLES = 1 << 16  # a pulse's segments joined span at most this many samples
GRID_TOLERANCE = 0.05  # segments of one sampling start within this many samples of one grid


def _join_segments(samples: np.ndarray, offsets: np.ndarray, pulse: np.ndarray, start: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[tuple[int, str]]]:
    """One waveform per pulse from the segments of its sampling (`start`: each segment's first sample, in
    samples from the anchor): a pulse of one segment keeps it as it is; several are placed on the first's
    sample grid, the gaps between them (where the digitizer recorded nothing: below detection) at the
    lowest sample the pulse recorded. Returns per waveform its first segment and how many it joins, the
    samples and offsets, and the pulses that cannot be joined with why."""
    if pulse.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), samples, offsets, []
    head = np.r_[True, pulse[1:] != pulse[:-1]]
    heads = np.flatnonzero(head)
    joined = np.diff(np.r_[heads, pulse.size])
    if (joined == 1).all():
        return heads, joined, samples, offsets, []
    pieces, lengths, keep, dropped = [], [], np.ones(heads.size, bool), []
    for w, (h, count) in enumerate(zip(heads, joined)):
        segs = np.arange(h, h + count)
        if count == 1:
            pieces.append(samples[offsets[h]:offsets[h + 1]])
            lengths.append(pieces[-1].size)
            continue
        shift = start[segs] - start[segs].min()
        at = np.rint(shift).astype(np.int64)
        span = int((at + np.diff(offsets)[segs]).max())
        off_grid, too_long = np.abs(shift - at).max() > GRID_TOLERANCE, span > MAX_JOINED_SAMPLES
        if off_grid or too_long:
            keep[w] = False
            dropped.append((int(pulse[h]), f"its {count} returning segments do not join into one waveform: " + (
                f"they start {', '.join(f'{v:g}' for v in np.round(shift, 2))} samples after the first, off "
                "one sample grid" if off_grid else f"they span {span} samples, more than {MAX_JOINED_SAMPLES}")))
            continue
        recorded = samples[offsets[h]:offsets[h + count]]
        wave = np.full(span, np.nanmin(recorded) if np.isfinite(recorded).any() else np.nan)
        for j, a in zip(segs, at):
            wave[a:a + offsets[j + 1] - offsets[j]] = samples[offsets[j]:offsets[j + 1]]
        pieces.append(wave)
        lengths.append(span)
        heads[w] = segs[np.argmin(start[segs])]
    out_offsets = np.zeros(len(pieces) + 1, np.int64)
    np.cumsum(lengths, out=out_offsets[1:])
    return heads[keep], joined[keep], np.concatenate(pieces) if pieces else samples[:0], out_offsets, dropped


def _pulse_waveforms(data, returning, seg_pulse, row, seg_duration, seg_count, seg_at, layout: _Layout,
                     tables: dict[int, LookupTable]):
    """The pulses' waveforms from their returning segments (`returning`, walked in pulse, sampling, segment
    order): one sampling a pulse (_one_sampling), its segments joined (_join_segments), through its lookup
    table. Returns each waveform's first segment, samples, offsets, segments joined and the pulses dropped."""
    r = row[returning]
    raw, offsets = _gather(data, seg_at[returning], seg_count[returning], layout.sample_bytes[r])
    keep = _one_sampling(raw, offsets, seg_pulse[returning], r, _saturation_codes(layout, tables))
    if not keep.all():
        raw = raw[np.repeat(keep, np.diff(offsets))]
        returning, r = returning[keep], r[keep]
        offsets = np.r_[0, np.cumsum(seg_count[returning])].astype(np.int64)
    samples = linear_samples(raw, offsets, layout.lookup_table[r], tables)
    start = (layout.duration_scale[r] * seg_duration[returning] + layout.duration_offset[r]) \
        * layout.unit_ps[r] / layout.spacing_ps[r]
    heads, joined, samples, offsets, dropped = _join_segments(samples, offsets, seg_pulse[returning], start)
    return returning[heads], samples, offsets, joined, dropped


def linear_samples(samples: np.ndarray, offsets: np.ndarray, table_of_segment: np.ndarray,
                   tables: dict[int, LookupTable]) -> np.ndarray:
    """Samples through their sampling's lookup table, where it has one (the spec: the table maps a sample to the
    physical value measured), as LookupTable.power gives them: a dB table gives back power, 10^(dB / 10), so
    that every model sees a signal proportional to power; a code the table marks "no value" (below
    detection) gives 0. A code beyond the table is NaN (its pulse is then not decomposed, and says why)."""
    out = samples
    for index in np.unique(table_of_segment[table_of_segment != 0]):
        table = tables.get(int(index))
        if table is None or table.entries.size == 0:
            continue  # fwl info lists the sampling's missing table; the codes stay
        values = table.power()
        segments = np.flatnonzero(table_of_segment == index)
        at = np.concatenate([np.arange(offsets[s], offsets[s + 1]) for s in segments])
        codes = samples[at].astype(np.int64)
        out = out.copy() if out is samples else out
        out[at] = np.where(codes < values.size, values[np.minimum(codes, values.size - 1)], np.nan)
    return out


def _misencoded(data, n, wave_offsets, counts, ends, seg_pulse, seg_at, seg_count, seg_end, kind, sample_bytes):
    """Pulses (of the first n walked) whose waves cannot be what their descriptor says: they run into the
    next pulse's waves, or their last returning segment ends with the next pulse's outgoing samples
    (GeoLas's converter wrote 8-bit outgoing samples under a 16-bit descriptor and padded with those)."""
    m = wave_offsets.size
    next_start = np.append(wave_offsets[1:], [data.size]) if m else wave_offsets
    increasing = np.append(wave_offsets[1:] > wave_offsets[:-1], [True]) if m else np.zeros(0, bool)
    overlap = (counts >= 0) & increasing & (ends > next_start)
    last_return = np.full(m, -1, np.int64)
    ret = np.flatnonzero(kind == RETURNING)
    last_return[seg_pulse[ret]] = ret
    first_out = np.full(m, -1, np.int64)
    out = np.flatnonzero(kind == OUTGOING)
    first_out[seg_pulse[out[::-1]]] = out[::-1]
    nxt = np.append(first_out[1:], [-1]) if m else first_out
    lr, no = np.maximum(last_return, 0), np.maximum(nxt, 0)
    valid = (last_return >= 0) & (nxt >= 0) & (counts >= 0) & np.append(counts[1:] >= 0, [False])
    end = np.where(valid, seg_end[lr] if seg_end.size else 0, 0)
    length = np.where(valid, (seg_count * sample_bytes)[lr] if seg_end.size else 0, 0)
    other = np.where(valid, seg_at[no] if seg_at.size else -1, -1)
    # as many bytes as the next pulse has outgoing samples: mis-encoded 16-bit ones are 8-bit on disk
    other_length = np.where(valid, seg_count[no] if seg_at.size else 0, 0)
    padded = _ends_with(data, end.astype(np.int64), length.astype(np.int64), other.astype(np.int64),
                        other_length.astype(np.int64))
    return (overlap | padded)[:n]


# ---------------------------------------------------------------- fwl info
