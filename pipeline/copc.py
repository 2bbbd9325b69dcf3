"""COPC (Cloud Optimized Point Cloud): an input's kept echoes as copc/<stem>.copc.laz, from its LAS parts.

A COPC file is a LAZ 1.4 file whose points are grouped into the nodes of an octree over one cube, each node a
LAZ chunk, with a hierarchy that lets a viewer or a box query read only the nodes it needs. copclib writes the
file (chunks, hierarchy, info record); this module decides which node holds which point, by grid sampling as
PDAL's untwine does: a node keeps the first point of each of its GRID^3 cells and hands the others to its
eight children; a node with at most LEAF_POINTS points keeps them all.

Bounded memory, in passes over the parts (the same points, records and header as las/<stem>.las) and over
files spilled under parts/:

    1. points per voxel of a fine grid -> the depth whose voxels ("buckets") hold at most BUCKET_POINTS
    2. every point appended to its bucket's file
    3. each bucket alone: its share of the nodes above it sampled (a cell of those nodes lies in one bucket)
       and appended to their files; the rest split into the bucket's nodes and written
    4. the nodes above the buckets, one at a time

The points reach the nodes in the order of the parts, so the file does not depend on how they were split
into ranges.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Iterator

import laspy
from laspy.vlrs.vlrlist import VLRList
import numpy as np

from fwcore.io.crs import las_crs_wkt
from pipeline.sinks import ExtraBytesRanges, temporary_path

GRID_BITS = 7  # a node's sampling grid: 128 cells a side, as untwine's
LEAF_POINTS = 100_000  # a node with at most this many points keeps them all
BUCKET_POINTS = 200_000  # the most points pass 3 holds at once (a bucket's), but for a voxel of FINE_DEPTH
CHUNK_POINTS = 250_000  # points read at once in passes 1 and 2
FINE_DEPTH = 8  # the finest voxels pass 1 counts in (256 a side)
MAX_DEPTH = 20  # below this, points that share a place stay together
LAS14_HEADER_BYTES = 375


@dataclasses.dataclass(frozen=True)
class Cube:
    """The octree's root voxel: a cube around the points' bounds."""

    centre: np.ndarray
    half: float

    @classmethod
    def around(cls, low: np.ndarray, high: np.ndarray, scales: np.ndarray) -> "Cube":
        # from the lowest corner, as copclib places nodes; a scale step of margin: no point on the far face
        half = float(np.max(high - low)) / 2 + float(np.max(scales))
        return cls(np.asarray(low, float) + half, half)

    def cells(self, xyz: np.ndarray, bits: int) -> np.ndarray:
        """Each point's cell of a grid of 2^bits a side over the cube, as (n, 3) integers."""
        n = 1 << bits
        index = np.floor((xyz - (self.centre - self.half)) * (n / (2 * self.half)))
        return np.clip(index, 0, n - 1).astype(np.int64)


def _codes(cells: np.ndarray, bits: int) -> np.ndarray:
    return (cells[:, 0] << (2 * bits)) | (cells[:, 1] << bits) | cells[:, 2]


def _xyz(records: np.ndarray, header) -> np.ndarray:
    """The points' coordinates as laspy scales them."""
    return np.stack([records[a] * s + o for a, s, o in zip("XYZ", header.scales, header.offsets)], axis=1)


def _part_header(part: Path) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Where an uncompressed LAS 1.4 part's points start, how many, and their bounds, from its header's bytes
    (laspy's reader parses every record of the header: 1 ms a part, thousands of parts)."""
    with open(part, "rb") as f:
        head = f.read(LAS14_HEADER_BYTES)
    offset = int(np.frombuffer(head, "<u4", 1, 96)[0])
    count = int(np.frombuffer(head, "<u8", 1, 247)[0])
    high_low = np.frombuffer(head, "<f8", 6, 179).reshape(3, 2)  # max x, min x, max y, ...
    return offset, count, high_low[:, 1].copy(), high_low[:, 0].copy()


def _chunks(parts: list[Path], dtype: np.dtype) -> Iterator[np.ndarray]:
    """Every point record of the parts, in order, in chunks of about CHUNK_POINTS (a range's part holds a few
    thousand: each chunk costs a pass over the upper levels' occupancy, which grows with the flight)."""
    held, n = [], 0
    for part in parts:
        offset, count, _, _ = _part_header(part)
        for start in range(0, count, CHUNK_POINTS):
            held.append(np.fromfile(part, dtype, min(CHUNK_POINTS, count - start), offset=offset
                                    + start * dtype.itemsize))
            n += len(held[-1])
            if n >= CHUNK_POINTS:
                yield np.concatenate(held)
                held, n = [], 0
    if held:
        yield np.concatenate(held)


def has_point_cloud_parts(formats) -> bool:
    """Whether a run's ranges write LAS parts: las/ and copc/ are both assembled from them."""
    return "las" in formats or "copc" in formats


def crs_wkt(header) -> str:
    """The WKT the COPC file declares: the LAS part's (written from the input's CRS), or none."""
    return las_crs_wkt(header)[0] or ""


# ---------------------------------------------------------------- pass 1

@dataclasses.dataclass
class _Survey:
    """What pass 1 finds: counts per fine voxel, points per return number, Extra Bytes ranges."""

    codes: np.ndarray
    counts: np.ndarray
    by_return: np.ndarray
    ranges: ExtraBytesRanges


def _survey(parts: list[Path], header, cube: Cube) -> _Survey:
    codes, counts = np.zeros(0, np.int64), np.zeros(0, np.int64)
    by_return = np.zeros(16, np.int64)
    ranges = ExtraBytesRanges(header)
    for records in _chunks(parts, header.point_format.dtype()):
        found, n = np.unique(_codes(cube.cells(_xyz(records, header), FINE_DEPTH), FINE_DEPTH), return_counts=True)
        codes, where = np.unique(np.concatenate([codes, found]), return_inverse=True)
        counts = np.bincount(where, weights=np.concatenate([counts, n]), minlength=codes.size).astype(np.int64)
        by_return += np.bincount(records["bit_fields"] & 0x0F, minlength=16)
        ranges.add(records)
    return _Survey(codes, counts, by_return, ranges)


def bucket_depth(codes: np.ndarray, counts: np.ndarray, bucket_points: int = BUCKET_POINTS) -> int:
    """The shallowest depth whose voxels hold at most bucket_points points (FINE_DEPTH at most)."""
    mask = (1 << FINE_DEPTH) - 1
    cells = np.stack([(codes >> (2 * FINE_DEPTH)) & mask, (codes >> FINE_DEPTH) & mask, codes & mask], axis=1)
    for depth in range(FINE_DEPTH + 1):
        _, where = np.unique(_codes(cells >> (FINE_DEPTH - depth), depth), return_inverse=True)
        if counts.size == 0 or np.bincount(where, weights=counts).max() <= bucket_points:
            return depth
    return FINE_DEPTH


# ---------------------------------------------------------------- pass 2

Key = tuple[int, int, int, int]  # a node: depth, x, y, z


def _spill_path(spill: Path, stem: str, key: Key) -> Path:
    return spill / f"{stem}-copc-{'-'.join(str(v) for v in key)}.bin"


def _append(path: Path, records: np.ndarray) -> None:
    with open(path, "ab") as f:
        records.tofile(f)


def _groups(codes: np.ndarray) -> Iterator[np.ndarray]:
    """The rows of each distinct code, in code order, each in its original order."""
    order = np.argsort(codes, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(codes[order]) != 0]) if order.size else np.zeros(0, int)
    for lo, hi in zip(starts, np.r_[starts[1:], order.size]):
        yield order[lo:hi]


def _spill(parts: list[Path], header, cube: Cube, depth: int, spill: Path, stem: str) -> list[Key]:
    """Pass 2: every point appended, in order, to the file of its bucket (its voxel at `depth`)."""
    buckets: set[Key] = set()
    for records in _chunks(parts, header.point_format.dtype()):
        cells = cube.cells(_xyz(records, header), depth)
        for rows in _groups(_codes(cells, max(depth, 1))):
            key = (depth, *(int(v) for v in cells[rows[0]]))
            buckets.add(key)
            _append(_spill_path(spill, stem, key), records[rows])
    return sorted(buckets)


def _take_upper(records: np.ndarray, xyz: np.ndarray, cube: Cube, depth: int,
                grid_bits: int) -> tuple[list[tuple[Key, np.ndarray]], np.ndarray]:
    """A bucket's share of the nodes above it: at each depth, the first point of each cell not taken higher up,
    in stream order; and the rows of the points left to the bucket. A cell of a node above the bucket lies in
    one bucket (depth <= grid_bits), so the buckets are sampled apart as the whole stream would be."""
    taken, rest = [], np.arange(len(records))
    for d in range(depth):
        if not rest.size:
            break
        cells = cube.cells(xyz[rest], d + grid_bits)
        _, first = np.unique(_codes(cells, d + grid_bits), return_index=True)
        first.sort()  # stream order within the node
        taken.append(((d, *(int(v) for v in cells[first[0]] >> grid_bits)), records[rest[first]]))
        rest = np.delete(rest, first)
    return taken, rest


# ---------------------------------------------------------------- pass 3

def _split(key: Key, records: np.ndarray, header, cube: Cube, leaf_points: int,
           grid_bits: int) -> Iterator[tuple[Key, np.ndarray]]:
    """A bucket's nodes: each keeps the first point of each of its grid's cells, its children the rest."""
    stack = [(key, records)]
    while stack:
        key, records = stack.pop()
        d, origin = key[0], np.array(key[1:], np.int64)
        if len(records) <= leaf_points or d >= MAX_DEPTH:
            yield key, records
            continue
        xyz = _xyz(records, header)
        local = cube.cells(xyz, d + grid_bits) - (origin << grid_bits)
        _, first = np.unique(_codes(local, grid_bits), return_index=True)
        keep = np.zeros(len(records), bool)
        keep[first] = True
        yield key, records[keep]
        rest = np.flatnonzero(~keep)
        child = cube.cells(xyz[rest], d + 1) - (origin << 1)
        which = (child[:, 0] << 2) | (child[:, 1] << 1) | child[:, 2]
        for c in range(7, -1, -1):  # popped in child order
            rows = rest[which == c]
            if rows.size:
                stack.append(((d + 1, *(int(v) for v in (origin << 1) + [(c >> 2) & 1, (c >> 1) & 1, c & 1])),
                              records[rows]))


# ---------------------------------------------------------------- the file

def _writer(path: Path, header, cube: Cube, wkt: str, grid_bits: int):
    """copclib's writer with the parts' point format, scales, offsets, Extra Bytes (read back by copclib from
    a one-point LAZ of the same header) and CRS."""
    import copclib

    template = path.with_name(path.name + ".header.tmp")
    probe = laspy.LasHeader(point_format=header.point_format, version="1.4")
    probe.scales, probe.offsets = header.scales, header.offsets
    probe.vlrs = [v for v in header.vlrs if v.user_id.rstrip("\0") == "LASF_Spec"]
    probe.global_encoding.wkt = True  # copclib reads only LAS 1.4 files that say their CRS is WKT
    with laspy.open(template, mode="w", header=probe, do_compress=True) as w:
        w.write_points(laspy.ScaleAwarePointRecord.zeros(1, header=probe))
    extra = copclib.LazReader(str(template)).laz_config.extra_bytes_vlr
    template.unlink()
    config = copclib.CopcConfigWriter(header.point_format.id, copclib.Vector3(*header.scales),
                                      copclib.Vector3(*header.offsets), wkt, extra, False)
    info = config.copc_info
    info.center_x, info.center_y, info.center_z = (float(v) for v in cube.centre)
    info.halfsize = cube.half
    info.spacing = 2 * cube.half / (1 << grid_bits)
    return copclib.FileWriter(str(path), config)


def _add(writer, key: Key, records: np.ndarray) -> None:
    import copclib

    if not len(records):  # a bucket whose points all went up (it has no children either)
        return
    writer.AddNode(copclib.VoxelKey(*key), copclib.VectorChar(np.ascontiguousarray(records).view(np.int8)))


def _finish_header(writer, header, survey: _Survey, low: np.ndarray, high: np.ndarray) -> None:
    import copclib

    las = writer.copc_config.las_header
    las.min, las.max = copclib.Vector3(*low), copclib.Vector3(*high)
    las.points_by_return = [int(v) for v in survey.by_return[1:]]
    las.global_encoding = int(header.global_encoding.value) | 0x10  # the parts' GPS time type; WKT
    las.system_identifier = header.system_identifier
    las.generating_software = "fwlidar"


def _patch_extra_bytes(path: Path, header, ranges: ExtraBytesRanges) -> None:
    """The Extra Bytes record with its descriptions, no-data values and the ranges over all points: copclib
    writes the record it read from the one-point file; it is replaced in place (the same size)."""
    vlrs = VLRList([v for v in header.vlrs if v.user_id.rstrip("\0") == "LASF_Spec" and v.record_id == 4])
    if not vlrs:
        return
    ranges.set_on(vlrs)
    data = vlrs[0].record_data_bytes()
    with open(path, "r+b") as f:
        head = f.read(375)
        at = int(np.frombuffer(head[94:96], "<u2")[0])
        for _ in range(int(np.frombuffer(head[100:104], "<u4")[0])):
            f.seek(at)
            vlr = f.read(54)
            user, record, length = vlr[2:18].rstrip(b"\0"), *np.frombuffer(vlr[18:22], "<u2")
            if user == b"LASF_Spec" and record == 4:
                if length != len(data):
                    raise ValueError(f"{path.name}: Extra Bytes record of {length} bytes, expected {len(data)}")
                f.seek(at + 54)
                f.write(data)
                return
            at += 54 + int(length)


def assemble_copc(parts: list[Path], path: Path, leaf_points: int = LEAF_POINTS, bucket_points: int = BUCKET_POINTS,
                  grid_bits: int = GRID_BITS) -> Path:
    """copc/<stem>.copc.laz from an input's LAS parts (in range order), holding at most a bucket's points or a
    node's at once; the spilled buckets and nodes go under the parts' folder and are removed."""
    with laspy.open(parts[0]) as first:
        header = first.header
    bounds = [(low, high) for _, count, low, high in map(_part_header, parts) if count]
    low = np.min([b[0] for b in bounds], axis=0) if bounds else np.zeros(3)
    high = np.max([b[1] for b in bounds], axis=0) if bounds else np.zeros(3)
    cube = Cube.around(low, high, np.asarray(header.scales))
    stem = path.name.removesuffix(".copc.laz")
    spill = parts[0].parent
    tmp = temporary_path(path)
    survey = _survey(parts, header, cube)
    depth = min(bucket_depth(survey.codes, survey.counts, bucket_points), grid_bits)
    try:
        for stale in spill.glob(f"{stem}-copc-*.bin"):  # an interrupted attempt's: appended to, they would double
            stale.unlink()
        buckets = _spill(parts, header, cube, depth, spill, stem)
        writer = _writer(tmp, header, cube, crs_wkt(header), grid_bits)
        upper: set[Key] = set()
        for key in buckets:  # pass 3: each bucket's share of the upper nodes spilled, its own nodes written
            records = np.fromfile(_spill_path(spill, stem, key), dtype=header.point_format.dtype())
            _spill_path(spill, stem, key).unlink()
            taken, rest = _take_upper(records, _xyz(records, header), cube, depth, grid_bits)
            for node, points in taken:
                upper.add(node)
                _append(_spill_path(spill, stem, node), points)
            for node, points in _split(key, records[rest], header, cube, leaf_points, grid_bits):
                _add(writer, node, points)
        for key in sorted(upper):  # pass 4: the nodes above the buckets, one at a time
            _add(writer, key, np.fromfile(_spill_path(spill, stem, key), dtype=header.point_format.dtype()))
            _spill_path(spill, stem, key).unlink()
        _finish_header(writer, header, survey, low, high)
        writer.Close()
    finally:
        for p in spill.glob(f"{stem}-copc-*.bin"):
            p.unlink()
    _patch_extra_bytes(tmp, header, survey.ranges)
    tmp.replace(path)
    return path
