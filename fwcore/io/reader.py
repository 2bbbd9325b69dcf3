"""Reading full-waveform LAS/LAZ files as pulses, in ranges of points.

A pulse is the set of points sharing one packet (same descriptor, same byte
offset): its samples are read once and its points are kept as the system's
returns. A file is read in ranges of points; `plan_point_ranges` makes every
pulse belong to exactly one range (the range of its first point), also when
its points lie far apart, and tells each range which outside points to add
and which of its points to leave to another range.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import laspy
import numpy as np

from fwcore.io.descriptors import WaveformDescriptor, read_descriptors
from fwcore.io.packets import (PacketError, PacketStore, external_packet_file,
                               lastools_compression)
from fwcore.io.records import PulseBatch

WAVEFORM_POINT_FORMATS = (4, 5, 9, 10)
_KEY_SHIFT = np.int64(48)  # key = descriptor index << 48 | byte offset


class WaveformFileError(ValueError):
    """A file that cannot be read as full-waveform LAS; the message names the file."""


@dataclasses.dataclass(frozen=True)
class WaveformFile:
    path: Path
    version: str
    point_format: int
    point_count: int
    descriptors: dict[int, WaveformDescriptor]
    packets: PacketStore


@dataclasses.dataclass(frozen=True)
class PointRange:
    """Points [start, stop) of a file, plus outside points of pulses it owns, minus points of pulses it does not."""

    path: str
    start: int
    stop: int
    extra_points: tuple[int, ...] = ()
    foreign_points: tuple[int, ...] = ()
    n_pulses: int = -1  # pulses this range owns (-1: not planned)
    max_pulses: int | None = None  # read only the first max_pulses of them (a run's --limit)


def open_waveform_file(path: str | Path) -> WaveformFile:
    """Check a file and find its descriptors and packets; errors name the file and the problem."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise WaveformFileError(f"{path}: empty file")
    try:
        with laspy.open(path) as reader:
            header = reader.header
    except Exception as err:  # laspy raises several types for a damaged header
        raise WaveformFileError(f"{path}: not a readable LAS/LAZ file ({err})") from None
    fmt = header.point_format.id
    if fmt not in WAVEFORM_POINT_FORMATS:
        raise WaveformFileError(f"{path}: point format {fmt} has no waveform packets "
                                f"(full-waveform formats are {', '.join(map(str, WAVEFORM_POINT_FORMATS))})")
    encoding = header.global_encoding
    if encoding.waveform_data_packets_external:
        packet_file = external_packet_file(path)
        store = PacketStore(packet_file, 0, bool(lastools_compression(packet_file)))
    elif encoding.waveform_data_packets_internal or header.start_of_waveform_data_packet_record:
        # LAS 1.3's field, or LAS 1.4's pointing at the EVLR 65535 header: offsets count from there
        start = int(header.start_of_waveform_data_packet_record)
        if start <= 0 or start >= path.stat().st_size:
            raise WaveformFileError(f"{path}: internal waveform packets announced at byte {start}, "
                                    f"outside the file ({path.stat().st_size} bytes)")
        store = PacketStore(path, start, False)
    else:
        raise WaveformFileError(f"{path}: the header says neither internal nor external waveform packets")
    try:
        descriptors = read_descriptors(header.vlrs, str(path), store.compressed)
    except ValueError as err:
        raise WaveformFileError(str(err)) from None
    if not descriptors:
        raise WaveformFileError(f"{path}: no waveform packet descriptor (VLR record ids 100-354)")
    return WaveformFile(path, f"{header.version.major}.{header.version.minor}", fmt,
                        int(header.point_count), descriptors, store)


def _packet_keys(points) -> np.ndarray:
    index = np.asarray(points.wavepacket_index).astype(np.int64)
    offset = np.asarray(points.wavepacket_offset).astype(np.int64)
    return np.where(index > 0, (index << _KEY_SHIFT) | offset, -1)


def plan_point_ranges(path: str | Path, points_per_range: int = 10_000,
                      chunk_points: int = 1_000_000) -> list[PointRange]:
    """Split a file into point ranges so that every pulse belongs to exactly one.

    One streaming pass reads the packet keys (8 bytes per point); memory grows
    with the point count only here, never in the readers of the ranges.
    """
    path = Path(path)
    wf = open_waveform_file(path)
    n = wf.point_count
    if n == 0:
        return []
    keys = np.empty(n, dtype=np.int64)
    with laspy.open(path) as reader:
        at = 0
        for chunk in reader.chunk_iterator(chunk_points):
            keys[at:at + len(chunk)] = _packet_keys(chunk)
            at += len(chunk)
    starts = np.arange(0, n, points_per_range)
    range_of_point = np.repeat(np.arange(starts.size), np.diff(np.append(starts, n)))
    has = keys >= 0
    unique, first, inverse = np.unique(keys[has], return_index=True, return_inverse=True)
    point_index = np.flatnonzero(has)
    owner = range_of_point[point_index[first]][inverse]
    pulses_per_range = np.bincount(range_of_point[point_index[first]], minlength=starts.size)
    straying = point_index[owner != range_of_point[point_index]]
    stray_owner = owner[owner != range_of_point[point_index]]
    ranges = []
    for r, start in enumerate(starts):
        stop = min(n, start + points_per_range)
        extra = tuple(int(p) for p in straying[stray_owner == r])
        foreign = tuple(int(p) for p in straying[(straying >= start) & (straying < stop)])
        ranges.append(PointRange(str(path), int(start), int(stop), extra, foreign, int(pulses_per_range[r])))
    return ranges


def _read_points(reader, start: int, stop: int, extra: tuple[int, ...]):
    reader.seek(start)
    parts = [reader.read_points(stop - start)]
    for p in extra:
        reader.seek(p)
        parts.append(reader.read_points(1))
    return parts, np.concatenate([np.arange(start, stop), np.asarray(extra, dtype=np.int64)])


def _column(parts, name, dtype=np.float64) -> np.ndarray:
    return np.concatenate([np.asarray(getattr(p, name)) for p in parts]).astype(dtype)


def read_pulses(point_range: PointRange | str | Path, wf: WaveformFile | None = None) -> PulseBatch:
    """The pulses a range owns, with their samples and system returns.

    A pulse whose packet cannot be read is listed in `rejected` with the reason.
    """
    if not isinstance(point_range, PointRange):
        path = Path(point_range)
        wf = wf or open_waveform_file(path)
        point_range = PointRange(str(path), 0, wf.point_count)
    wf = wf or open_waveform_file(point_range.path)
    with laspy.open(wf.path) as reader:
        parts, index = _read_points(reader, point_range.start, point_range.stop, point_range.extra_points)
        scale = reader.header.scales
        offset = reader.header.offsets
    keys = np.concatenate([_packet_keys(p) for p in parts])
    keep = keys >= 0
    if point_range.foreign_points:
        keep &= ~np.isin(index, np.asarray(point_range.foreign_points))
    xyz = np.stack([_column(parts, "X") * scale[0] + offset[0], _column(parts, "Y") * scale[1] + offset[1],
                    _column(parts, "Z") * scale[2] + offset[2]], axis=1)
    cols = {name: _column(parts, name) for name in (
        "gps_time", "return_point_wave_location", "x_t", "y_t", "z_t", "return_number", "intensity",
        "point_source_id", "scan_direction_flag", "edge_of_flight_line", "user_data", "wavepacket_size")}
    angle_name = "scan_angle_rank" if wf.point_format in (4, 5) else "scan_angle"
    cols["scan_angle"] = _column(parts, angle_name) * (1.0 if angle_name == "scan_angle_rank" else 0.006)
    has_rgb = wf.point_format in (5, 10)
    sel = np.flatnonzero(keep)
    # group points by packet; within a pulse, order by return number so the first is the anchor
    order = sel[np.lexsort((cols["return_number"][sel], index[sel], keys[sel]))]
    pulse_keys, starts = np.unique(keys[order], return_index=True)
    bounds = np.append(starts, order.size)
    # pulses in file order of their first point, as a reader would meet them
    first_point = np.minimum.reduceat(index[order], starts) if order.size else np.zeros(0, np.int64)
    pulse_order = np.argsort(first_point, kind="stable")[:point_range.max_pulses]

    data = wf.packets.open()
    good, samples, rejected = [], [], []
    for i in pulse_order:
        key = int(pulse_keys[i])
        d_index, byte_offset = key >> 48, key & ((1 << 48) - 1)
        anchor = order[bounds[i]]
        descriptor = wf.descriptors.get(d_index)
        if descriptor is None:
            rejected.append((byte_offset, f"descriptor index {d_index} has no waveform packet descriptor"))
            continue
        try:
            samples.append(wf.packets.read(data, descriptor, byte_offset, int(cols["wavepacket_size"][anchor])))
        except PacketError as err:
            rejected.append((byte_offset, str(err)))
            continue
        good.append(i)
    good = np.asarray(good, dtype=np.int64)
    anchors = order[bounds[good]] if good.size else np.zeros(0, np.int64)
    members = [order[bounds[i]:bounds[i + 1]] for i in good]
    return_points = np.concatenate(members) if members else np.zeros(0, np.int64)
    return_offsets = np.zeros(good.size + 1, dtype=np.int64)
    np.cumsum([m.size for m in members], out=return_offsets[1:])
    sample_offsets = np.zeros(good.size + 1, dtype=np.int64)
    np.cumsum([s.size for s in samples], out=sample_offsets[1:])
    descriptors = [wf.descriptors[int(pulse_keys[i]) >> 48] for i in good]
    rgb = nir = None
    if has_rgb:
        rgb = np.stack([_column(parts, c, np.uint16)[anchors] for c in ("red", "green", "blue")], axis=1)
        if wf.point_format == 10:
            nir = _column(parts, "nir", np.uint16)[anchors]
    return PulseBatch(
        source_file=str(wf.path),
        pulse_id=(pulse_keys[good] & ((1 << 48) - 1)).astype(np.int64),
        descriptor_index=(pulse_keys[good] >> 48).astype(np.int16),
        gps_time=cols["gps_time"][anchors],
        anchor=xyz[anchors],
        anchor_location_ps=cols["return_point_wave_location"][anchors],
        direction=np.stack([cols["x_t"][anchors], cols["y_t"][anchors], cols["z_t"][anchors]], axis=1),
        scan_angle=cols["scan_angle"][anchors],
        point_source_id=cols["point_source_id"][anchors].astype(np.uint16),
        scan_direction_flag=cols["scan_direction_flag"][anchors].astype(np.uint8),
        edge_of_flight_line=cols["edge_of_flight_line"][anchors].astype(np.uint8),
        user_data=cols["user_data"][anchors].astype(np.uint8),
        sample_spacing_ps=np.array([d.sample_spacing_ps for d in descriptors], dtype=np.float64),
        digitizer_gain=np.array([d.gain for d in descriptors], dtype=np.float64),
        digitizer_offset=np.array([d.offset for d in descriptors], dtype=np.float64),
        bits_per_sample=np.array([d.bits_per_sample for d in descriptors], dtype=np.int16),
        samples=np.concatenate(samples) if samples else np.zeros(0),
        sample_offsets=sample_offsets,
        return_xyz=xyz[return_points],
        return_number=cols["return_number"][return_points].astype(np.uint8),
        return_intensity=cols["intensity"][return_points].astype(np.uint16),
        return_location_ps=cols["return_point_wave_location"][return_points],
        return_offsets=return_offsets,
        rgb=rgb, nir=nir,
        rejected=tuple(rejected),
    )
