"""Reading full-waveform LAS/LAZ files as pulses, in ranges of points.

A pulse is the set of points sharing one packet (same descriptor, same byte
offset): its samples are read once and its points are kept as the system's
returns. A file is read in ranges of points; `plan_las_ranges` makes every
pulse belong to exactly one range (the range of its first point), also when
its points lie far apart, and tells each range which outside points to add
and which of its points to leave to another range.

Uncompressed point records are memory-mapped and read as laspy packed
records; LAZ goes through laspy's decompressor. Every point record the header
promises is read or reported missing (`WaveformFile.problems`).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator
from pathlib import Path

import laspy
import numpy as np

from fwcore.io.descriptors import WaveformDescriptor, read_descriptors, warn_unusable
from fwcore.io.errors import ForeignWaveformFileError, WaveformFileError
from fwcore.io.ownership import BUCKET_POINTS, KEY_SHIFT, pulse_ownership
from fwcore.io.packets import PacketStore, external_packet_file, lastools_compression
from fwcore.io.records import PointRange, PulseBatch, pulse_identity
from fwcore.io.signatures import LAS_SIGNATURE

LOG = logging.getLogger("fwl")
MAX_BEAM_REACH_M = 20_000.0  # farther than any airborne range from a pulse's own return
MAX_GPS_TIME_S = 2e9  # adjusted standard GPS time spans 1980-2043 within +-1e9 s; week time < 604800 s
OFFSET_MASK = np.int64((1 << 48) - 1)  # a packet key's byte offset bits (ownership.KEY_SHIFT)


@dataclasses.dataclass(frozen=True)
class PointFormat:
    """What differs between the full-waveform point formats, in one place."""

    scan_angle_field: str
    scan_angle_degrees: float  # degrees per stored unit
    rgb: bool
    nir: bool


POINT_FORMATS = {
    4: PointFormat("scan_angle_rank", 1.0, rgb=False, nir=False),
    5: PointFormat("scan_angle_rank", 1.0, rgb=True, nir=False),
    9: PointFormat("scan_angle", 0.006, rgb=False, nir=False),
    10: PointFormat("scan_angle", 0.006, rgb=True, nir=True),
}
WAVEFORM_POINT_FORMATS = tuple(POINT_FORMATS)


@dataclasses.dataclass(frozen=True)
class WaveformFile:
    path: Path
    version: str
    point_format: int
    point_count: int  # point records we read: those present, whatever the header says
    descriptors: dict[int, WaveformDescriptor]
    packets: PacketStore
    header_point_count: int = -1  # what the header promises
    compressed: bool = False  # LAZ
    problems: tuple[str, ...] = ()  # file-level findings that lose points, each naming the file
    adjusted_standard_gps_time: bool = False  # global encoding bit 0: GPS time - 1e9 s, else week seconds

    @property
    def quirks(self) -> PointFormat:
        return POINT_FORMATS[self.point_format]


def _point_region_end(header, size: int) -> int:
    """The byte where point records must end: the packet record, the first EVLR or the end of the file."""
    ends = [size]
    start_wdp = int(getattr(header, "start_of_waveform_data_packet_record", 0) or 0)
    if header.global_encoding.waveform_data_packets_internal and header.offset_to_point_data < start_wdp < size:
        ends.append(start_wdp)
    if getattr(header, "number_of_evlrs", 0) and header.offset_to_point_data < header.start_of_first_evlr < size:
        ends.append(int(header.start_of_first_evlr))
    return min(ends)


def open_waveform_file(path: str | Path, read_evlrs: bool = True) -> WaveformFile:
    """Check a file and find its descriptors and packets; errors name the file and the problem. `read_evlrs`
    False: its EVLRs neither read nor checked (a planned range's file, checked whole by its plan)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    size = path.stat().st_size
    if size == 0:
        raise WaveformFileError(f"{path}: empty file")
    try:
        with laspy.open(path, read_evlrs=read_evlrs) as reader:
            header = reader.header
    except Exception as err:  # laspy raises several types for a damaged header
        message = f"{path}: not a readable LAS/LAZ file ({err})"
        try:
            with open(path, "rb") as f:
                head = f.read(len(LAS_SIGNATURE))
        except OSError:
            head = b""
        if head == LAS_SIGNATURE:  # a LAS file, damaged
            raise WaveformFileError(message) from None
        # another kind of file: the table of formats says which (fwcore.io.formats)
        raise ForeignWaveformFileError(message, path, "a LAS/LAZ or PulseWaves file", str(err)) from None
    fmt = header.point_format.id
    if fmt not in WAVEFORM_POINT_FORMATS:
        raise WaveformFileError(f"{path}: point format {fmt} has no waveform packets "
                                f"(full-waveform formats are {', '.join(map(str, WAVEFORM_POINT_FORMATS))})")
    for axis, scale, offset in zip("xyz", header.scales, header.offsets):
        # bounds far beyond any survey's (1e-9 degrees to km; the Earth's size): a damaged header, not data
        if not (1e-12 <= abs(scale) <= 1e4 and abs(offset) <= 1e10):
            raise WaveformFileError(f"{path}: the header's {axis} scale {scale} / offset {offset} cannot give "
                                    "coordinates (a scale must be finite and non-zero, within 1e-12..1e4, "
                                    "an offset finite, within +-1e10)")
    encoding = header.global_encoding
    if encoding.waveform_data_packets_external:
        packet_file = external_packet_file(path)
        if packet_file.stat().st_size == 0:
            raise WaveformFileError(f"{path}: its waveform packet file {packet_file.name} is empty")
        store = PacketStore(packet_file, 0, bool(lastools_compression(packet_file)))
    elif encoding.waveform_data_packets_internal or header.start_of_waveform_data_packet_record:
        # LAS 1.3's field, or LAS 1.4's pointing at the EVLR 65535 header: offsets count from there
        start = int(header.start_of_waveform_data_packet_record)
        if start <= 0 or start >= size:
            raise WaveformFileError(f"{path}: internal waveform packets announced at byte {start}, "
                                    f"outside the file ({size} bytes)")
        store = PacketStore(path, start, False)
    else:
        raise WaveformFileError(f"{path}: the header says neither internal nor external waveform packets")
    descriptors = read_descriptors(header.vlrs, store.compressed)
    if not descriptors:
        raise WaveformFileError(f"{path}: no waveform packet descriptor (VLR record ids 100-354)")
    promised = int(header.point_count)
    present, problems = promised, []
    laz = header.are_points_compressed if hasattr(header, "are_points_compressed") else path.suffix.lower() == ".laz"
    if not laz:
        record = header.point_format.size
        present = max(0, (_point_region_end(header, size) - header.offset_to_point_data) // record)
        if present < promised:
            problems.append(f"{path}: truncated: {present} of {promised} point records present")
        elif present > promised:
            LOG.warning("%s: the header promises %d point records but the file holds %d; reading all %d",
                        path, promised, present, present)
    return WaveformFile(path, f"{header.version.major}.{header.version.minor}", fmt, present, descriptors, store,
                        promised, laz, tuple(problems), int(encoding.gps_time_type) == 1)


# ---------------------------------------------------------------- points

def _point_records(data: np.ndarray | None, reader, start: int, stop: int, extra: tuple[int, ...] = ()):
    """laspy packed records of points [start, stop) plus `extra`, in that order."""
    point_format = reader.header.point_format
    if data is not None:  # uncompressed: straight from the memory map
        rows = data[start:stop] if not extra else np.concatenate([data[start:stop], data[np.asarray(extra)]])
        return laspy.PackedPointRecord(np.array(rows), point_format)
    reader.seek(start)
    parts = [np.asarray(reader.read_points(stop - start).array)]
    for p in extra:
        reader.seek(p)
        parts.append(np.asarray(reader.read_points(1).array))
    return laspy.PackedPointRecord(np.concatenate(parts), point_format)


class PointRecords:
    """An open file's point records: a memory map for LAS, laspy's reader for LAZ."""

    def __init__(self, wf: WaveformFile):
        self.wf = wf
        try:
            # the EVLRs were read by open_waveform_file, if at all: LAS 1.4's hold the packets, megabytes each open
            self.reader = laspy.open(wf.path, read_evlrs=False)
        except Exception as err:
            raise WaveformFileError(f"{wf.path}: not a readable LAS/LAZ file ({err})") from None
        self.data = None
        if not wf.compressed and wf.point_count:
            header = self.reader.header
            self.data = np.memmap(wf.path, dtype=header.point_format.dtype(), mode="r",
                                  offset=header.offset_to_point_data, shape=(wf.point_count,))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.reader.close()

    def read(self, start: int, stop: int, extra: tuple[int, ...] = ()):
        try:
            return _point_records(self.data, self.reader, start, stop, extra)
        except WaveformFileError:
            raise
        except Exception as err:  # lazrs on a truncated or corrupt chunk
            raise WaveformFileError(f"{self.wf.path}: point records {start}..{stop} cannot be read "
                                    f"({type(err).__name__}: {err})") from None

    def chunks(self, chunk_points: int = 1_000_000) -> Iterator[tuple[int, np.ndarray]]:
        """(first point, point records) chunk by chunk; uncompressed records are read, not mapped, so that a
        pass over the whole file never keeps it resident."""
        header = self.reader.header
        for at in range(0, self.wf.point_count, chunk_points):
            stop = min(self.wf.point_count, at + chunk_points)
            if self.data is not None:
                yield at, np.fromfile(self.wf.path, dtype=self.data.dtype, count=stop - at,
                                      offset=header.offset_to_point_data + at * self.data.dtype.itemsize)
            else:
                yield at, self.read(at, stop).array


def packet_keys(points) -> np.ndarray:
    """Each point's packet as one int64 (descriptor index << KEY_SHIFT | byte offset); -1: it points at none."""
    index = np.asarray(points["wavepacket_index"]).astype(np.int64)
    offset = np.asarray(points["wavepacket_offset"]).astype(np.int64)
    return np.where((index > 0) & (offset >= 0) & (offset <= OFFSET_MASK), (index << KEY_SHIFT) | offset, -1)


# ---------------------------------------------------------------- plan

def plan_las_ranges(path: str | Path, points_per_range: int = 10_000, chunk_points: int = 1_000_000,
                    bucket_points: int = BUCKET_POINTS, wf: WaveformFile | None = None) -> list[PointRange]:
    """Split a file into point ranges so that every pulse belongs to exactly one.

    One streaming pass reads the packet keys; `pulse_ownership` finds each pulse's owner in memory bounded
    by `chunk_points` and `bucket_points`, whatever the file's size. The file's problems (points the header
    promises but the file lacks) travel with the first range, which reports them.
    """
    path = Path(path)
    wf = wf or open_waveform_file(path)
    if points_per_range < 1:
        raise ValueError(f"points per range must be at least 1, not {points_per_range}")
    n = wf.point_count
    if n == 0:
        return [PointRange(str(path), 0, 0, n_pulses=0, problems=wf.problems)] if wf.problems else []
    with PointRecords(wf) as points:
        key_chunks = ((at, packet_keys(rows)) for at, rows in points.chunks(chunk_points))
        owned = pulse_ownership(key_chunks, n, points_per_range, bucket_points)
    warn_unusable(wf.path.name, {i: d.problem for i, d in wf.descriptors.items() if d.problem},
                  owned.descriptor_points, "points' pulses")
    straying, stray_owner = owned.straying, owned.stray_owner
    by_owner = np.argsort(stray_owner, kind="stable")  # each range's extra points, in point order
    owner_bounds = np.searchsorted(stray_owner[by_owner], np.arange(len(owned.pulses_per_range) + 1))
    ranges = []
    for r, start in enumerate(range(0, n, points_per_range)):
        stop = min(n, start + points_per_range)
        extra = tuple(int(p) for p in straying[by_owner[owner_bounds[r]:owner_bounds[r + 1]]])
        foreign = tuple(int(p) for p in straying[np.searchsorted(straying, start):np.searchsorted(straying, stop)])
        ranges.append(PointRange(str(path), start, stop, extra, foreign, int(owned.pulses_per_range[r]),
                                 problems=wf.problems if r == 0 else ()))
    return ranges


# ---------------------------------------------------------------- read

def _field(points, name: str, dtype=np.float64) -> np.ndarray:
    with np.errstate(invalid="ignore"):  # damaged records hold signalling NaNs; non-finite values are checked after
        return np.asarray(points[name]).astype(dtype)


def read_las_pulses(point_range: PointRange | str | Path, wf: WaveformFile | None = None) -> PulseBatch:
    """The pulses a range owns, with their samples and system returns.

    A pulse that cannot be read (its descriptor unusable, its packet lost,
    a non-finite field) is listed in `rejected` with the reason; so are the
    point records the file lacks, once, in the first range.
    """
    if not isinstance(point_range, PointRange):
        path = Path(point_range)
        wf = wf or open_waveform_file(path)
        point_range = PointRange(str(path), 0, wf.point_count, problems=wf.problems)
    wf = wf or open_waveform_file(point_range.path, read_evlrs=False)  # a planned range: its plan read them
    stop = min(point_range.stop, wf.point_count)
    extra = tuple(p for p in point_range.extra_points if p < wf.point_count)
    with PointRecords(wf) as source:
        points = source.read(point_range.start, stop, extra) if stop > point_range.start or extra else None
        scale, offset = source.reader.header.scales, source.reader.header.offsets
    rejected = [(-1, reason) for reason in point_range.problems]
    if points is None or len(points) == 0:
        return _empty_batch(str(wf.path), tuple(rejected))
    index = np.concatenate([np.arange(point_range.start, stop), np.asarray(extra, dtype=np.int64)])
    keys = packet_keys(points)
    keep = keys >= 0
    if point_range.foreign_points:
        keep &= ~np.isin(index, np.asarray(point_range.foreign_points))
    no_packet = int((keys < 0).sum())
    if no_packet and point_range.max_pulses is None:  # no pulse to put them in: reported, not dropped silently
        rejected.append((-1, f"{wf.path}: {no_packet} point records of points {point_range.start}..{stop - 1} "
                             "point at no waveform packet (descriptor index 0, or an impossible offset)"))
    xyz = np.stack([_field(points, "X") * scale[0] + offset[0], _field(points, "Y") * scale[1] + offset[1],
                    _field(points, "Z") * scale[2] + offset[2]], axis=1)
    order, pulse_keys, first_of, n_points = _pulses_of(points, index, keys, keep, point_range.max_pulses)
    anchors = order[first_of]
    gps_time = _field(points, "gps_time")[anchors]
    direction = np.stack([_field(points, c)[anchors] for c in ("x_t", "y_t", "z_t")], axis=1)
    location = _field(points, "return_point_wave_location")[anchors]
    pulse_id = pulse_identity(gps_time, xyz[anchors])
    d_index = (pulse_keys >> KEY_SHIFT).astype(np.int64)
    byte_offset = pulse_keys & OFFSET_MASK
    sizes = _field(points, "wavepacket_size", np.int64)[anchors]
    reason = _implausible(wf, gps_time, direction, location)
    got = _read_packets(wf, d_index, byte_offset, sizes, direction, location, reason)
    good = np.flatnonzero(reason == None)  # noqa: E711 (object array)
    rejected += [(int(pulse_id[i]), str(reason[i])) for i in np.flatnonzero(reason != None)]  # noqa: E711
    samples, sample_offsets = _flat_samples(got, good, pulse_keys.size)
    return _batch(wf, points, xyz, order, first_of, n_points, anchors, good, pulse_id, byte_offset, d_index,
                  gps_time, direction, location, samples, sample_offsets, tuple(rejected))


def _pulses_of(points, index: np.ndarray, keys: np.ndarray, keep: np.ndarray, max_pulses: int | None):
    """The kept points grouped by packet (`order`), and per pulse its key, where its points start in `order`
    and how many they are; pulses in file order of their first point, as a reader would meet them."""
    return_number = _field(points, "return_number", np.int64)
    sel = np.flatnonzero(keep)
    # within a pulse, order by return number so the first is the anchor
    order = sel[np.lexsort((return_number[sel], index[sel], keys[sel]))]
    pulse_keys, starts = np.unique(keys[order], return_index=True)
    bounds = np.append(starts, order.size)
    first_point = np.minimum.reduceat(index[order], starts) if order.size else np.zeros(0, np.int64)
    pulse_order = np.argsort(first_point, kind="stable")[:max_pulses]
    n_points = (bounds[1:] - bounds[:-1])[pulse_order]
    return order, pulse_keys[pulse_order], bounds[pulse_order], n_points


def _implausible(wf: WaveformFile, gps_time: np.ndarray, direction: np.ndarray, location: np.ndarray) -> np.ndarray:
    """Per pulse None, or why its fields rule it out (non-finite, a GPS time no flight has)."""
    reason = np.full(gps_time.size, None, dtype=object)
    finite = np.isfinite(direction).all(axis=1) & np.isfinite(location) & np.isfinite(gps_time)
    reason[~finite] = f"{wf.path.name}: non-finite x_t/y_t/z_t, return point location or GPS time"
    timeless = finite & ~(np.abs(gps_time) <= MAX_GPS_TIME_S)
    reason[timeless] = [f"{wf.path.name}: implausible GPS time {t:.6g} s" for t in gps_time[timeless]]
    return reason


def _read_packets(wf: WaveformFile, d_index: np.ndarray, byte_offset: np.ndarray, sizes: np.ndarray,
                  direction: np.ndarray, location: np.ndarray, reason: np.ndarray) -> dict:
    """The samples of the pulses `reason` leaves (None), descriptor by descriptor: {descriptor: (rows read,
    samples (k, n))}; why each other pulse is lost goes into `reason`."""
    finite = reason == None  # noqa: E711 (object array)
    got = {}
    data = wf.packets.open()
    for d in np.unique(d_index):
        mine = np.flatnonzero((d_index == d) & finite)
        descriptor = wf.descriptors.get(int(d))
        if descriptor is None:
            reason[mine] = f"{wf.path.name}: descriptor index {d} has no waveform packet descriptor"
            continue
        if descriptor.problem:
            reason[mine] = f"{wf.path.name}: {descriptor.problem}"
            continue
        # echoes lie L0 - t along the beam, t within the packet: a reach beyond any flight is a damaged record
        window_ps = descriptor.n_samples * descriptor.sample_spacing_ps
        reach = np.maximum(np.abs(location[mine]), np.abs(location[mine] - window_ps)) \
            * np.linalg.norm(direction[mine], axis=1)
        far = reach > MAX_BEAM_REACH_M
        reason[mine[far]] = [f"{wf.path.name}: implausible beam: its echoes would lie up to {r:.3g} m from the "
                             f"pulse's return (return point location, x_t/y_t/z_t)" for r in reach[far]]
        mine = mine[~far]
        values, problems = wf.packets.read_many(data, descriptor, byte_offset[mine], sizes[mine])
        lost = np.array([p is not None for p in problems], dtype=bool)
        reason[mine[lost]] = np.array([p for p in problems if p is not None], dtype=object)
        got[int(d)] = (mine[~lost], values[~lost])
    return got


def _flat_samples(got: dict, good: np.ndarray, n_pulses: int) -> tuple[np.ndarray, np.ndarray]:
    """The samples of the good pulses, flat, in pulse order, and the offset of each pulse's first sample."""
    n_samples = np.zeros(n_pulses, np.int64)
    for d, (rows, values) in got.items():
        n_samples[rows] = values.shape[1]
    sample_offsets = np.zeros(good.size + 1, dtype=np.int64)
    np.cumsum(n_samples[good], out=sample_offsets[1:])
    samples = np.empty(sample_offsets[-1], np.float64)
    position = np.full(n_pulses, -1, np.int64)
    position[good] = np.arange(good.size)
    for d, (rows, values) in got.items():
        if rows.size:
            samples[sample_offsets[position[rows]][:, None] + np.arange(values.shape[1])] = values
    return samples, sample_offsets


def _batch(wf, points, xyz, order, first_of, n_points, anchors, good, pulse_id, byte_offset, d_index, gps_time,
           direction, location, samples, sample_offsets, rejected) -> PulseBatch:
    quirks = wf.quirks
    a = anchors[good]
    counts = n_points[good]
    return_offsets = np.zeros(good.size + 1, dtype=np.int64)
    np.cumsum(counts, out=return_offsets[1:])
    # the points of each good pulse: order[first_of[i] : first_of[i] + n_points[i]]
    return_points = order[np.repeat(first_of[good], counts) + np.arange(return_offsets[-1])
                          - np.repeat(return_offsets[:-1], counts)]
    table = {name: np.zeros(256) for name in ("spacing", "gain", "offset", "bits")}
    for d in wf.descriptors.values():
        table["spacing"][d.index], table["gain"][d.index] = d.sample_spacing_ps, d.gain
        table["offset"][d.index], table["bits"][d.index] = d.offset, d.bits_per_sample
    dg = d_index[good]
    rgb = nir = None
    if quirks.rgb:
        rgb = np.stack([_field(points, c, np.uint16)[a] for c in ("red", "green", "blue")], axis=1)
    if quirks.nir:
        nir = _field(points, "nir", np.uint16)[a]
    location_all = _field(points, "return_point_wave_location")
    return PulseBatch(
        source_file=str(wf.path),
        pulse_id=pulse_id[good],
        packet_offset=byte_offset[good].astype(np.int64),
        descriptor_index=d_index[good].astype(np.int16),
        gps_time=gps_time[good],
        anchor=xyz[a],
        anchor_location_ps=location[good],
        direction=direction[good],
        scan_angle=_field(points, quirks.scan_angle_field)[a] * quirks.scan_angle_degrees,
        point_source_id=_field(points, "point_source_id", np.uint16)[a],
        scan_direction_flag=_field(points, "scan_direction_flag", np.uint8)[a],
        edge_of_flight_line=_field(points, "edge_of_flight_line", np.uint8)[a],
        user_data=_field(points, "user_data", np.uint8)[a],
        sample_spacing_ps=table["spacing"][dg],
        digitizer_gain=table["gain"][dg],
        digitizer_offset=table["offset"][dg],
        bits_per_sample=table["bits"][dg].astype(np.int16),
        samples=samples,
        sample_offsets=sample_offsets,
        return_xyz=xyz[return_points],
        return_number=_field(points, "return_number", np.uint8)[return_points],
        return_intensity=_field(points, "intensity", np.uint16)[return_points],
        return_location_ps=location_all[return_points],
        return_offsets=return_offsets,
        classification=_field(points, "classification", np.uint8)[a],
        channel=np.zeros(good.size, np.int16),
        segment=np.zeros(good.size, np.int16),
        rgb=rgb, nir=nir,
        rejected=rejected,
        number_of_returns=_field(points, "number_of_returns", np.uint8)[return_points],
    )


def _empty_batch(source_file: str, rejected: tuple = ()) -> PulseBatch:
    empty, none = np.zeros(0), np.zeros(0, np.int64)
    return PulseBatch(source_file, none, none, none.astype(np.int16), empty, np.zeros((0, 3)), empty,
                      np.zeros((0, 3)), empty, none.astype(np.uint16), none.astype(np.uint8), none.astype(np.uint8),
                      none.astype(np.uint8), empty, empty, empty, none.astype(np.int16), empty, np.zeros(1, np.int64),
                      np.zeros((0, 3)), none.astype(np.uint8), none.astype(np.uint16), empty, np.zeros(1, np.int64),
                      classification=none.astype(np.uint8), channel=none.astype(np.int16),
                      segment=none.astype(np.int16), rejected=rejected)
