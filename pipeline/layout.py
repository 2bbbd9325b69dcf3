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

<range> is the range's first point, 12 digits. A range's mark is the last thing it writes, and lists its
files: a resumed run keeps a range whose mark and files are there, and redoes every other from scratch
(`range_is_complete`, `remove_range_files`).
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
from pathlib import Path

from pipeline.copc import assemble_copc, has_point_cloud_parts
from pipeline.records import RangePart, ReadTask, Rejection
from pipeline.sinks import assemble_las, assemble_mcap, remove_parts, write_json, write_part
from pipeline.tables import rejected_table

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


def mark_range_done(output: str | Path, task: ReadTask, planned: int, rejected: int) -> Path:
    """The range's end: its planned pulses, those rejected, and the files it wrote with their sizes (written
    last, atomically)."""
    written = {p.relative_to(output).as_posix(): p.stat().st_size for p in range_files(output, task) if p.exists()}
    return write_json(progress_mark(output, task.source.stem, task.start),
                      {"pulses": planned, "rejected": rejected, "files": written})


def range_is_complete(output: str | Path, task: ReadTask) -> bool:
    """Whether a range ended (its mark is there) and every file it wrote is still there, at its size."""
    try:
        mark = json.loads(progress_mark(output, task.source.stem, task.start).read_text())
        return all((Path(output) / f).stat().st_size == size for f, size in mark["files"].items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def remove_range_files(output: str | Path, task: ReadTask) -> None:
    """A range to be redone loses what an earlier attempt left of it: a part without a mark is never trusted."""
    mark = progress_mark(output, task.source.stem, task.start)
    remove_parts(range_files(output, task) + [mark, mark.with_suffix(FAULT_SUFFIX)])


# ---------------------------------------------------------------- rejections, logs

def write_rejections(output: str | Path, task: ReadTask, rows: list[Rejection]) -> Path:
    """A range's Rejections -> rejected/<stem>-<range>.parquet (one file per range, so a bad file stays bounded)."""
    rows = sorted(rows, key=lambda r: (r.pulse_id, r.stage))
    return write_part(rejected_table(rows), Path(output) / REJECTED, part_name(task.source.stem, task.start))


def write_file_rejection(output: str | Path, rejection: Rejection) -> Path:
    """A file that could not be planned -> rejected/<stem>.parquet."""
    return write_part(rejected_table([rejection]), Path(output) / REJECTED, rejection.stem)


def log_to_file(output: str | Path) -> None:
    """A worker's own log lines go to logs/ under the output folder (once per process and folder: a process
    that runs jobs for several folders, such as the driver's in-process jobs, logs each into its own)."""
    logger = logging.getLogger("fwl")
    logs = Path(output) / LOGS
    for h in [h for h in logger.handlers if getattr(h, "fwl_worker", None)]:
        if h.fwl_worker == str(logs) and Path(h.baseFilename).exists():  # not a replaced run's
            return
        logger.removeHandler(h)
        h.close()
    logs.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(logs / f"worker-{socket.gethostname()}-{os.getpid()}.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s"))
    handler.fwl_worker = str(logs)
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False  # not to the runner's logging, which a terminal may show


# ---------------------------------------------------------------- per file

def written_parts(output: str | Path, tasks: list[ReadTask],
                  formats: frozenset[str]) -> list[tuple[str, list[RangePart]]]:
    """After the ranges' job, each input's RangeParts as the files under parts/ show them (a range is written
    whole or not at all, and a range's stale parts are removed before it is redone), in plan order."""
    files: dict[str, list[RangePart]] = {}
    for task in tasks:
        paths = part_paths(output, task)
        las = str(paths[LAS]) if has_point_cloud_parts(formats) and paths[LAS].exists() else ""
        mcap = str(paths[MCAP]) if "mcap" in formats and paths[MCAP].exists() else ""
        if las or mcap:
            files.setdefault(task.source.stem, []).append(RangePart(
                task.source.stem, task.source.path, task.start, las, mcap, task.source.adjusted_standard_gps_time))
    return list(files.items())


def assemble_file(item: tuple[str, list[RangePart]], output: str | Path, laz: bool,
                  formats: frozenset[str] = frozenset(("las", "mcap"))) -> str:
    """One input's RangeParts -> las/<stem>.las (or .laz), copc/<stem>.copc.laz and mcap/<stem>.mcap, streamed
    from the parts in range order; the parts are removed once in the files."""
    stem, ranges = item
    ranges = sorted(ranges, key=lambda r: r.range_start)
    las = [Path(r.las) for r in ranges if r.las]
    mcap = [Path(r.mcap) for r in ranges if r.mcap]
    paths = file_outputs(output, stem, laz)
    if las and "las" in formats:
        assemble_las(las, paths[LAS], laz)
    if las and "copc" in formats:
        assemble_copc(las, paths[COPC])
    if mcap:
        assemble_mcap(mcap, paths[MCAP], ranges[0].adjusted_standard_gps_time)
    remove_parts(las + mcap)
    return stem
