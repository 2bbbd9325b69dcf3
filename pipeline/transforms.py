"""The Beam transforms: a thin layer over plain functions (pipeline.stages, pipeline.plan). A run is three jobs:

    plan:   inputs -> Spread -> PlanFile -> parts/plans/<stem>.json          (pipeline.plan)
    ranges: ReadTasks -> Spread -> RangeStages: stages.run_range (read -> decompose -> geolocate -> write)
            -> the range's parts, its rejected/<stem>-<range>.parquet, and its mark parts/<stem>-<range>.json,
            written last
    files:  assemble.written_parts -> AssembleFiles: assemble.assemble_file -> las/<stem>.las, copc/<stem>.copc.laz,
            mcap/<stem>.mcap

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

The output folder's names are pipeline.layout's; the plain functions these
transforms call for a range's mark, its rejections and a file's assembly are
pipeline.marks, pipeline.rejections and pipeline.assemble.
"""

from __future__ import annotations

import dataclasses
import logging
import pickle
import time

import apache_beam as beam
from apache_beam.metrics import Metrics

from fwcore.engine.config import DecompositionConfig
from fwcore.radiometry.equations import RadiometryConfig
from pipeline.allocator import kept_memory
from pipeline.forest_settings import ForestSettings
from pipeline.faults import WRITING, MachineFault, note_fault, raised_as_fault
from pipeline.handoff import claimed_ranges
from pipeline.assemble import assemble_file
from pipeline.layout import echo_tables_path, part_name, plan_path
from pipeline.logs import log_to_file
from pipeline.marks import MARK_COUNTS, mark_range_done
from pipeline.plan import InputToPlan, plan_input, planned_pulses
from pipeline.records import ReadTask
from pipeline.rejections import write_file_rejection, write_rejections
from pipeline.sinks import write_json
from pipeline.stages import RangeSettings, run_range, warm_up
from pipeline.timing import Laps, log_timing
from pipeline.worker_exit import leave_quickly_at_exit

LOG = logging.getLogger("fwl")
NAMESPACE = "fwl"


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
        self.stopped: MachineFault | None = None  # a fault of this worker's output: its later ranges not tried
        self.handed: set[str] = set()  # the files whose plan's echo tables this worker took

    def setup(self):
        log_to_file(self.settings.output)
        leave_quickly_at_exit()  # the job's end need not wait for this worker's teardown
        laps = Laps()
        with laps("warm up"):
            warm_up(self.settings.config)
        log_timing("setup", "ranges", laps)

    def process(self, task: ReadTask):
        if self.stopped is not None:  # this worker's output takes nothing: the range is not tried, nor marked
            return
        if task.source.stem not in self.handed:
            self.handed.add(task.source.stem)
            _take_echo_tables(self.settings.output, task.source.stem, task.source.pulse)
        try:
            with kept_memory():  # a Dask worker's eager trimming faulted in every array's pages anew
                outcome = run_range(task, self.settings)  # a fault there is said in the worker's log by run_range
        except MachineFault as fault:
            self._stop(task, fault)
            return
        try:
            with raised_as_fault(WRITING, self.settings.output, task.label):
                if outcome.rejected:  # the one place where the dead letter leaves
                    write_rejections(self.settings.output, task, outcome.rejected)
                # the one place where a range's end is recorded
                mark_range_done(self.settings.output, task, planned_pulses(task), outcome.pulses_rejected,
                                {k: getattr(outcome, k) for k in MARK_COUNTS})
        except MachineFault as fault:
            LOG.error("%s: stopped: %s", task.label, fault.said())
            self._stop(task, fault)
            return
        for name, counter in self.counters.items():
            counter.inc(getattr(outcome, name))
        if outcome.part is not None:
            yield outcome.part

    def _stop(self, task: ReadTask, fault: MachineFault) -> None:
        """The range ends without its mark (a resumed run redoes it), its fault noted for the driver."""
        note_fault(self.settings.output, part_name(task.source.stem, task.start), fault)
        if fault.doing == WRITING:  # a full or read-only output fails every range: stop trying them
            self.stopped = fault

    def teardown(self):
        for handler in logging.getLogger("fwl").handlers:  # the worker's log file, complete
            handler.flush()


def _write_echo_tables(output: str, stem: str, pulse) -> None:
    """The echo tables the plan made of a file's response, for the workers (fwcore.instrument.shape)."""
    from fwcore.instrument.shape import echo_shapes_of

    tables = echo_shapes_of(pulse.echo_response())
    if tables:
        path = echo_tables_path(output, stem)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")  # a worker never reads half a file (a full disk stops here)
        with open(tmp, "wb") as f:
            pickle.dump(tables, f, protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)


def _take_echo_tables(output: str, stem: str, pulse) -> None:
    """The plan's echo tables of a file, handed to this process's echo_shape; where there are none (a resumed run's
    older plan), the worker makes them as before."""
    from fwcore.instrument.shape import hand_over_echo_shapes

    path = echo_tables_path(output, stem)
    if pulse.response is None or not path.is_file():
        return
    with open(path, "rb") as f:
        hand_over_echo_shapes(pulse.echo_response(), pickle.load(f))


# ---------------------------------------------------------------- the three jobs

class PlanFile(beam.DoFn):
    """InputToPlan -> its stem: the file's plan (pipeline.plan) to parts/plans/<stem>.json; a file that cannot
    be planned also to rejected/<stem>.parquet."""

    def __init__(self, output: str, config: DecompositionConfig, points_per_range: int, limit: int | None):
        self.output, self.config, self.points_per_range, self.limit = output, config, points_per_range, limit

    def setup(self):
        log_to_file(self.output)

    def process(self, item: InputToPlan):
        stem = plan_into_parts(item, self.output, self.config, self.points_per_range, self.limit)
        if stem is not None:
            yield stem


def plan_into_parts(item: InputToPlan, output: str, config: DecompositionConfig, points_per_range: int,
                    limit: int | None) -> str | None:
    """An input's plan (pipeline.plan) to parts/plans/<stem>.json, its echo tables beside it; a file that cannot
    be planned also to rejected/<stem>.parquet. Its stem, or None where a fault of the machine was noted."""
    began = time.perf_counter()
    try:
        laps = Laps()
        with laps("plan"), kept_memory():
            plan = plan_input(item, config, points_per_range, limit)
        log_timing("plan", item.name, laps)
        with raised_as_fault(WRITING, plan_path(output, item.stem), f"planning {item.name}"):
            if plan.rejection:
                write_file_rejection(output, plan.rejection)
            if plan.source is not None and plan.source.pulse.response is not None:  # before the plan: its
                _write_echo_tables(output, item.stem, plan.source.pulse)  # readers find them whole
            write_json(plan_path(output, item.stem), plan.to_json())
    except MachineFault as fault:  # no plan, and no rejection: the driver reads the note and stops
        LOG.error("%s: stopped: %s", item.name, fault.said())
        note_fault(output, item.stem, fault)
        return None
    LOG.info("%s planned: %d ranges in %.2f s", item.name, len(plan.ranges), time.perf_counter() - began)
    return item.stem


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


class AwaitRanges(beam.DoFn):
    """A worker's number -> the ranges the driver hands over once it has planned them, each taken by the first
    worker to claim it (pipeline.handoff.claimed_ranges), one at a time as the ranges' DoFn fused after this one
    finishes the last: the ranges' job, started before the plans, has its workers up and their kernels loaded
    (warmed up on one element each, where the runner spreads them) by then."""

    def __init__(self, output: str, config: DecompositionConfig):
        self.output, self.config = output, config

    def setup(self):
        log_to_file(self.output)
        leave_quickly_at_exit()
        laps = Laps()
        with laps("warm up"):
            warm_up(self.config)  # while the driver plans: the ranges' DoFn then finds the kernels loaded
        log_timing("setup", "awaiting ranges", laps)

    def process(self, worker: int):
        yield from claimed_ranges(self.output)


@dataclasses.dataclass
class DecomposeFlight(beam.PTransform):
    """Planned ranges -> each range read, decomposed, geolocated and written (stages.run_range), with its mark."""

    config: DecompositionConfig
    output: str
    formats: frozenset[str]
    spread: bool = True  # Reshuffle the ranges over workers (the Dask runner spreads them by its partitions)
    radiometry: RadiometryConfig = RadiometryConfig()
    forest: ForestSettings = ForestSettings()  # --stratum, --pulse-metrics (pipeline.stages.geolocate_range)

    def expand(self, tasks):
        if self.spread:
            tasks = tasks | "Spread" >> beam.Reshuffle()
        settings = RangeSettings(self.output, self.config, self.formats, self.radiometry, self.forest)
        return tasks | "RangeStages" >> beam.ParDo(RangeStages(settings))


@dataclasses.dataclass
class AssembleFiles(beam.PTransform):
    """Each input's RangeParts (written_parts) -> its point cloud and MCAP (assemble_file)."""

    output: str
    laz: bool = False
    formats: frozenset[str] = frozenset(("las", "mcap"))

    def expand(self, files):
        return files | "Assemble" >> beam.Map(assemble_file_or_fault, self.output, self.laz, self.formats)


def assemble_file_or_fault(item: tuple, output: str, laz: bool, formats: frozenset[str]) -> str:
    """assemble.assemble_file; a fault of the machine noted for the driver (the parts stay for a resumed run)."""
    try:
        laps = Laps()
        with raised_as_fault(WRITING, output, f"assembling {item[0]}"), laps("assemble"), kept_memory():
            stem = assemble_file(item, output, laz, formats)
        log_timing("assemble", item[0], laps, ranges=len(item[1]))
        return stem
    except MachineFault as fault:
        LOG.error("%s: stopped: %s", item[0], fault.said())
        note_fault(output, item[0], fault)
        return item[0]
