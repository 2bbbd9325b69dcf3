"""The output folder of a run, by name: its folders and marker files, each range's parts and mark, and the
per-file outputs assembled from the parts. Every name written under an output folder is spelled here.

    fwl-output.json                  the manifest: written first, claims the folder (pipeline.outputs)
    fwl.lock                         held by the one command writing the folder (pipeline.lock)
    run.json                         written last: the mark of a complete run
    echoes/<stem>-<range>.parquet    a range's tables; fwl compact replaces the echo parts by <stem>-tile-NNNN
    pulses/<stem>-<range>.parquet
    rejected/<stem>-<range>.parquet  a range's Rejections; rejected/<stem>.parquet a file's
    parts/<stem>-<range>.las|.mcap   a range's point cloud and MCAP parts, until its file is assembled
    parts/<stem>-<range>.json        the range's mark, written last: its planned pulses and its files' sizes
    parts/<stem>-<range>.fault       a fault of the machine that stopped the range, for the driver (pipeline.faults)
    parts/plans/<stem>.json          a file's plan
    las/<stem>.las, copc/<stem>.copc.laz, mcap/<stem>.mcap   assembled from the parts
    logs/                            the driver's and each worker's log

<range> is the range's first point, 12 digits. Names only: writing and trusting a range's mark is
pipeline.marks, assembling a file from its parts pipeline.assemble, writing rejected/ pipeline.rejections,
the logs pipeline.logs.
"""

from __future__ import annotations

import re
from pathlib import Path

from pipeline.records import ReadTask

MANIFEST = "fwl-output.json"
RUN_JSON = "run.json"
LOCK = "fwl.lock"  # names the command writing the folder, while it does (pipeline.lock)
ECHOES, PULSES, REJECTED = "echoes", "pulses", "rejected"  # the tables, a Parquet part per range
LAS, COPC, MCAP = "las", "copc", "mcap"  # the per-file outputs
LOGS = "logs"
PARTS = "parts"  # range parts and marks, removed once the files are assembled
# the folders a run writes into; nothing else under the output folder is ours
OUTPUT_DIRS = (ECHOES, PULSES, REJECTED, LAS, MCAP, COPC, LOGS, PARTS)
TABLES = (ECHOES, PULSES, REJECTED)
# fwl grid's default output inside a run (pipeline.grid): its files are those its mark lists, and go with the run
GRID_DIR, GRID_MARK = "grid", "fwl-grid.json"
PLANS = Path(PARTS) / "plans"
COMPACT = Path(PARTS) / "compact"  # fwl compact's staging
STAGED = COMPACT / ECHOES  # the new echoes/, complete before it replaces the old
REPLACED = COMPACT / "replaced"  # the old echoes/, between the two renames
FINISHED = Path(PARTS) / "compact-finished"  # the staging of a finished compaction, on its way out
RANGE_DIGITS = 12
FAULT_SUFFIX = ".fault"  # parts/<name>.fault: a worker's note of a fault of the machine (pipeline.faults)
# after an input's stem, as regular expressions: a range's part, a tile of fwl compact, a bucket of its staging
RANGE_SUFFIX, TILE_SUFFIX, BUCKET_SUFFIX = rf"-\d{{{RANGE_DIGITS}}}", r"-tile-\d{4,}", r"-bucket-\d{4,}"


def part_name(stem: str, range_start: int) -> str:
    """A range's files' name: its input's stem and its first point."""
    return f"{stem}-{range_start:0{RANGE_DIGITS}d}"


def range_start(part: str | Path) -> int | None:
    """The first point of the range a part's name says (<stem>-<range>.*), None for another name (a tile's)."""
    m = re.search(rf"-(\d{{{RANGE_DIGITS}}})$", Path(part).stem)
    return int(m.group(1)) if m else None


def tile_name(stem: str, index: int) -> str:
    return f"{stem}-tile-{index:04d}"


def bucket_name(stem: str, index: int) -> str:
    return f"{stem}-bucket-{index:04d}"


def plan_path(output: str | Path, stem: str) -> Path:
    return Path(output) / PLANS / f"{stem}.json"


def echo_tables_path(output: str | Path, stem: str) -> Path:
    """The echo tables a file's plan made (fwcore.instrument.shape.echo_shapes_of), for the workers to take."""
    return Path(output) / PLANS / f"{stem}.pickle"


def part_paths(output: str | Path, task: ReadTask) -> dict[str, Path]:
    """A range's parts by what they hold: its two tables' parts, and its LAS and MCAP parts under parts/."""
    name, out = part_name(task.source.stem, task.start), Path(output)
    return {ECHOES: out / ECHOES / f"{name}.parquet", PULSES: out / PULSES / f"{name}.parquet",
            LAS: out / PARTS / f"{name}.las", MCAP: out / PARTS / f"{name}.mcap"}


def file_rejected(output: str | Path, stem: str) -> Path:
    """rejected/<stem>.parquet: an input's own rejected rows (the file rejected whole; or none, when nothing of
    it was)."""
    return Path(output) / REJECTED / f"{stem}.parquet"


def rejected_files(output: str | Path, stem: str) -> list[Path]:
    """An input's rejected/ files: its own (file_rejected, there or not) and those of its ranges there now."""
    ranges = (Path(output) / REJECTED).glob(f"{stem}-" + "[0-9]" * RANGE_DIGITS + ".parquet")
    return [file_rejected(output, stem)] + sorted(ranges)


def file_outputs(output: str | Path, stem: str, laz: bool) -> dict[str, Path]:
    """An input's files assembled from its ranges' parts."""
    out = Path(output)
    return {LAS: out / LAS / f"{stem}{'.laz' if laz else '.las'}", COPC: out / COPC / f"{stem}.copc.laz",
            MCAP: out / MCAP / f"{stem}.mcap"}


# ---------------------------------------------------------------- a range's mark

def progress_mark(output: str | Path, stem: str, range_start: int) -> Path:
    """Where a range's end is recorded: the driver's progress bar counts these, a resumed run trusts them."""
    return Path(output) / PARTS / f"{part_name(stem, range_start)}.json"


def range_files(output: str | Path, task: ReadTask) -> list[Path]:
    """Every file a range may write, by its deterministic names: its parts and its rejections."""
    parts = part_paths(output, task)
    rejected = Path(output) / REJECTED / f"{part_name(task.source.stem, task.start)}.parquet"
    return [parts[ECHOES], parts[PULSES], rejected, parts[LAS], parts[MCAP]]
