"""`fwl classify RUN_DIR`: every kept echo of a finished run classified (ASPRS: 2 ground, 6 building, 3/4/5
vegetation by height, 7 low noise, 1 otherwise) with its height above the terrain, written into the run's echo table
(`classification`, `height`; null for spurious echoes). `fwl grid` runs it first when the table has no classes.

Tile by tile with an overlap (fwcore.terrain.tiles), so that a survey of any size streams, the tiles on the
runner's workers as `fwl run`'s ranges are (pipeline.tiled):

    1. the driver: each tile's task names the echo table's row groups whose bounds (Parquet statistics) meet its
       core and margin; no echo is read in the driver
    2. the workers, a tile each (classify_tile): its kept echoes read from those row groups, the ground filter,
       roofs and heights over its core and margin; its core's echoes' results by their row in the table into the
       tile's result file (under the run's .classify/ folder, removed at the end), then its mark
    3. the workers, a file each (write_file_columns): the results of the tiles that read the file, into its two
       columns (atomically: a file is old or new, never half)
    4. the run's LAS and COPC files rewritten with the classes (pipeline.classes_las)

An interrupted call leaves .classify/ behind: `resume` (--resume) keeps the tiles and files with a mark.
Memory: one tile's echoes a worker, or one echo file; the driver holds no echo.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from fwcore.grid import Grid
from fwcore.terrain.classes import asprs_classes
from fwcore.terrain.ground import GroundConfig
from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M, tile_terrain, tiles_over
from pipeline.classes_las import classify_point_clouds
from pipeline.echo_table import echo_bounds, echo_files
from pipeline.outputs import read_run
from pipeline.tables import COLUMNS
from pipeline.tiled import (IN_PROCESS_ECHOES, FileTask, TileTask, mark_tile, read_tile, result_path, run_tiles,
                            start_work, table_bounds, table_parts, tile_results, tile_tasks)

SPILL_DIR = ".classify"
TILE_COLUMNS = ("x", "y", "z", "pulse_id", "echo_index")
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


def classify_tile(task: TileTask, config: GroundConfig) -> None:
    """A tile's work, on a worker: the ground filter, roofs and heights over its echoes (core and margin, read
    from the echo table's row groups that meet them); its core's results by their row in the table into its
    result file, a row group per echo file (a file's task reads its own), then its mark."""
    e = read_tile(task, TILE_COLUMNS)
    if e:
        t = task.tile
        result = tile_terrain(t, e["x"], e["y"], e["z"], e["pulse_id"], e["echo_index"], config)
        core = t.in_core(e["x"], e["y"])
        table = pa.table({"row": e["row"][core], "ground": result.ground[core], "building": result.building[core],
                          "noise": result.noise[core], "height": result.height[core].astype(np.float32)})
        tmp = result_path(task).with_suffix(".tmp")
        rows = table.column("row").to_numpy()
        with pq.ParquetWriter(tmp, table.schema) as writer:
            for s in task.sources:  # the rows are in the table's order: each file's a slice
                lo, hi = np.searchsorted(rows, [s.first, s.first + s.rows])
                if hi > lo:
                    writer.write_table(table.slice(lo, hi - lo))
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
    parts = table_parts(files)
    bounds = table_bounds(parts) or echo_bounds(files)
    if bounds is None:
        raise ValueError(f"{run_dir}: the run kept no echo with coordinates: nothing to classify")
    grid = Grid.covering(*bounds, DEFAULT_CELL_M)
    work = run_dir / SPILL_DIR
    tasks = tile_tasks(work, tiles_over(grid, tile, overlap), parts)
    settings = {"tile_m": tile, "overlap_m": overlap, "config": dataclasses.asdict(config),
                "echo_files": [[str(p.path.name), p.rows] for p in parts]}  # rows: a rewritten file keeps them
    start_work(work, settings, resume)
    readers: dict[str, list[int]] = {}
    for t in tasks:
        for s in t.sources:
            readers.setdefault(s.path, []).append(t.index)
    file_tasks = [FileTask(str(work), i, str(p.path), p.first, tuple(readers.get(str(p.path), ())))
                  for i, p in enumerate(parts)]
    run_tiles(functools.partial(classify_tile, config=config), tasks, beam_args,  # one job: the tiles, then the files
              small=sum(p.rows for p in parts) <= IN_PROCESS_ECHOES, then=(write_file_columns, file_tasks))
    by_class: dict[int, int] = {}
    for _, path in tile_results(file_tasks, ".json"):
        for code, count in json.loads(path.read_text()).items():
            by_class[int(code)] = by_class.get(int(code), 0) + count
    matched = classify_point_clouds(run_dir, files, work)
    shutil.rmtree(work, ignore_errors=True)  # kept until here: an interrupted call resumes from it
    return Classified(int(sum(by_class.values())), by_class, len(tasks), tile, overlap, sum(matched.values()))


def file_classes(task: FileTask, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """A file's classes and heights (rows long; class 1 and NaN where no tile's core has the echo), from the
    results of the tiles that read it."""
    ground, building, noise = np.zeros(rows, bool), np.zeros(rows, bool), np.zeros(rows, bool)
    height = np.full(rows, np.nan, np.float32)
    for k in task.tiles:
        path = result_path(TileTask(task.folder, k, None))
        if not path.exists():
            continue
        table = pq.read_table(path, filters=[("row", ">=", task.first), ("row", "<", task.first + rows)])
        r = {c: table.column(c).to_numpy() for c in table.column_names}
        at = r["row"] - task.first
        ground[at], building[at], noise[at], height[at] = r["ground"], r["building"], r["noise"], r["height"]
    return asprs_classes(height, ground, building, noise), height


def write_file_columns(task: FileTask) -> None:
    """A file's work, on a worker: its classification and height columns (null where not kept or not placed)
    from the results of the tiles that read it, written atomically; its kept echoes by class into its result;
    then its mark."""
    f = Path(task.path)
    pf = pq.ParquetFile(f)
    table = pf.read()
    n = table.num_rows
    c, h = file_classes(task, n)
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

