"""Biomass maps for `fwl grid`: the mean of the per-shot L4A predictions (fwcore.metrics.biomass) in each cell.

    agbd.tif             the run's shots (pulses/ agbd: GEDI and LVIS shots), where any was predicted
    footprints_agbd.tif  the GEDI footprints `fwl footprints --stratum` simulated from an airborne run
                         (RUN_DIR/footprints.parquet), where any was predicted: biomass from an airborne waveform
                         survey, GEDI's way

A cell's value is a mean of shot predictions, not L4B's gridded estimate (which weighs the shots' sampling and
model errors): a cell without a predicted shot is NaN. Read a record batch at a time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow.parquet as pq

from fwcore.grid import CellStatistics, Grid
from pipeline.pulse_maps import BATCH_ROWS, _anchors, pulse_files
from pipeline.tables import GEOMETRY_COLUMN

FOOTPRINTS_FILE = "footprints.parquet"  # pipeline.footprints' default output in the run's folder
MAPS = {"agbd.tif": "mean aboveground biomass density of the shots (GEDI L4A models) [Mg/ha]",
        "footprints_agbd.tif": "mean aboveground biomass density of the simulated GEDI footprints (L4A models) [Mg/ha]"}


def _shot_agbd(run_dir: Path) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    for f in pulse_files(run_dir):
        parquet = pq.ParquetFile(f)
        if "agbd" not in parquet.schema_arrow.names:
            continue
        for batch in parquet.iter_batches(BATCH_ROWS, columns=[GEOMETRY_COLUMN, "agbd"]):
            x, y = _anchors(batch.column(GEOMETRY_COLUMN))
            yield x, y, batch.column("agbd").to_numpy(zero_copy_only=False).astype(np.float64)


def _footprint_agbd(path: Path) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    if not path.is_file() or "agbd" not in pq.read_schema(path).names:
        return
    for batch in pq.ParquetFile(path).iter_batches(BATCH_ROWS, columns=["x", "y", "agbd"]):
        yield tuple(batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64) for c in ("x", "y", "agbd"))


def mean_agbd(points: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]], grid: Grid) -> np.ndarray | None:
    """Each cell's mean agbd (the grid's cell order; NaN: no prediction), or None where nothing was predicted."""
    stats = CellStatistics(grid, ("agbd",))
    for x, y, agbd in points:
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(agbd)
        stats.add(x[ok], y[ok], np.zeros(ok.sum()), agbd=agbd[ok])
    return stats.mean("agbd") if stats.counts["agbd"].any() else None


def biomass_maps(run_dir: str | Path, grid: Grid) -> dict[str, tuple[list[np.ndarray], str, float, list[str]]]:
    """Per map file, as pipeline.grid writes them (bands, dtype, nodata, descriptions): agbd.tif and
    footprints_agbd.tif where the run holds predictions for them, nothing otherwise."""
    run_dir = Path(run_dir)
    found = {"agbd.tif": mean_agbd(_shot_agbd(run_dir), grid),
             "footprints_agbd.tif": mean_agbd(_footprint_agbd(run_dir / FOOTPRINTS_FILE), grid)}
    return {name: ([grid.raster(mean).astype(np.float32)], "float32", np.nan, [MAPS[name]])
            for name, mean in found.items() if mean is not None}
