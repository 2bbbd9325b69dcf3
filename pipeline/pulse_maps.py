"""Maps of the pulses' own forest metrics (`pulses/`: rh, cover, pai, ground_z) for large footprints: a GEDI or
LVIS shot is a 25 m (10-20 m) sample of the forest in itself, so a cell's value is the mean of its shots'.

    shot_metric_maps(run_dir, grid) -> {file: (bands, dtype, nodata, descriptions)}   rh98, rh50, cover, pai and
                                                                                      ground per cell
    large_footprint_run(run_dir) -> bool   GEDI or LVIS inputs with measured metrics: fwl grid maps them

Read a record batch at a time: memory grows with the cells, not the shots. The shot's position is its pulse's
anchor (GEDI: bin0, the top of its waveform, within a metre of the ground's horizontally).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from fwcore.grid import CellStatistics, Grid
from pipeline.layout import PULSES
from pipeline.tables import GEOMETRY_COLUMN

BATCH_ROWS = 200_000
SHOT_METRICS = ("rh98", "rh50", "cover", "pai", "ground_z")
DESCRIPTIONS = {"rh98": "mean RH98 of the shots [m]", "rh50": "mean RH50 of the shots [m]",
                "cover": "mean canopy cover of the shots [1]", "pai": "mean plant area index of the shots [m2/m2]",
                "ground_z": "mean ground height of the shots [CRS unit]"}
MAP_FILES = {"rh98": "rh98.tif", "rh50": "rh50.tif", "cover": "cover.tif", "pai": "pai.tif",
             "ground_z": "ground.tif"}


def pulse_files(run_dir: Path) -> list[Path]:
    return sorted((Path(run_dir) / PULSES).rglob("*.parquet"))


def large_footprint_run(run_dir: Path) -> bool:
    """Whether the run read GEDI or LVIS granules (run.json's inputs: their format, or a .h5 name where the file
    is gone) and its pulses carry measured metrics."""
    from fwcore.io.formats import GEDI_L1B, LVIS_L1B, format_of
    from pipeline.outputs import read_run

    def large(path: str) -> bool:
        return format_of(path) in (GEDI_L1B, LVIS_L1B) if Path(path).is_file() else path.lower().endswith(".h5")
    inputs = read_run(Path(run_dir)).get("inputs", [])
    return any(large(str(i.get("path", ""))) for i in inputs) and has_shot_metrics(Path(run_dir))


def has_shot_metrics(run_dir: Path) -> bool:
    """Whether the run's pulses carry measured forest metrics (a run of this version on any input)."""
    for f in pulse_files(run_dir):
        if "metrics_reason" in pq.read_schema(f).names:
            reasons = pq.read_table(f, columns=["metrics_reason"]).column(0)
            if pc.any(pc.equal(reasons, "")).as_py():
                return True
    return False


def _anchors(geometry: pa.Array) -> tuple[np.ndarray, np.ndarray]:
    """x, y of WKB Point Z values (pipeline.tables.wkb_points: 29 bytes each); NaN where null."""
    n = len(geometry)
    x, y = np.full(n, np.nan), np.full(n, np.nan)
    valid = ~np.asarray(geometry.is_null())
    if valid.any():  # read from the array's buffers: each value's x at bytes 5-12, y at 13-20 of its WKB
        offsets = np.frombuffer(geometry.buffers()[1], np.int32)[geometry.offset:geometry.offset + n + 1]
        data = np.frombuffer(geometry.buffers()[2], np.uint8)
        start = offsets[:-1][valid]
        x[valid] = data[start[:, None] + np.arange(5, 13)].view("<f8").ravel()
        y[valid] = data[start[:, None] + np.arange(13, 21)].view("<f8").ravel()
    return x, y


def _batches(files: list[Path]) -> Iterator[dict[str, np.ndarray]]:
    for f in files:
        parquet = pq.ParquetFile(f)
        if "metrics_reason" not in parquet.schema_arrow.names:
            continue
        for batch in parquet.iter_batches(BATCH_ROWS, columns=[GEOMETRY_COLUMN, "rh", "cover", "pai", "ground_z"]):
            rh = batch.column("rh")
            flat = rh.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
            lengths = np.asarray(rh.value_lengths().fill_null(0))
            starts = np.r_[0, np.cumsum(lengths)[:-1]]
            full = lengths == 101
            rh98, rh50 = np.full(len(batch), np.nan), np.full(len(batch), np.nan)
            rh98[full], rh50[full] = flat[starts[full] + 98], flat[starts[full] + 50]
            x, y = _anchors(batch.column(GEOMETRY_COLUMN))
            yield {"x": x, "y": y, "rh98": rh98, "rh50": rh50,
                   **{c: batch.column(c).to_numpy(zero_copy_only=False).astype(np.float64)
                      for c in ("cover", "pai", "ground_z")}}


def shot_metric_maps(run_dir: Path, grid: Grid) -> dict[str, tuple[list[np.ndarray], str, float, list[str]]]:
    """Per map file, as pipeline.grid writes them: its band (the mean of the shots in each cell; NaN: no shot
    measured), dtype, nodata and description."""
    stats = CellStatistics(grid, SHOT_METRICS)
    for b in _batches(pulse_files(run_dir)):
        located = np.isfinite(b["x"]) & np.isfinite(b["y"])
        stats.add(b["x"][located], b["y"][located], np.zeros(located.sum()),
                  **{name: b[name][located] for name in SHOT_METRICS})
    return {MAP_FILES[name]: ([grid.raster(stats.mean(name)).astype(np.float32 if name != "ground_z" else np.float64)],
                              "float32" if name != "ground_z" else "float64", np.nan, [DESCRIPTIONS[name]])
            for name in SHOT_METRICS}
