"""The echo table as spatially indexed GeoParquet: rows in Hilbert order, row groups small enough that their
statistics of the bbox covering (pipeline.tables.BBOX_COLUMN) let a reader skip all but the few that can hold a
box's echoes, and the reading side of that: which row groups a box touches, judged by those statistics alone.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.spatial import spatial_order
from pipeline.sinks import write_part
from pipeline.tables import BBOX_COLUMN

# Rows per row group of an echo file: chosen by measurement (bench/bench_query.py, docs/benchmarks.md): smaller
# groups prune a box query closer to its own echoes, larger ones compress better and keep footers small.
ECHO_ROW_GROUP_ROWS = 2048


def spatially_sorted(table: pa.Table, bounds: tuple[float, float, float, float] | None = None) -> pa.Table:
    """The echo rows along the Hilbert curve over `bounds` (default: the square over their own extent); rows
    without a position last; rows in one cell keep their order."""
    if table.num_rows < 2:
        return table
    x, y = (table.column(c).to_numpy(zero_copy_only=False).astype(np.float64) for c in ("x", "y"))
    return table.take(pa.array(spatial_order(x, y, bounds)))


def write_echo_part(table: pa.Table, directory: Path, name: str, row_group_rows: int = ECHO_ROW_GROUP_ROWS,
                    sort: bool = True) -> Path:
    """An echo part in Hilbert order over its own extent (or as given, `sort` False), in row groups of
    `row_group_rows`, with statistics (atomically)."""
    return write_part(spatially_sorted(table) if sort else table, directory, name, row_group_size=row_group_rows,
                      write_statistics=True)


@dataclasses.dataclass(frozen=True)
class RowGroup:
    """One row group of an echo file: where it is, its rows and bytes, and the box its bbox statistics give."""

    path: str
    index: int
    rows: int
    bytes: int  # compressed, as stored
    box: tuple[float, float, float, float] | None  # xmin, ymin, xmax, ymax; None: no statistics to judge by


def row_groups(paths: list[Path]) -> list[RowGroup]:
    """Every row group of the files, with the box of its bbox column's statistics (min of xmin and ymin, max of
    xmax and ymax), read from the footers only."""
    groups = []
    for path in paths:
        meta = pq.ParquetFile(path).metadata
        leaves = {meta.schema.column(i).path: i for i in range(meta.num_columns)}
        wanted = [leaves.get(f"{BBOX_COLUMN}.{f}") for f in ("xmin", "ymin", "xmax", "ymax")]
        for g in range(meta.num_row_groups):
            group = meta.row_group(g)
            stats = [group.column(i).statistics if i is not None else None for i in wanted]
            known = all(s is not None and s.has_min_max for s in stats)
            box = (stats[0].min, stats[1].min, stats[2].max, stats[3].max) if known else None
            groups.append(RowGroup(str(path), g, group.num_rows,
                                    sum(group.column(i).total_compressed_size for i in range(group.num_columns)), box))
    return groups


def touched(groups: list[RowGroup], box: tuple[float, float, float, float]) -> list[RowGroup]:
    """The row groups a box query must read: those whose statistics' box meets `box` (xmin, ymin, xmax, ymax),
    and those without statistics."""
    xmin, ymin, xmax, ymax = box
    return [g for g in groups if g.box is None or not (g.box[2] < xmin or g.box[0] > xmax or g.box[3] < ymin
                                                          or g.box[1] > ymax)]


def extent_of(groups: list[RowGroup]) -> tuple[float, float, float, float]:
    """The box of every row group's statistics together."""
    boxes = np.array([g.box for g in groups if g.box is not None], dtype=np.float64)
    if not boxes.size:
        raise ValueError("no row group has statistics of the bbox column")
    return float(boxes[:, 0].min()), float(boxes[:, 1].min()), float(boxes[:, 2].max()), float(boxes[:, 3].max())


def centre_box(extent: tuple[float, float, float, float], share: float = 0.1) -> tuple[float, float, float, float]:
    """The box at the extent's centre whose sides are `share` of the extent's (share**2 of its area)."""
    xmin, ymin, xmax, ymax = extent
    cx, cy, hx, hy = (xmin + xmax) / 2, (ymin + ymax) / 2, (xmax - xmin) * share / 2, (ymax - ymin) * share / 2
    return cx - hx, cy - hy, cx + hx, cy + hy


def bytes_touched(paths: list[Path], box: tuple[float, float, float, float]) -> float:
    """The share of the files' row group bytes that a box query must read, judged by the bbox statistics."""
    groups = row_groups(paths)
    total = sum(g.bytes for g in groups)
    return sum(g.bytes for g in touched(groups, box)) / total if total else 0.0
