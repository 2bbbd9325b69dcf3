"""`fwl classify RUN_DIR`: every kept echo of a finished run classified (ASPRS: 2 ground, 6 building, 3/4/5
vegetation by height, 7 low noise, 1 otherwise) with its height above the terrain, written into the run's echo table
(`classification`, `height`; null for spurious echoes). `fwl grid` runs it first when the table has no classes.

Tile by tile with an overlap (fwcore.terrain.tiles), so that a survey of any size streams:

    1. the kept echoes, a record batch at a time, appended to the spill file of each tile whose core or
       margin holds them (under the run's .classify/ folder, removed at the end)
    2. each tile alone: the ground filter, roofs and heights over its core and margin; its core's echoes'
       results kept by their row in the table (a byte and a float32 an echo)
    3. each echo file rewritten with the two columns (atomically: a file is old or new, never half)
    4. the run's LAS and COPC files rewritten with the classes (pipeline.classes_las)

Memory: one tile's echoes at a time, plus five bytes per echo of the survey for the results of step 2.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from fwcore.grid import Grid
from fwcore.terrain.classes import asprs_classes
from fwcore.terrain.ground import GroundConfig
from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M, Tile, tile_terrain, tiles_over
from pipeline.classes_las import classify_point_clouds
from pipeline.echo_table import BATCH_ROWS, echo_bounds, echo_files
from pipeline.outputs import read_run
from pipeline.tables import COLUMNS

SPILL_DIR = ".classify"
SPILL_COLUMNS = ("row", "x", "y", "z", "pulse_id", "echo_index")
DEFAULT_CELL_M = 1.0  # the tiles' cells (a tile is a whole number of them)


@dataclasses.dataclass(frozen=True)
class Classified:
    """What classify_run did: echoes by class, tiles, and the settings."""

    echoes: int
    by_class: dict[int, int]
    tiles: int
    tile_m: float
    overlap_m: float
    points_classified: int = 0  # points of the run's LAS and COPC files given their echo's class


def is_classified(run_dir: str | Path) -> bool:
    """Whether the run's echo table has classes (fwl classify ran on it): its first file's first kept row."""
    f = echo_files(Path(run_dir))[0]
    schema = pq.read_schema(f)
    if "classification" not in schema.names:
        return False
    table = pq.read_table(f, columns=["classification", "kept"])
    kept = table.filter(pc.fill_null(table.column("kept"), False))
    return kept.num_rows == 0 or kept.column("classification").null_count < kept.num_rows


def _kept_batches(files: list[Path], columns: list[str]) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """(first row of the batch in the whole table, the kept and placed rows' columns with their "row")."""
    first = 0
    for f in files:
        for batch in pq.ParquetFile(f).iter_batches(batch_size=BATCH_ROWS, columns=[*columns, "kept"]):
            x, y = batch.column("x").to_numpy(zero_copy_only=False), batch.column("y").to_numpy(zero_copy_only=False)
            kept = np.asarray(pc.fill_null(batch.column("kept"), False)) & np.isfinite(x) & np.isfinite(y)
            rows = np.flatnonzero(kept)
            if rows.size:
                values = {c: batch.column(c).to_numpy(zero_copy_only=False)[rows] for c in columns}
                values["row"] = rows + first
                yield first, values
            first += batch.num_rows


def spill_tiles(files: list[Path], tiles: list[Tile], folder: Path, columns: tuple[str, ...]) -> list[Path]:
    """Step 1: each tile's echoes (core and margin) into folder/tile-K.parquet; the files (absent: no echo)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"tile-{k}.parquet" for k in range(len(tiles))]
    writers: dict[int, pq.ParquetWriter] = {}
    boxes = np.array([t.buffered for t in tiles])
    try:
        for _, b in _kept_batches(files, [c for c in columns if c != "row"]):
            x, y = b["x"], b["y"]
            near = np.flatnonzero((boxes[:, 0] <= x.max()) & (boxes[:, 2] > x.min()) & (boxes[:, 1] <= y.max())
                                  & (boxes[:, 3] > y.min()))
            for k in near:
                inside = tiles[k].in_buffered(x, y)
                if inside.any():
                    table = pa.table({c: b[c][inside] for c in columns})
                    if k not in writers:
                        writers[k] = pq.ParquetWriter(paths[k], table.schema)
                    writers[k].write_table(table)
    finally:
        for w in writers.values():
            w.close()
    return paths


def classify_run(run_dir: str | Path, tile: float = DEFAULT_TILE_M, overlap: float = DEFAULT_OVERLAP_M,
                 config: GroundConfig = GroundConfig()) -> Classified:
    """Classes and heights of a finished run's kept echoes, into its echo table (see the module)."""
    run_dir = Path(run_dir)
    read_run(run_dir)  # a folder that is not a finished run is refused here
    files = echo_files(run_dir)
    bounds = echo_bounds(files)
    if bounds is None:
        raise ValueError(f"{run_dir}: the run kept no echo with coordinates: nothing to classify")
    grid = Grid.covering(*bounds, DEFAULT_CELL_M)
    tiles = tiles_over(grid, tile, overlap)
    rows = sum(pq.ParquetFile(f).metadata.num_rows for f in files)
    ground = np.zeros(rows, bool)
    building = np.zeros(rows, bool)
    noise = np.zeros(rows, bool)
    height = np.full(rows, np.nan, np.float32)
    spill = run_dir / SPILL_DIR
    shutil.rmtree(spill, ignore_errors=True)
    try:
        paths = spill_tiles(files, tiles, spill, SPILL_COLUMNS)
        for t, path in zip(tiles, paths):
            if not path.exists():
                continue
            e = {c: v.to_numpy(zero_copy_only=False) for c, v in zip(SPILL_COLUMNS, pq.read_table(path).columns)}
            result = tile_terrain(t, e["x"], e["y"], e["z"], e["pulse_id"], e["echo_index"], config)
            core = t.in_core(e["x"], e["y"])
            r = e["row"][core]
            ground[r], building[r], height[r] = result.ground[core], result.building[core], result.height[core]
            noise[r] = result.noise[core]
            path.unlink()
        codes = asprs_classes(height, ground, building, noise)
        by_class = _write_columns(files, codes, height)
        del ground, building, noise, height, codes
        matched = classify_point_clouds(run_dir, files, spill)
    finally:
        shutil.rmtree(spill, ignore_errors=True)
    return Classified(int(sum(by_class.values())), by_class, len(tiles), tile, overlap, sum(matched.values()))


def _write_columns(files: list[Path], codes: np.ndarray, height: np.ndarray) -> dict[int, int]:
    """Step 3: each file with classification and height (null where not kept or not placed)."""
    by_class: dict[int, int] = {}
    first = 0
    for f in files:
        pf = pq.ParquetFile(f)
        table = pf.read()
        n = table.num_rows
        kept = (np.asarray(pc.fill_null(table.column("kept"), False))
                & np.isfinite(table.column("x").to_numpy(zero_copy_only=False))
                & np.isfinite(table.column("y").to_numpy(zero_copy_only=False)))
        c, h = codes[first:first + n], height[first:first + n]
        for code, count in zip(*np.unique(c[kept], return_counts=True)):
            by_class[int(code)] = by_class.get(int(code), 0) + int(count)
        for name, values in (("classification", pa.array(c, pa.uint8(), mask=~kept)),
                             ("height", pa.array(h.astype(np.float64), pa.float64(), mask=~kept))):
            field = COLUMNS[name].field
            if name in table.column_names:
                table = table.set_column(table.column_names.index(name), field, values)
            else:
                table = table.append_column(field, values)
        tmp = f.with_name(f.name + ".tmp")
        group = pf.metadata.row_group(0).num_rows if pf.metadata.num_row_groups else n
        pq.write_table(table, tmp, row_group_size=max(group, 1), compression="zstd")
        tmp.replace(f)
        first += n
    return by_class


def summary_line(result: Classified) -> str:
    names = {1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation", 5: "high vegetation",
             6: "building", 7: "low noise"}
    parts = ", ".join(f"{names.get(k, k)} {v:,}" for k, v in sorted(result.by_class.items()))
    return (f"fwl classify: {result.echoes:,} kept echoes in {result.tiles} tiles of {result.tile_m:g} m "
            f"(overlap {result.overlap_m:g} m): {parts}; {result.points_classified:,} points of the LAS and COPC "
            f"files classified")

