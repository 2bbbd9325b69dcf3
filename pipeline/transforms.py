"""The Beam transforms: a thin layer over plain functions (pipeline.stages, pipeline.plan). A run is three jobs:

    plan:   inputs -> Spread -> PlanFile -> parts/plans/<stem>.json          (pipeline.plan)
    ranges: ReadTasks -> Spread -> RangeStages: stages.run_range (read -> decompose -> geolocate -> write)
            -> the range's parts, its rejected/<stem>-<range>.parquet, and its mark parts/<stem>-<range>.json,
            written last
    files:  written_parts -> AssembleFiles -> las/<stem>.las, copc/<stem>.copc.laz, mcap/<stem>.mcap

One dead-letter path: a stage hands on its record and Rejections, and an
exception in a stage turns what its range still holds into Rejections with
the stage and the reason (stages.run_range). The four stages of a range run
in one ParDo, `RangeStages`, so that only the small record that leaves a
range (its RangePart) is a ParDo's output: Beam 2.77's Dask runner keeps
every output of a ParDo in the task that made it until the whole job ends
(8 MB a range otherwise). A range's rejections are all made in that one call,
so they are written there, one file per range, without a GroupByKey (on that
runner a task shuffle whose tasks grow as ranges x log(ranges), kept by the
scheduler and workers); for the same reason the files are assembled in a job
of their own.

A range's mark is the last thing it writes, and lists its files: a resumed
run keeps a range whose mark and files are there, and redoes every other
from scratch (`range_is_complete`, `remove_range_files`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import socket
import time
from pathlib import Path

import apache_beam as beam
from apache_beam.metrics import Metrics

from fwcore.config import DecompositionConfig
from fwcore.radiometry import RadiometryConfig
from pipeline.copc import assemble_copc, has_point_cloud_parts
from pipeline.plan import InputToPlan, plan_input, plan_path, planned_pulses
from pipeline.records import RangePart, ReadTask, Rejection
from pipeline.sinks import assemble_las, assemble_mcap, remove_parts, write_json, write_part
from pipeline.stages import PARTS, RangeSettings, part_name, part_paths, run_range, warm_up
from pipeline.tables import rejected_table

LOG = logging.getLogger("fwl")
NAMESPACE = "fwl"


def progress_mark(output: str | Path, stem: str, range_start: int) -> Path:
    """Where a range's end is recorded: the driver's progress bar counts these, a resumed run trusts them."""
    return Path(output) / PARTS / f"{part_name(stem, range_start)}.json"


def range_files(output: str | Path, task: ReadTask) -> list[Path]:
    """Every file a range may write, by its deterministic names: its parts (stages.part_paths) and rejections."""
    parts = part_paths(output, task)
    rejected = Path(output) / "rejected" / f"{part_name(task.source.stem, task.start)}.parquet"
    return [parts["echoes"], parts["pulses"], rejected, parts["las"], parts["mcap"]]


def mark_range_done(output: str | Path, task: ReadTask, rejected: list[Rejection]) -> Path:
    """The range's end: its planned pulses, those rejected, and the files it wrote with their sizes (written
    last, atomically)."""
    written = {p.relative_to(output).as_posix(): p.stat().st_size for p in range_files(output, task) if p.exists()}
    return write_json(progress_mark(output, task.source.stem, task.start),
                      {"pulses": planned_pulses(task), "rejected": sum(1 for r in rejected if r.pulse_id >= 0),
                       "files": written})


def range_is_complete(output: str | Path, task: ReadTask) -> bool:
    """Whether a range ended (its mark is there) and every file it wrote is still there, at its size."""
    try:
        mark = json.loads(progress_mark(output, task.source.stem, task.start).read_text())
        return all((Path(output) / f).stat().st_size == size for f, size in mark["files"].items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def remove_range_files(output: str | Path, task: ReadTask) -> None:
    """A range to be redone loses what an earlier attempt left of it: a part without a mark is never trusted."""
    remove_parts(range_files(output, task) + [progress_mark(output, task.source.stem, task.start)])


def _log_to_file(output: str) -> None:
    """A worker's own log lines go to logs/ under the output folder (once per process and folder: a process
    that runs jobs for several folders, such as the driver's in-process jobs, logs each into its own)."""
    logger = logging.getLogger("fwl")
    logs = Path(output) / "logs"
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


# ---------------------------------------------------------------- a range, all stages

def write_rejections(output: str, task: ReadTask, rows: list[Rejection]) -> Path:
    """A range's Rejections -> rejected/<stem>-<range>.parquet (one file per range, so a bad file stays bounded)."""
    rows = sorted(rows, key=lambda r: (r.pulse_id, r.stage))
    return write_part(rejected_table(rows), Path(output) / "rejected", part_name(task.source.stem, task.start))


def write_file_rejection(output: str | Path, rejection: Rejection) -> Path:
    """A file that could not be planned -> rejected/<stem>.parquet."""
    return write_part(rejected_table([rejection]), Path(output) / "rejected", rejection.stem)


class RangeStages(beam.DoFn):
    """ReadTask -> RangePart: the range through stages.run_range; its Rejections to rejected/, then its mark;
    Beam's counters from its outcome.

    Beam 2.77's Dask runner collects a ParDo's outputs in a receiver that is an argument of the
    partition's task, and a worker keeps the arguments of a finished task until every task after it,
    to the job's end, is released: as four ParDos, every range's pulses, fit and tables (8 MB a range)
    stayed in the workers for the whole run. Here they are released as soon as the range is written.
    """

    COUNTERS = ("pulses_read", "pulses_rejected", "problems", "pulses_decomposed", "echoes_kept", "echoes_spurious")

    def __init__(self, settings: RangeSettings):
        self.settings = settings
        self.counters = {name: Metrics.counter(NAMESPACE, name) for name in self.COUNTERS}

    def setup(self):
        _log_to_file(self.settings.output)
        warm_up(self.settings.config)

    def process(self, task: ReadTask):
        outcome = run_range(task, self.settings)
        if outcome.rejected:  # the one place where the dead letter leaves
            write_rejections(self.settings.output, task, outcome.rejected)
        mark_range_done(self.settings.output, task, outcome.rejected)  # the one place where a range's end is recorded
        for name, counter in self.counters.items():
            counter.inc(getattr(outcome, name))
        if outcome.part is not None:
            yield outcome.part

    def teardown(self):
        for handler in logging.getLogger("fwl").handlers:  # the worker's log file, complete
            handler.flush()


# ---------------------------------------------------------------- per file

def assemble_file(item: tuple[str, list[RangePart]], output: str, laz: bool,
                  formats: frozenset[str] = frozenset(("las", "mcap"))) -> str:
    """One input's RangeParts -> las/<stem>.las (or .laz), copc/<stem>.copc.laz and mcap/<stem>.mcap, streamed
    from the parts in range order; the parts are removed once in the files."""
    stem, ranges = item
    ranges = sorted(ranges, key=lambda r: r.range_start)
    las = [Path(r.las) for r in ranges if r.las]
    mcap = [Path(r.mcap) for r in ranges if r.mcap]
    if las and "las" in formats:
        assemble_las(las, Path(output) / "las" / f"{stem}{'.laz' if laz else '.las'}", laz)
    if las and "copc" in formats:
        assemble_copc(las, Path(output) / "copc" / f"{stem}.copc.laz")
    if mcap:
        assemble_mcap(mcap, Path(output) / "mcap" / f"{stem}.mcap", ranges[0].adjusted_standard_gps_time)
    remove_parts(las + mcap)
    return stem


def written_parts(output: str, tasks: list[ReadTask], formats: frozenset[str]) -> list[tuple[str, list[RangePart]]]:
    """After the ranges' job, each input's RangeParts as the files under parts/ show them (a range is written
    whole or not at all, and a range's stale parts are removed before it is redone), in plan order."""
    files: dict[str, list[RangePart]] = {}
    parts = Path(output) / PARTS
    for task in tasks:
        name = part_name(task.source.stem, task.start)
        las, mcap = parts / f"{name}.las", parts / f"{name}.mcap"
        las = str(las) if has_point_cloud_parts(formats) and las.exists() else ""
        mcap = str(mcap) if "mcap" in formats and mcap.exists() else ""
        if las or mcap:
            files.setdefault(task.source.stem, []).append(RangePart(
                task.source.stem, task.source.path, task.start, las, mcap, task.source.adjusted_standard_gps_time))
    return list(files.items())


# ---------------------------------------------------------------- the three jobs

class PlanFile(beam.DoFn):
    """InputToPlan -> its stem: the file's plan (pipeline.plan) to parts/plans/<stem>.json; a file that cannot
    be planned also to rejected/<stem>.parquet."""

    def __init__(self, output: str, config: DecompositionConfig, points_per_range: int, limit: int | None):
        self.output, self.config, self.points_per_range, self.limit = output, config, points_per_range, limit

    def setup(self):
        _log_to_file(self.output)

    def process(self, item: InputToPlan):
        began = time.perf_counter()
        plan = plan_input(item, self.config, self.points_per_range, self.limit)
        if plan.rejection:
            write_file_rejection(self.output, plan.rejection)
        write_json(plan_path(self.output, item.stem), plan.to_json())
        LOG.info("%s planned: %d ranges in %.2f s", item.name, len(plan.ranges), time.perf_counter() - began)
        yield item.stem


@dataclasses.dataclass
class PlanFiles(beam.PTransform):
    """The inputs, each planned by a worker."""

    output: str
    config: DecompositionConfig
    points_per_range: int
    limit: int | None = None
    spread: bool = True  # Reshuffle the files over workers (the Dask runner spreads them by its partitions)

    def expand(self, inputs):
        if self.spread:
            inputs = inputs | "Spread" >> beam.Reshuffle()
        return inputs | "PlanFile" >> beam.ParDo(PlanFile(self.output, self.config, self.points_per_range, self.limit))


@dataclasses.dataclass
class DecomposeFlight(beam.PTransform):
    """Planned ranges -> each range read, decomposed, geolocated and written (stages.run_range), with its mark."""

    config: DecompositionConfig
    output: str
    formats: frozenset[str]
    spread: bool = True  # Reshuffle the ranges over workers (the Dask runner spreads them by its partitions)
    radiometry: RadiometryConfig = RadiometryConfig()

    def expand(self, tasks):
        if self.spread:
            tasks = tasks | "Spread" >> beam.Reshuffle()
        settings = RangeSettings(self.output, self.config, self.formats, self.radiometry)
        return tasks | "RangeStages" >> beam.ParDo(RangeStages(settings))


@dataclasses.dataclass
class AssembleFiles(beam.PTransform):
    """Each input's RangeParts (written_parts) -> its point cloud and MCAP (assemble_file)."""

    output: str
    laz: bool = False
    formats: frozenset[str] = frozenset(("las", "mcap"))

    def expand(self, files):
        return files | "Assemble" >> beam.Map(assemble_file, self.output, self.laz, self.formats)
