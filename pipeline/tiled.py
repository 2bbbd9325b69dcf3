"""The maps' jobs over a finished run (fwl classify, fwl grid, fwl footprints) on the runners of `fwl run`: the
survey cut into tiles with their overlap (fwcore.terrain.tiles), each tile's work a plain function run on a
worker, as a range's is in `fwl run`.

    start_spill(folder, settings, resume)   the command's work folder: kept for --resume when its settings match
    start_work(folder, settings, resume)    the same, for tiles that read the table (nothing to spill)
    table_parts(files)                      the echo table's files and their row groups' x, y bounds (statistics only)
    tile_tasks(folder, tiles, parts)        a task a tile, naming the row groups its core and margin meet
    read_tile(task, columns)                on a worker: the tile's kept echoes (core and margin) from those row groups
    spill(batches, tiles, folder, columns)  the driver streams the echoes once into each tile's file (fwl footprints)
    run_tiles(work, tasks, beam_args, small, then)  the job: each task without its mark run on a worker; `work(task)`
                                            writes the task's result (result_path) and then its mark (mark_tile);
                                            `then`: the files' tasks, each after the tiles that read its file
    tile_results(tasks)                     the results, in task order, as the driver assembles them
    FileTask                                a file's share of the assembly, run on the workers as a tile's

A tile's result is trusted only with its mark, written after it (pipeline.marks' habit for ranges): a resumed
command redoes only the tiles without one, and a command interrupted leaves its work folder for --resume. The
runner's set-up is pipeline.run's (`Jobs`): the DirectRunner with 2 worker processes by default, a small job in
the driver's process, one Dask partition a tile.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from fwcore.terrain.tiles import Tile
from pipeline.allocator import kept_memory

SETTINGS = "settings.json"  # what the spill was made with: a resumed command reuses it only if they match
SPILLED = "spilled.json"  # written once every tile's echoes are spilled
IN_PROCESS_ECHOES = 300_000  # a job over this many echoes or fewer runs in the driver's process (no runner given)


class Source(NamedTuple):
    """A file of the echo table a tile reads: its path, its first row in the whole table, its rows, and the row
    groups whose echoes' bounds meet the tile's core and margin."""

    path: str
    first: int
    rows: int
    groups: tuple[int, ...]


class TileTask(NamedTuple):
    """One tile's work: its number, the tile, the command's work folder (a path: workers share the disk), and the
    echo table's row groups it reads (none: its echoes were spilled, read_spill)."""

    folder: str
    index: int
    tile: Tile
    sources: tuple[Source, ...] = ()
    weight: float = 0.0  # the echoes it reads, about: the job deals the tiles to the workers by it

    @property
    def name(self) -> str:
        return f"tile-{self.index:05d}"


class FileTask(NamedTuple):
    """One file's share of an assembly (fwl classify: the classes into an echo file), as a tile's: the file, its
    first row in the table, and the tiles that read it (whose results hold its rows)."""

    folder: str
    index: int
    path: str
    first: int = 0
    tiles: tuple[int, ...] = ()

    @property
    def name(self) -> str:
        return f"file-{self.index:05d}"


def spill_path(task: TileTask) -> Path:
    return Path(task.folder) / f"{task.name}.parquet"


def result_path(task: TileTask | FileTask, suffix: str = ".parquet") -> Path:
    return Path(task.folder) / f"{task.name}.result{suffix}"


def mark_path(task: TileTask | FileTask) -> Path:
    return Path(task.folder) / f"{task.name}.done"


def mark_tile(task: TileTask | FileTask) -> None:
    """The tile's end, written after its result (atomically): a resumed command trusts the result."""
    tmp = mark_path(task).with_suffix(".tmp")
    tmp.write_text("done\n")
    tmp.replace(mark_path(task))


def tile_is_done(task: TileTask | FileTask) -> bool:
    return mark_path(task).is_file()


def start_spill(folder: Path, settings: dict, resume: bool) -> bool:
    """The work folder, ready: True when a resumed command finds its spill complete with the same settings (its
    tiles' marks then stand); else the folder is emptied (anything an earlier attempt left is redone)."""
    if resume and (folder / SPILLED).is_file():
        try:
            if json.loads((folder / SETTINGS).read_text()) == settings:
                return True
        except (OSError, ValueError):
            pass
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    (folder / SETTINGS).write_text(json.dumps(settings, sort_keys=True) + "\n")
    return False


def start_work(folder: Path, settings: dict, resume: bool) -> bool:
    """start_spill's folder for tiles that read the echo table themselves: nothing to spill, so it is complete at
    once, and a resumed command with the same settings keeps its tiles' marks."""
    kept = start_spill(folder, settings, resume)
    if not kept:
        (folder / SPILLED).write_text(json.dumps({"echoes": None}) + "\n")
    return kept


@dataclasses.dataclass(frozen=True)
class TablePart:
    """A file of the echo table: its rows, and each row group's first row and x, y bounds (xmin, ymin, xmax,
    ymax; infinite where the file has no statistics, so that every tile reads it)."""

    path: Path
    first: int
    rows: int
    group_rows: np.ndarray
    boxes: np.ndarray


def table_parts(files: list[Path]) -> list[TablePart]:
    """The echo table's files with their row groups' bounds, from the Parquet statistics (no rows read)."""
    parts, first = [], 0
    for f in files:
        meta = pq.ParquetFile(f).metadata
        names = [meta.schema.column(i).name for i in range(meta.num_columns)]
        boxes = np.tile([-np.inf, -np.inf, np.inf, np.inf], (meta.num_row_groups, 1))
        for g in range(meta.num_row_groups):
            group = meta.row_group(g)
            stats = [group.column(names.index(n)).statistics for n in ("x", "y")]
            if all(s is not None and s.has_min_max for s in stats):
                boxes[g] = (stats[0].min, stats[1].min, stats[0].max, stats[1].max)
            elif group.num_rows and all(s is not None and s.null_count == group.num_rows for s in stats):
                boxes[g] = (np.inf, np.inf, -np.inf, -np.inf)  # no coordinates: no tile's
        group_rows = np.array([meta.row_group(g).num_rows for g in range(meta.num_row_groups)], np.int64)
        parts.append(TablePart(f, first, meta.num_rows, group_rows, boxes))
        first += meta.num_rows
    return parts


def table_bounds(parts: list[TablePart]) -> tuple[float, float, float, float] | None:
    """The echoes' x, y bounds from the parts' statistics; None where a file has none (read them) or no echoes."""
    boxes = [p.boxes for p in parts if p.boxes.size]
    if not boxes:
        return None
    b = np.concatenate(boxes)
    b = b[b[:, 0] <= b[:, 2]]
    if not b.size or not np.isfinite(b).all():
        return None
    return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())


def tile_tasks(folder: Path, tiles: list[Tile], parts: list[TablePart]) -> list[TileTask]:
    """A task a tile, with the row groups whose bounds meet its core and margin (closed boxes: an echo on an
    edge is read)."""
    boxes = np.concatenate([p.boxes for p in parts]) if parts else np.zeros((0, 4))
    rows = np.concatenate([p.group_rows for p in parts]) if parts else np.zeros(0, np.int64)
    part = np.repeat(np.arange(len(parts)), [len(p.group_rows) for p in parts])
    group = np.concatenate([np.arange(len(p.group_rows)) for p in parts]) if parts else np.zeros(0, np.int64)
    tasks = []
    for k, t in enumerate(tiles):
        xmin, ymin, xmax, ymax = t.buffered
        meet = np.flatnonzero((boxes[:, 0] <= xmax) & (boxes[:, 2] >= xmin) & (boxes[:, 1] <= ymax)
                              & (boxes[:, 3] >= ymin))
        sources = []
        for i in np.unique(part[meet]):  # in the table's order
            p = parts[i]
            sources.append(Source(str(p.path), p.first, p.rows, tuple(int(g) for g in group[meet][part[meet] == i])))
        weight = float(np.sum(rows[meet] * _share(boxes[meet], t.buffered)))
        tasks.append(TileTask(str(folder), k, t, tuple(sources), weight))
    return tasks


def _share(boxes: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """The share of each row group's box inside `box` (1 where a box has no area or no bounds)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.minimum(boxes[:, 2], box[2]) - np.maximum(boxes[:, 0], box[0])
        h = np.minimum(boxes[:, 3], box[3]) - np.maximum(boxes[:, 1], box[1])
        area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        share = np.clip(w, 0, None) * np.clip(h, 0, None) / area
    return np.where(np.isfinite(share) & (area > 0), share, 1.0)


def read_tile(task: TileTask, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    """A tile's kept, placed echoes in its core and margin, read from its row groups in the table's order, by
    column, with "row" (in the whole table) and "batch" (the first row of the record batch of BATCH_ROWS of its
    file that a stream of the table, pipeline.echo_table's, reads it in: sums by batch add as the stream's do);
    empty when none."""
    from pipeline.echo_table import BATCH_ROWS

    out: dict[str, list[np.ndarray]] = {c: [] for c in (*columns, "row", "batch")}
    wanted = list(dict.fromkeys([*columns, "x", "y", "kept"]))
    for s in task.sources:
        pf = pq.ParquetFile(s.path)
        starts = np.concatenate([[0], np.cumsum([pf.metadata.row_group(g).num_rows
                                                 for g in range(pf.metadata.num_row_groups)])])
        for g in s.groups:
            table = pf.read_row_group(g, columns=wanted)
            x, y = table.column("x").to_numpy(), table.column("y").to_numpy()
            keep = (np.asarray(pc.fill_null(table.column("kept"), False)) & np.isfinite(x) & np.isfinite(y)
                    & task.tile.in_buffered(x, y))
            rows = np.flatnonzero(keep)
            if not rows.size:
                continue
            for c in columns:
                out[c].append(table.column(c).to_numpy()[rows])
            in_file = starts[g] + rows
            out["row"].append(s.first + in_file)
            out["batch"].append(s.first + in_file // BATCH_ROWS * BATCH_ROWS)  # the batch's first row
    if not out["row"]:
        return {}
    return {c: np.concatenate(v) for c, v in out.items()}


def spill(batches: Iterable[dict[str, np.ndarray]], tasks: list[TileTask], columns: tuple[str, ...]) -> int:
    """Each tile's echoes (core and margin) appended to its spill file, a record batch at a time; the echoes
    read. The work folder's SPILLED mark is written at the end."""
    boxes = np.array([t.tile.buffered for t in tasks])
    writers: dict[int, pq.ParquetWriter] = {}
    echoes = 0
    try:
        for b in batches:
            x, y = b["x"], b["y"]
            if not x.size:
                continue
            echoes += x.size
            near = np.flatnonzero((boxes[:, 0] <= x.max()) & (boxes[:, 2] > x.min()) & (boxes[:, 1] <= y.max())
                                  & (boxes[:, 3] > y.min()))
            for k in near:
                inside = tasks[k].tile.in_buffered(x, y)
                if inside.any():
                    table = pa.table({c: b[c][inside] for c in columns})
                    if k not in writers:
                        writers[k] = pq.ParquetWriter(spill_path(tasks[k]), table.schema)
                    writers[k].write_table(table)
    finally:
        for w in writers.values():
            w.close()
    if tasks:
        (Path(tasks[0].folder) / SPILLED).write_text(json.dumps({"echoes": echoes}) + "\n")
    return echoes


def spilled_echoes(folder: Path) -> int:
    return int(json.loads((folder / SPILLED).read_text())["echoes"])


def read_spill(task: TileTask) -> dict[str, np.ndarray]:
    """A tile's spilled echoes by column (empty when none fell in the tile)."""
    path = spill_path(task)
    if not path.exists():
        return {}
    table = pq.read_table(path)
    return {c: table.column(c).to_numpy() for c in table.column_names}


def run_tiles(work: Callable, tasks: list[TileTask] | list[FileTask], beam_args: list[str] | None,
              small: bool, then: tuple[Callable, list[FileTask]] | None = None) -> int:
    """The tiles' job on the runner `beam_args` name (pipeline.options: the DirectRunner with 2 workers when none):
    `work(task)` for each task without its mark; `small` lets the default runner keep the job in the driver's
    process. `then` (work, file tasks): in the same job, each file's task once every tile that reads it (its
    `tiles`) has ended (on Dask, a second job after the tiles'). The tasks run."""
    import apache_beam as beam
    from apache_beam.options.pipeline_options import DirectOptions

    from pipeline.options import check_beam_args, runner_given
    from pipeline.run import Jobs

    todo = [t for t in tasks if not tile_is_done(t)]
    later = [t for t in (then[1] if then else []) if not tile_is_done(t)]
    if not todo and not later:
        return 0
    options = check_beam_args(list(beam_args or []))
    jobs = Jobs(options, small_in_process=not runner_given(list(beam_args or [])))
    workers = 1 if jobs.dask else max(int(options.view_as(DirectOptions).direct_num_workers or 1), 1)
    todo = balanced_order(todo, workers)

    def build_tiles(p):  # Create keeps the order, and so the shares Reshuffle deals the workers (balanced_order)
        return (p | "Tiles" >> beam.Create(todo, reshuffle=False) | "Spread" >> beam.Reshuffle()
                | "TileWork" >> beam.Map(_run_one, work))

    def build(p):
        done = build_tiles(p) if todo else []
        if later:
            readers: dict[int, list[int]] = {}
            for f in later:
                for k in f.tiles:
                    readers.setdefault(k, []).append(f.index)
            files = p | "Files" >> beam.Create([(f.index, f) for f in later], reshuffle=False)
            groups = {"file": files}
            if todo:
                groups["after"] = done | "Feeds" >> beam.FlatMap(_fed, readers)
            (groups | "AfterTiles" >> beam.CoGroupByKey() | "FileTasks" >> beam.FlatMap(_file_task)
             | "SpreadFiles" >> beam.Reshuffle() | "FileWork" >> beam.Map(_run_one, then[0]))

    def files_after(p):
        (p | "Files" >> beam.Create(later, reshuffle=False) | "SpreadFiles" >> beam.Reshuffle()
         | "FileWork" >> beam.Map(_run_one, then[0]))

    if jobs.dask and todo and later:  # Dask's CoGroupByKey is a shuffle of a bag a task: at 50 million echoes
        jobs.run(len(todo), build_tiles, small, dask_share(len(todo)))  # classify took 1.22x and peaked at 1.5x
        jobs.run(len(later), files_after, small, dask_share(len(later)))  # with it (docs/benchmarks.md)
    else:
        jobs.run(len(todo) + len(later), build, small, dask_share(len(todo) + len(later)))
    missing = [t.name for t in [*todo, *later] if not tile_is_done(t)]
    if missing:  # a worker that ended without its mark: nothing of the tile is trusted
        raise RuntimeError(f"{(todo or later)[0].folder}: {', '.join(missing[:5])} ended without their result; run "
                           f"again with --resume")
    return len(todo) + len(later)


# At most this many bag partitions a job on Dask: its scheduler's work and memory grow with the tasks (50 million
# echoes: 624 tiles, 1,036 files), and a few dozen workers stay busy on 128. `--dask_npartitions` overrides.
DASK_PARTITIONS = 128


def dask_share(n: int) -> int:
    """Tasks a Dask bag partition holds so that a job of n has at most DASK_PARTITIONS: consecutive tasks of the
    heaviest-first order, so the heaviest start first and the last partitions are the lightest."""
    return max(1, -(-n // DASK_PARTITIONS))


def balanced_order(tasks: list, workers: int) -> list:
    """The tasks, heaviest first (their `weight`, where they have one), dealt in a snake over `workers` (0, 1, 1,
    0, 0, 1, ...): the DirectRunner deals a Reshuffle's elements in turn, so each worker's share weighs about
    the same; a runner that hands out tasks as workers free up (Dask) gets the heaviest first."""
    order = sorted(tasks, key=lambda t: -getattr(t, "weight", 0.0))
    rows = [order[i:i + workers] for i in range(0, len(order), workers)]
    return [t for j, row in enumerate(rows) for t in (row[::-1] if j % 2 else row)]


def _run_one(task: TileTask | FileTask, work: Callable) -> int:
    with kept_memory():  # a Dask worker's eager trimming faulted in every array's pages anew (pipeline.allocator)
        work(task)
    return task.index


def _fed(tile: int, readers: dict[int, list[int]]) -> list[tuple[int, None]]:
    """A tile's end, to the files it read: their tasks wait for it."""
    return [(f, None) for f in readers.get(tile, ())]


def _file_task(grouped: tuple[int, dict]) -> list[FileTask]:
    return list(grouped[1]["file"])


def tile_results(tasks: list, suffix: str = ".parquet") -> Iterator[tuple[TileTask | FileTask, Path]]:
    """The tasks whose work wrote a result, with its path, in task order."""
    for t in tasks:
        path = result_path(t, suffix)
        if path.exists():
            yield t, path
