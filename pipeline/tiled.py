"""The maps' jobs over a finished run (fwl classify, fwl grid, fwl footprints) on the runners of `fwl run`: the
survey cut into tiles with their overlap (fwcore.terrain.tiles), each tile's work a plain function run on a
worker, as a range's is in `fwl run`.

    start_spill(folder, settings, resume)   the command's work folder: kept for --resume when its settings match
    spill(batches, tiles, folder, columns)  the driver streams the echoes once into each tile's file (core and margin)
    run_tiles(work, tasks, beam_args, small)  the job: each task without its mark run on a worker; `work(task)` writes
                                            the task's result (result_path) and then its mark (mark_tile)
    tile_results(tasks)                     the results, in task order, as the driver assembles them
    FileTask                                a file's share of the assembly, run on the workers as a tile's

A tile's result is trusted only with its mark, written after it (pipeline.marks' habit for ranges): a resumed
command redoes only the tiles without one, and a command interrupted leaves its work folder for --resume. The
runner's set-up is pipeline.run's (`Jobs`): the DirectRunner with 2 worker processes by default, a small job in
the driver's process, one Dask partition a tile.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.terrain.tiles import Tile

SETTINGS = "settings.json"  # what the spill was made with: a resumed command reuses it only if they match
SPILLED = "spilled.json"  # written once every tile's echoes are spilled
IN_PROCESS_ECHOES = 300_000  # a job over this many echoes or fewer runs in the driver's process (no runner given)


class TileTask(NamedTuple):
    """One tile's work: its number, the tile, and the command's work folder (a path: workers share the disk)."""

    folder: str
    index: int
    tile: Tile

    @property
    def name(self) -> str:
        return f"tile-{self.index:05d}"


class FileTask(NamedTuple):
    """One file's share of an assembly (fwl classify: the classes into an echo file), as a tile's."""

    folder: str
    index: int
    path: str

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
              small: bool) -> int:
    """The tiles' job on the runner `beam_args` name (pipeline.options: the DirectRunner with 2 workers when none):
    `work(task)` for each task without its mark; `small` lets the default runner keep the job in the driver's
    process. The tasks run."""
    import apache_beam as beam

    from pipeline.options import check_beam_args, runner_given
    from pipeline.run import Jobs

    todo = [t for t in tasks if not tile_is_done(t)]
    if not todo:
        return 0
    options = check_beam_args(list(beam_args or []))
    jobs = Jobs(options, small_in_process=not runner_given(list(beam_args or [])))
    jobs.run(len(todo), lambda p: (p | "Tiles" >> beam.Create(todo) | "Spread" >> beam.Reshuffle()
                                   | "TileWork" >> beam.Map(_run_one, work)), small)
    missing = [t.index for t in todo if not tile_is_done(t)]
    if missing:  # a worker that ended without its mark: nothing of the tile is trusted
        raise RuntimeError(f"{tasks[0].folder}: tiles {missing[:5]} ended without their result; run again with "
                           f"--resume")
    return len(todo)


def _run_one(task: TileTask | FileTask, work: Callable) -> int:
    work(task)
    return task.index


def tile_results(tasks: list, suffix: str = ".parquet") -> Iterator[tuple[TileTask | FileTask, Path]]:
    """The tasks whose work wrote a result, with its path, in task order."""
    for t in tasks:
        path = result_path(t, suffix)
        if path.exists():
            yield t, path
