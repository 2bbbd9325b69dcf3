"""`fwl classify RUN_DIR`: every kept echo of a finished run classified (ASPRS: 2 ground, 6 building, 3/4/5
vegetation by height, 7 low noise, 1 otherwise) with its height above the terrain, written into the run's echo table
(`classification`, `height`; null for spurious echoes). `fwl grid` runs it first when the table has no classes.

Tile by tile with an overlap (fwcore.terrain.tiles), so that a survey of any size streams, the tiles on the
runner's workers as `fwl run`'s ranges are (pipeline.tiled):

    1. the driver: the kept echoes, a record batch at a time, appended to the spill file of each tile whose core
       or margin holds them (under the run's .classify/ folder, removed at the end)
    2. the workers, a tile each (classify_tile): the ground filter, roofs and heights over its core and margin;
       its core's echoes' results by their row in the table into the tile's result file, then its mark
    3. the driver gathers the results; the workers, a file each (write_file_columns), write them into each echo
       file's two columns (atomically: a file is old or new, never half)
    4. the run's LAS and COPC files rewritten with the classes (pipeline.classes_las)

An interrupted call leaves .classify/ behind: `resume` (--resume) keeps its spill and the tiles with a mark.
Memory: one tile's echoes a worker, plus five bytes per echo of the survey in the driver for step 3.
"""

from __future__ import annotations

import dataclasses
import functools
import json
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
from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M, tile_terrain, tiles_over
from pipeline.classes_las import classify_point_clouds
from pipeline.echo_table import BATCH_ROWS, echo_bounds, echo_files
from pipeline.outputs import read_run
from pipeline.tables import COLUMNS
from pipeline.tiled import (IN_PROCESS_ECHOES, FileTask, TileTask, mark_tile, read_spill, result_path, run_tiles,
                            spill, spilled_echoes, start_spill, tile_is_done, tile_results)

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


def _kept_batches(files: list[Path], columns: list[str]) -> Iterator[dict[str, np.ndarray]]:
    """The kept and placed rows' columns with their "row" (in the whole table), a record batch at a time."""
    first = 0
    for f in files:
        for batch in pq.ParquetFile(f).iter_batches(batch_size=BATCH_ROWS, columns=[*columns, "kept"]):
            x, y = batch.column("x").to_numpy(zero_copy_only=False), batch.column("y").to_numpy(zero_copy_only=False)
            kept = np.asarray(pc.fill_null(batch.column("kept"), False)) & np.isfinite(x) & np.isfinite(y)
            rows = np.flatnonzero(kept)
            if rows.size:
                values = {c: batch.column(c).to_numpy(zero_copy_only=False)[rows] for c in columns}
                values["row"] = rows + first
                yield values
            first += batch.num_rows


def classify_tile(task: TileTask, config: GroundConfig) -> None:
    """A tile's work, on a worker: the ground filter, roofs and heights over its spilled echoes (core and
    margin); its core's results by their row in the table into its result file, then its mark."""
    e = read_spill(task)
    if e:
        t = task.tile
        result = tile_terrain(t, e["x"], e["y"], e["z"], e["pulse_id"], e["echo_index"], config)
        core = t.in_core(e["x"], e["y"])
        table = pa.table({"row": e["row"][core], "ground": result.ground[core], "building": result.building[core],
                          "noise": result.noise[core], "height": result.height[core].astype(np.float32)})
        tmp = result_path(task).with_suffix(".tmp")
        pq.write_table(table, tmp)
        tmp.replace(result_path(task))
    mark_tile(task)


def classify_run(run_dir: str | Path, tile: float = DEFAULT_TILE_M, overlap: float = DEFAULT_OVERLAP_M,
                 config: GroundConfig = GroundConfig(), beam_args: list[str] | None = None,
                 resume: bool = False) -> Classified:
    """Classes and heights of a finished run's kept echoes, into its echo table (see the module). The tiles run
    on the runner `beam_args` names (pipeline.tiled); `resume` keeps the tiles an interrupted call finished."""
    run_dir = Path(run_dir)
    read_run(run_dir)  # a folder that is not a finished run is refused here
    files = echo_files(run_dir)
    bounds = echo_bounds(files)
    if bounds is None:
        raise ValueError(f"{run_dir}: the run kept no echo with coordinates: nothing to classify")
    grid = Grid.covering(*bounds, DEFAULT_CELL_M)
    spill_dir = run_dir / SPILL_DIR
    tasks = [TileTask(str(spill_dir), k, t) for k, t in enumerate(tiles_over(grid, tile, overlap))]
    settings = {"tile_m": tile, "overlap_m": overlap, "config": dataclasses.asdict(config),
                "echo_files": [[f.name, f.stat().st_size] for f in files]}
    if not start_spill(spill_dir, settings, resume):
        spill(_kept_batches(files, [c for c in SPILL_COLUMNS if c != "row"]), tasks, SPILL_COLUMNS)
    run_tiles(functools.partial(classify_tile, config=config), tasks, beam_args,
              small=spilled_echoes(spill_dir) <= IN_PROCESS_ECHOES)
    rows = sum(pq.ParquetFile(f).metadata.num_rows for f in files)
    ground, building, noise = np.zeros(rows, bool), np.zeros(rows, bool), np.zeros(rows, bool)
    height = np.full(rows, np.nan, np.float32)
    for _, path in tile_results(tasks):
        table = pq.read_table(path)
        r = {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}
        ground[r["row"]], building[r["row"]], noise[r["row"]] = r["ground"], r["building"], r["noise"]
        height[r["row"]] = r["height"]
    codes = asprs_classes(height, ground, building, noise)
    by_class = _write_columns(files, codes, height, spill_dir, beam_args)
    del ground, building, noise, height, codes
    matched = classify_point_clouds(run_dir, files, spill_dir)
    shutil.rmtree(spill_dir, ignore_errors=True)  # kept until here: an interrupted call resumes from it
    return Classified(int(sum(by_class.values())), by_class, len(tasks), tile, overlap, sum(matched.values()))


def _write_columns(files: list[Path], codes: np.ndarray, height: np.ndarray, folder: Path,
                   beam_args: list[str] | None) -> dict[int, int]:
    """Step 3: each file's slice of the classes and heights into the work folder, then each file rewritten
    with them on a worker (write_file_columns); the kept echoes by class."""
    tasks, first = [], 0
    for i, f in enumerate(files):
        n = pq.ParquetFile(f).metadata.num_rows
        task = FileTask(str(folder), i, str(f))
        if not tile_is_done(task):
            np.savez(result_path(task, ".classes.npz"), codes=codes[first:first + n], height=height[first:first + n])
        tasks.append(task)
        first += n
    run_tiles(write_file_columns, tasks, beam_args, small=first <= IN_PROCESS_ECHOES)
    by_class: dict[int, int] = {}
    for _, path in tile_results(tasks, ".json"):
        for code, count in json.loads(path.read_text()).items():
            by_class[int(code)] = by_class.get(int(code), 0) + count
    return by_class


def write_file_columns(task: FileTask) -> None:
    """A file's work, on a worker: its classification and height columns (null where not kept or not placed)
    written, atomically; its kept echoes by class into its result; then its mark."""
    f = Path(task.path)
    with np.load(result_path(task, ".classes.npz")) as given:
        c, h = given["codes"], given["height"]
    pf = pq.ParquetFile(f)
    table = pf.read()
    n = table.num_rows
    kept = (np.asarray(pc.fill_null(table.column("kept"), False))
            & np.isfinite(table.column("x").to_numpy(zero_copy_only=False))
            & np.isfinite(table.column("y").to_numpy(zero_copy_only=False)))
    counts = {int(code): int(count) for code, count in zip(*np.unique(c[kept], return_counts=True))}
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
    result_path(task, ".json").write_text(json.dumps(counts))
    mark_tile(task)


def summary_line(result: Classified) -> str:
    names = {1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation", 5: "high vegetation",
             6: "building", 7: "low noise"}
    parts = ", ".join(f"{names.get(k, k)} {v:,}" for k, v in sorted(result.by_class.items()))
    return (f"fwl classify: {result.echoes:,} kept echoes in {result.tiles} tiles of {result.tile_m:g} m "
            f"(overlap {result.overlap_m:g} m): {parts}; {result.points_classified:,} points of the LAS and COPC "
            f"files classified")

