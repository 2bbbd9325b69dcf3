"""The classes of `fwl classify` into a run's point clouds: las/<stem>.las (or .laz) and copc/<stem>.copc.laz.

`fwl run` writes the point clouds before there are classes, from the same kept echoes as the echo table but in
another order; a point is found in the table by its GPS time and its coordinates in the file's scaled integers
(a 64-bit hash of the four: pulses differ in time, a pulse's echoes in place). The LAS is rewritten a chunk at a
time into a temporary uncompressed LAS beside the spilled tiles, which then replaces the LAS and is the one part
the COPC is assembled from again (pipeline.copc). Memory: the table's hashes and classes (9 bytes an echo of the
input) and a chunk of points.
"""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import laspy
from laspy.vlrs.vlrlist import VLRList
import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pipeline.layout import COPC, LAS

CHUNK_POINTS = 1_000_000
UNMATCHED = 1  # a point the table does not know keeps "unclassified"
_MIX = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9))


def point_hash(gps_time: np.ndarray, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """A 64-bit key of a point: its GPS time's bits and its scaled integer coordinates, mixed."""
    with np.errstate(over="ignore"):
        h = np.asarray(gps_time, np.float64).view(np.uint64).copy()
        for v, m in zip((X, Y, Z), _MIX):
            h ^= np.asarray(v, np.int64).view(np.uint64) * m
            h = (h ^ (h >> np.uint64(29))) * _MIX[0]
        return h


def _table_classes(files: list[Path], source: str, header) -> tuple[np.ndarray, np.ndarray]:
    """The echo table's kept echoes of one input: their hashes (sorted) and classes."""
    keys, codes = [], []
    for f in files:
        t = pq.read_table(f, columns=["source_file", "gps_time", "x", "y", "z", "kept", "classification"])
        t = t.filter(pc.and_(pc.equal(t.column("source_file"), source), pc.fill_null(t.column("kept"), False)))
        if not t.num_rows:
            continue
        scaled = [np.round((t.column(c).to_numpy(zero_copy_only=False) - o) / s).astype(np.int64)
                  for c, o, s in zip("xyz", header.offsets, header.scales)]
        keys.append(point_hash(t.column("gps_time").to_numpy(zero_copy_only=False), *scaled))
        codes.append(np.nan_to_num(t.column("classification").to_numpy(zero_copy_only=False), nan=UNMATCHED)
                     .astype(np.uint8))
    if not keys:
        return np.zeros(0, np.uint64), np.zeros(0, np.uint8)
    keys, codes = np.concatenate(keys), np.concatenate(codes)
    order = np.argsort(keys, kind="stable")
    return keys[order], codes[order]


def _lookup(keys: np.ndarray, codes: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The classes of the points whose hashes are `wanted` (UNMATCHED where the table has none), and which
    were found."""
    if keys.size == 0:
        return np.full(wanted.size, UNMATCHED, np.uint8), np.zeros(wanted.size, bool)
    i = np.minimum(np.searchsorted(keys, wanted), keys.size - 1)
    found = keys[i] == wanted
    return np.where(found, codes[i], UNMATCHED).astype(np.uint8), found


def classify_point_clouds(run_dir: Path, echo_files: list[Path], scratch: Path) -> dict[str, int]:
    """Each input's LAS and COPC with the table's classes; per stem, the points that found their echo."""
    from pipeline.copc import assemble_copc

    matched: dict[str, int] = {}
    stems = {p.name.removesuffix(".copc.laz") for p in (run_dir / COPC).glob("*.copc.laz")}
    las_files = {p.stem: p for p in (run_dir / LAS).glob("*.la[sz]")}
    stems |= set(las_files)
    scratch.mkdir(parents=True, exist_ok=True)
    for stem in sorted(stems):
        copc = run_dir / COPC / f"{stem}.copc.laz"
        source = las_files.get(stem) or copc
        tmp = scratch / f"{stem}.las"
        with laspy.open(source) as reader:
            header = reader.header
            sources = _source_names(echo_files, stem)
            keys, codes = _table_classes(echo_files, sources, header) if sources else (np.zeros(0, np.uint64),
                                                                                       np.zeros(0, np.uint8))
            out_header = copy.deepcopy(header)  # scales, offsets, CRS, Extra Bytes: the file's own
            out_header.vlrs = VLRList([v for v in header.vlrs if v.user_id.rstrip("\0") != "copc"])
            if getattr(out_header, "evlrs", None) is not None:
                out_header.evlrs = VLRList([v for v in out_header.evlrs if v.user_id.rstrip("\0") != "copc"])
            count = 0
            with laspy.open(tmp, mode="w", header=out_header) as writer:
                for points in reader.chunk_iterator(CHUNK_POINTS):
                    c, found = _lookup(keys, codes, point_hash(points.gps_time, points.X, points.Y, points.Z))
                    count += int(found.sum())
                    points.classification = c
                    writer.write_points(points)
        matched[stem] = count
        if stem in las_files:
            target = las_files[stem]
            if target.suffix == ".laz":
                with laspy.open(tmp) as r, laspy.open(target.with_name(target.name + ".tmp"), mode="w",
                                                       header=r.header, do_compress=True) as w:
                    for points in r.chunk_iterator(CHUNK_POINTS):
                        w.write_points(points)
            else:
                shutil.copyfile(tmp, target.with_name(target.name + ".tmp"))
            target.with_name(target.name + ".tmp").replace(target)
        if copc.exists():
            assemble_copc([tmp], copc)
        tmp.unlink()
    return matched


def _source_names(echo_files: list[Path], stem: str) -> str | None:
    """The echo table's source_file of an input whose outputs are named by `stem`."""
    for f in echo_files:
        names = pq.read_table(f, columns=["source_file"]).column("source_file").unique().to_pylist()
        for name in names:
            if name and Path(name).stem == stem:
                return name
    return None
