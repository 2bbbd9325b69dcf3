"""The Beam transforms: each stage a few lines over a fwcore function. A run is three jobs:

    plan:   inputs -> Spread -> PlanFile -> parts/plans/<stem>.json          (pipeline.plan)
    ranges: ReadTasks -> Spread -> RangeStages(ReadRange -> Decompose -> Geolocate -> WriteRange)
            -> the range's parts, and its mark parts/<stem>-<range>.json, written last
    files:  written_parts -> AssembleFiles -> las/<stem>.las, mcap/<stem>.mcap
    any stage -> Rejection -> (the range's end, in RangeStages) rejected/<stem>-<range>.parquet

One dead-letter path: a stage hands on its record or Rejections, and an
exception in a stage turns its range into Rejections with the reason. Beam
2.77's Dask runner hands the consumer of a tagged output every output of the
ParDo (its ParDo collects all tags into one bag, and a tagged PCollection maps
to its producer's bag), so Rejections travel in the main stream: `_Stage`,
the base of every stage, passes them on, and `RangeStages` splits them off
once, by type, at the range's end. The four stages of a range run in one
ParDo, `RangeStages`, so that only the small record that leaves a range (its
RangePart) is a ParDo's output: that runner keeps every output of a ParDo in
the task that made it until the whole job ends (8 MB a range otherwise). A
range's rejections are all made in that one call, so they are written there,
one file per range, without a GroupByKey (on that runner a task shuffle whose
tasks grow as ranges x log(ranges), kept by the scheduler and workers); for
the same reason the files are assembled in a job of their own.

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
from typing import Iterable, Iterator

import apache_beam as beam
import numpy as np
from apache_beam.metrics import Metrics

from fwcore.config import DecompositionConfig
from fwcore.engine import decompose_batch
from fwcore.flight_radiometry import file_radiometry, range_radiometry
from fwcore.io import read_pulses
from fwcore.io.writer import write_point_cloud
from fwcore.pulses import decomposed_echoes, echo_positions, pulse_waveforms
from fwcore.radiometry import RadiometryConfig
from fwcore.records import STATUS_REASONS
from fwcore.survey import model_samples
from pipeline.plan import InputToPlan, plan_input, plan_path, planned_pulses
from pipeline.records import (DecomposedRange, GeolocatedRange, PulseRange, RangePart, ReadTask, Rejection)
from pipeline.sinks import assemble_las, assemble_mcap, remove_parts, write_json, write_mcap, write_part
from pipeline.tables import pulse_tables, rejected_table

LOG = logging.getLogger("fwl")
NAMESPACE = "fwl"
PARTS = "parts"  # under the output folder: range parts and progress marks, removed once the files are assembled


def part_name(stem: str, range_start: int) -> str:
    return f"{stem}-{range_start:012d}"


def progress_mark(output: str | Path, stem: str, range_start: int) -> Path:
    """Where a range's end is recorded: the driver's progress bar counts these, a resumed run trusts them."""
    return Path(output) / PARTS / f"{part_name(stem, range_start)}.json"


def range_files(output: str | Path, task: ReadTask) -> list[Path]:
    """Every file a range may write, by its deterministic names."""
    name, out = part_name(task.source.stem, task.start), Path(output)
    return [out / "echoes" / f"{name}.parquet", out / "pulses" / f"{name}.parquet",
            out / "rejected" / f"{name}.parquet", out / PARTS / f"{name}.las", out / PARTS / f"{name}.mcap"]


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


# ---------------------------------------------------------------- the stage base

def _pulse_rejections(task: ReadTask, pulse_ids: Iterable[int], stage: str, reason: str) -> list[Rejection]:
    s = task.source
    return [Rejection(s.name, s.stem, task.start, int(p), stage, reason) for p in pulse_ids]


class _Stage(beam.DoFn):
    """A stage of a range: Rejections pass through untouched; an exception rejects the range with its reason."""

    stage = ""

    def __init__(self, output: str):
        self.output = output
        self.rejected = Metrics.counter(NAMESPACE, "pulses_rejected")
        self.problems = Metrics.counter(NAMESPACE, "problems")  # a whole range, or missing point records

    def setup(self):
        _log_to_file(self.output)

    def process(self, element):
        if isinstance(element, Rejection):  # the one place where the dead letter is told from work
            yield element
            return
        try:
            outputs = list(self.run(element))
        except Exception as err:  # noqa: BLE001  any failure of one range must not stop the others
            LOG.exception("%s: %s failed", self.stage, element.task if hasattr(element, "task") else element)
            outputs = self.reject_range(element, f"{type(err).__name__}: {err}")
        self.rejected.inc(sum(1 for o in outputs if isinstance(o, Rejection) and o.pulse_id >= 0))
        self.problems.inc(sum(1 for o in outputs if isinstance(o, Rejection) and o.pulse_id < 0))
        yield from outputs

    def run(self, element) -> Iterator:
        raise NotImplementedError

    def reject_range(self, element, reason: str) -> list[Rejection]:
        """Every pulse of a failed range as a Rejection (one for the range when its pulses are unknown)."""
        task = element if isinstance(element, ReadTask) else element.task
        ids = None
        if isinstance(element, PulseRange):
            ids = element.pulses.pulse_id
        elif isinstance(element, DecomposedRange):  # those the engine rejected are Rejections already
            ids = element.pulses.pulse_id[element.result.status == 0]
        elif isinstance(element, GeolocatedRange):
            ids = element.pulses.column("pulse_id").to_numpy()
        where = f"points {task.point_range.start}-{task.point_range.stop}"
        if ids is None:
            return [Rejection(task.source.name, task.source.stem, task.start, -1, self.stage,
                              f"{where} ({planned_pulses(task)} pulses): {reason}")]
        return _pulse_rejections(task, ids, self.stage, f"{where}: {reason}")


# ---------------------------------------------------------------- read

class ReadRange(_Stage):
    """ReadTask -> PulseRange; a pulse whose packet cannot be read -> Rejection."""

    stage = "read"

    def __init__(self, output: str):
        super().__init__(output)
        self.read = Metrics.counter(NAMESPACE, "pulses_read")

    def run(self, task: ReadTask):
        pulses = read_pulses(task.point_range)
        self.read.inc(len(pulses) + sum(1 for pulse_id, _ in pulses.rejected if pulse_id >= 0))
        for pulse_id, reason in pulses.rejected:
            yield Rejection(task.source.name, task.source.stem, task.start, int(pulse_id), self.stage, reason)
        if len(pulses):  # else nothing left to decompose: the range ends here
            yield PulseRange(task, pulses)


# ---------------------------------------------------------------- decompose

class Decompose(_Stage):
    """PulseRange -> DecomposedRange: the batched numba engine, one call per range.

    setup() compiles the kernels once per worker (from numba's cache when warm).
    """

    stage = "decompose"

    def __init__(self, output: str, config: DecompositionConfig):
        super().__init__(output)
        self.config = config

    def setup(self):
        super().setup()
        from fwcore.records import WaveformBatch
        warm = WaveformBatch.from_waveforms([np.r_[np.zeros(8), 50.0, 100.0, 50.0, np.zeros(8)]], 1000.0, [0])
        decompose_batch(warm, self.config.replace(generations=1), threads=1)

    def run(self, item: PulseRange):
        config = self.config.replace(system_pulse_fwhm_ps=item.task.source.system_pulse_fwhm_ps,
                                     shape_tolerance=item.task.source.shape_tolerance)
        began = time.perf_counter()
        # one thread per worker: Beam's workers are the parallelism; results do not depend on it
        result = decompose_batch(pulse_waveforms(item.pulses, config.seed), config, threads=1)
        ok = result.status == 0
        for i in np.flatnonzero(~ok):
            yield Rejection(item.task.source.name, item.task.source.stem, item.task.start,
                            int(item.pulses.pulse_id[i]), self.stage, STATUS_REASONS[result.status[i]])
        LOG.info("%s points %d+: %d pulses decomposed, %d rejected, %.1f pulses/s", item.task.source.name,
                 item.task.start, ok.sum(), (~ok).sum(), len(item.pulses) / max(time.perf_counter() - began, 1e-9))
        yield DecomposedRange(item.task, item.pulses, config, result)


# ---------------------------------------------------------------- geolocate

def _waveform_views(pulses, result) -> dict[str, np.ndarray]:
    """What the MCAP sink needs per pulse, as compact arrays (JSON is made one message at a time when writing)."""
    owner = result.echo_waveform
    spacing = pulses.sample_spacing_ps
    return {"pulse_id": pulses.pulse_id, "gps_time": pulses.gps_time, "sample_spacing_ps": spacing,
            "sample_offsets": pulses.sample_offsets, "raw": pulses.samples.astype(np.float32),
            "model": model_samples(result, pulses.sample_offsets),
            "echo_offsets": result.echo_offsets, "echo_time_ps": result.position * spacing[owner],
            "echo_amplitude": result.amplitude, "echo_fwhm_ps": result.fwhm * spacing[owner],
            "echo_reject": result.reject}


class Geolocate(_Stage):
    """DecomposedRange -> GeolocatedRange: every echo placed along its beam, its range and radiometry computed,
    the range's tables built."""

    stage = "geolocate"

    def __init__(self, output: str, with_views: bool, radiometry: RadiometryConfig = RadiometryConfig()):
        super().__init__(output)
        self.with_views, self.radiometry = with_views, radiometry

    def run(self, item: DecomposedRange):
        pulses, result, source = item.pulses, item.result, item.task.source
        xyz = echo_positions(pulses, result, source.range_offset_ps)
        file = file_radiometry(source.path, source.adjusted_standard_gps_time, self.radiometry)
        radiometry = range_radiometry(pulses, result, xyz, source.range_offset_ps, file, self.radiometry)
        echoes, table = pulse_tables(source.name, pulses, result, item.config, xyz, result.status == 0, radiometry)
        cloud = decomposed_echoes(pulses, result, xyz)
        kept = result.reject == 0
        cloud.update({name: values[kept] for name, values in radiometry.items()})
        yield GeolocatedRange(item.task, echoes, table, cloud,
                              _waveform_views(pulses, result) if self.with_views else None)


# ---------------------------------------------------------------- write a range

class WriteRange(_Stage):
    """GeolocatedRange -> RangePart: the range's Parquet parts, and its LAS and MCAP parts under parts/."""

    stage = "write"

    def __init__(self, output: str, formats: frozenset[str], calibrated: bool = False):
        super().__init__(output)
        self.formats, self.calibrated = formats, calibrated
        # counted once written, so that a range rejected on the way is not also counted as decomposed
        self.decomposed = Metrics.counter(NAMESPACE, "pulses_decomposed")
        self.kept = Metrics.counter(NAMESPACE, "echoes_kept")
        self.spurious = Metrics.counter(NAMESPACE, "echoes_spurious")

    def _paths(self, task: ReadTask) -> dict[str, Path]:
        name, out = part_name(task.source.stem, task.start), Path(self.output)
        return {"echoes": out / "echoes" / f"{name}.parquet", "pulses": out / "pulses" / f"{name}.parquet",
                "las": out / PARTS / f"{name}.las", "mcap": out / PARTS / f"{name}.mcap"}

    def run(self, item: GeolocatedRange):
        task, paths = item.task, self._paths(item.task)
        try:
            if "parquet" in self.formats:
                write_part(item.echoes, paths["echoes"].parent, paths["echoes"].stem)
                write_part(item.pulses, paths["pulses"].parent, paths["pulses"].stem)
            if "las" in self.formats:
                write_point_cloud(paths["las"], task.source.path, item.cloud, self.calibrated)
            if "mcap" in self.formats:
                write_mcap(paths["mcap"], item.cloud, item.views, task.source.adjusted_standard_gps_time)
        except Exception:
            remove_parts(list(paths.values()))  # a range is written whole or not at all
            raise
        n_kept = int(np.count_nonzero(item.echoes.column("kept").to_numpy(zero_copy_only=False)))
        self.decomposed.inc(item.pulses.num_rows)
        self.kept.inc(n_kept)
        self.spurious.inc(item.echoes.num_rows - n_kept)
        yield RangePart(task.source.stem, task.source.path, task.start,
                        str(paths["las"]) if "las" in self.formats else "",
                        str(paths["mcap"]) if "mcap" in self.formats else "", task.source.adjusted_standard_gps_time)


# ---------------------------------------------------------------- a range, all stages

def write_rejections(output: str, task: ReadTask, rows: list[Rejection]) -> Path:
    """A range's Rejections -> rejected/<stem>-<range>.parquet (one file per range, so a bad file stays bounded)."""
    rows = sorted(rows, key=lambda r: (r.pulse_id, r.stage))
    return write_part(rejected_table(rows), Path(output) / "rejected", part_name(task.source.stem, task.start))


def write_file_rejection(output: str | Path, rejection: Rejection) -> Path:
    """A file that could not be planned -> rejected/<stem>.parquet."""
    return write_part(rejected_table([rejection]), Path(output) / "rejected", rejection.stem)


class RangeStages(beam.DoFn):
    """ReadTask -> RangePart: each range through the stages in turn, in one ParDo; its Rejections to rejected/,
    then its mark.

    Beam 2.77's Dask runner collects a ParDo's outputs in a receiver that is an argument of the
    partition's task, and a worker keeps the arguments of a finished task until every task after it,
    to the job's end, is released: as four ParDos, every range's pulses, fit and tables (8 MB a range)
    stayed in the workers for the whole run. Here they are released as soon as the range is written.
    """

    def __init__(self, output: str, *stages: _Stage):
        self.output, self.stages = output, stages

    def setup(self):
        for stage in self.stages:
            stage.setup()

    def process(self, task: ReadTask):
        items = [task]
        for stage in self.stages:
            items = [out for item in items for out in stage.process(item)]
        rejected = [e for e in items if isinstance(e, Rejection)]  # the one place where the dead letter leaves
        if rejected:
            write_rejections(self.output, task, rejected)
        mark_range_done(self.output, task, rejected)  # the one place where a range's end is recorded
        yield from (e for e in items if not isinstance(e, Rejection))

    def teardown(self):
        for stage in self.stages:
            stage.teardown()


# ---------------------------------------------------------------- per file

def assemble_file(item: tuple[str, list[RangePart]], output: str, laz: bool) -> str:
    """One input's RangeParts -> las/<stem>.las (or .laz) and mcap/<stem>.mcap, streamed from the parts in
    range order; the parts are removed once in the file."""
    stem, ranges = item
    ranges = sorted(ranges, key=lambda r: r.range_start)
    las = [Path(r.las) for r in ranges if r.las]
    mcap = [Path(r.mcap) for r in ranges if r.mcap]
    if las:
        assemble_las(las, Path(output) / "las" / f"{stem}{'.laz' if laz else '.las'}", laz)
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
        las = str(las) if "las" in formats and las.exists() else ""
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
    """Planned ranges -> each range read, decomposed, geolocated and written, with its mark."""

    config: DecompositionConfig
    output: str
    formats: frozenset[str]
    spread: bool = True  # Reshuffle the ranges over workers (the Dask runner spreads them by its partitions)
    radiometry: RadiometryConfig = RadiometryConfig()

    def expand(self, tasks):
        if self.spread:
            tasks = tasks | "Spread" >> beam.Reshuffle()
        return tasks | "RangeStages" >> beam.ParDo(RangeStages(
            self.output,
            ReadRange(self.output),
            Decompose(self.output, self.config),
            Geolocate(self.output, "mcap" in self.formats, self.radiometry),
            WriteRange(self.output, self.formats, self.radiometry.calibrated)))


@dataclasses.dataclass
class AssembleFiles(beam.PTransform):
    """Each input's RangeParts (written_parts) -> its point cloud and MCAP (assemble_file)."""

    output: str
    laz: bool = False

    def expand(self, files):
        return files | "Assemble" >> beam.Map(assemble_file, self.output, self.laz)
