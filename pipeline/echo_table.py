"""A finished run's echo table, read for the maps made over it (fwl grid, classify, footprints): its Parquet
files, its CRS, the echoes' bounds, and its kept, placed echoes a record batch at a time (memory grows with the
batch, not the run)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pipeline.layout import ECHOES
from pipeline.tables import GEO_METADATA_KEY

BATCH_ROWS = 1_000_000


def echo_files(run_dir: Path) -> list[Path]:
    """The run's echo table: its Parquet files under echoes/ (parts or tiles)."""
    files = sorted((run_dir / ECHOES).rglob("*.parquet"))
    if not files:
        raise ValueError(f"{run_dir}: the run has no echo table (echoes/*.parquet): run it with --formats parquet")
    return files


def run_crs_wkt(files: list[Path]) -> str | None:
    """The run's CRS as WKT, from its echo table's GeoParquet metadata (pipeline.tables.file_crs_projjson,
    written from each input's CRS); None where no input names one. Inputs in different CRSs cannot share a map."""
    import pyproj

    found = set()
    for f in files:
        geo = (pq.read_schema(f).metadata or {}).get(GEO_METADATA_KEY)
        crs = json.loads(geo)["columns"]["geometry"].get("crs") if geo else None
        if crs:
            found.add(pyproj.CRS.from_json_dict(crs).to_wkt())
    if len(found) > 1:
        raise ValueError(f"{files[0].parent.parent}: its inputs are in {len(found)} different CRSs; grid one at a time")
    return found.pop() if found else None


def echo_bounds(files: list[Path]) -> tuple[float, float, float, float] | None:
    """The echoes' x, y bounds from the row groups' statistics (no rows read); None without echoes."""
    low, high = [math.inf, math.inf], [-math.inf, -math.inf]
    for f in files:
        meta = pq.ParquetFile(f).metadata
        names = [meta.schema.column(i).name for i in range(meta.num_columns)]
        for g in range(meta.num_row_groups):
            for axis, name in enumerate(("x", "y")):
                stats = meta.row_group(g).column(names.index(name)).statistics
                if stats is None or not stats.has_min_max:
                    return _bounds_read(files)
                low[axis], high[axis] = min(low[axis], stats.min), max(high[axis], stats.max)
    return None if not math.isfinite(low[0]) else (low[0], low[1], high[0], high[1])


def _bounds_read(files: list[Path]) -> tuple[float, float, float, float] | None:
    low, high = [math.inf, math.inf], [-math.inf, -math.inf]
    for batch in kept_batches(files, ["x", "y"]):
        for axis, name in enumerate(("x", "y")):
            low[axis] = min(low[axis], float(np.min(batch[name])))
            high[axis] = max(high[axis], float(np.max(batch[name])))
    return None if not math.isfinite(low[0]) else (low[0], low[1], high[0], high[1])


def kept_batches(files: list[Path], columns: list[str]) -> Iterator[dict[str, np.ndarray]]:
    """The kept echoes' columns with coordinates, a record batch at a time (nulls as NaN)."""
    for f in files:
        for batch in pq.ParquetFile(f).iter_batches(batch_size=BATCH_ROWS, columns=[*columns, "kept"]):
            placed = pc.and_(pc.is_finite(batch.column("x")), pc.is_finite(batch.column("y")))
            keep = pc.and_(batch.column("kept"), placed)
            kept = batch.filter(pc.fill_null(keep, False))  # null coordinates: not placed, not mapped
            if kept.num_rows:
                yield {c: kept.column(c).to_numpy(zero_copy_only=False) for c in columns}


def column_max(files: list[Path], column: str, default: float) -> float:
    """The largest finite value of a column over the kept, placed echoes (fwl classify leaves the others null),
    from the row groups' statistics, which leave out nulls and NaN; a file without them is read. `default`
    where there is none."""
    found = []
    for f in files:
        meta = pq.ParquetFile(f).metadata
        names = [meta.schema.column(i).name for i in range(meta.num_columns)]
        stats = [meta.row_group(g).column(names.index(column)).statistics for g in range(meta.num_row_groups)]
        if any(s is None for s in stats):
            found += [float(np.nanmax(b[column])) for b in kept_batches([f], ["x", "y", column])
                      if np.isfinite(b[column]).any()]
        else:
            found += [float(s.max) for s in stats if s.has_min_max]
    return max(found, default=default)
