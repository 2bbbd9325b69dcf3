"""Planning: an input file -> its ranges of a few thousand pulses each, and what the file does not record.

A file's plan is one pass over its packet keys (every pulse in exactly one
range) and the measurement of its system pulse. It is the dataflow's first
stage, run on the workers, one file per element (`transforms.PlanFile`): a
cluster plans many files at once and the driver only lists the inputs. Each
plan is written to parts/plans/<stem>.json, which the driver reads back: it
then knows the total for the progress bar and the ranges, which become the
first collection of the ranges' job (the Dask runner partitions a job's
first collection, one range per partition, and cannot spread ranges born
inside a partition). A resumed run reuses the plans it finds.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import NamedTuple

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.pulse import PulseOverrides
from fwcore.io import input_summary, open_input, plan_point_ranges
from fwcore.io.formats import input_crs
from fwcore.io.records import PointRange
from pipeline.faults import READING, machine_fault
from pipeline.layout import plan_path
from pipeline.outputs import InputNames
from pipeline.records import InputFile, ReadTask, Rejection

class InputToPlan(NamedTuple):
    """The driver -> plan: an input as listed, under its output names."""

    path: str
    name: str
    stem: str
    crs: str | None = None  # --crs as WKT (fwcore.io.crs.parse_crs), or None: the file's own
    overrides: PulseOverrides = PulseOverrides()  # what the user gave of the pulse instead of measuring it
    l2a_algorithms: str = "selected"  # --l2a-algorithms (GEDI): selected | all | 1..6


@dataclasses.dataclass(frozen=True)
class FilePlan:
    """plan -> the driver: a file's ranges, or the Rejection that says why it could not be planned."""

    source: InputFile | None
    ranges: tuple[PointRange, ...] = ()
    rejection: Rejection | None = None

    @property
    def tasks(self) -> list[ReadTask]:
        return [ReadTask(self.source, r) for r in self.ranges]

    def to_json(self) -> dict:
        return {"source": self.source.to_dict() if self.source else None,
                "ranges": [dataclasses.asdict(r) for r in self.ranges],
                "rejection": self.rejection._asdict() if self.rejection else None}

    @classmethod
    def from_json(cls, value: dict) -> "FilePlan":
        def point_range(r: dict) -> PointRange:
            return PointRange(**{k: tuple(v) if isinstance(v, list) else v for k, v in r.items()})
        return cls(InputFile.from_dict(value["source"]) if value["source"] else None,
                   tuple(point_range(r) for r in value["ranges"]),
                   Rejection(**value["rejection"]) if value["rejection"] else None)


def plan_file(path: str, name: str, stem: str, config: DecompositionConfig, points_per_range: int,
              limit: int | None, crs: str | None = None,
              overrides: PulseOverrides = PulseOverrides(), l2a_algorithms: str = "selected") -> list[ReadTask]:
    opened = open_input(path)  # the header, read once for the ranges and the summary
    ranges = plan_point_ranges(path, points_per_range, opened)
    summary = input_summary(path, opened)  # LAS or PulseWaves
    adjusted, count = summary.adjusted_standard_gps_time, summary.records
    pulse = file_system_pulse(path, count, config, overrides)  # the file does not record it: measured on it
    found = input_crs(path, crs)
    settings, settings_source = file_metric_settings(path, l2a_algorithms)
    source = InputFile(path, name, stem, pulse, adjusted, found.wkt, found.source, found.named, settings,
                       settings_source)
    tasks, remaining = [], limit
    for r in ranges:
        if remaining is not None:
            if remaining <= 0:
                break
            r = dataclasses.replace(r, max_pulses=min(remaining, r.n_pulses))
            remaining -= r.max_pulses
        tasks.append(ReadTask(source, r))
    return tasks


def file_metric_settings(path: str, l2a_algorithms: str = "selected") -> tuple[dict | None, str]:
    """A GEDI L1B's forest-metric settings ({"default": the algorithm of shots L2A selected none for, "algorithms":
    {number: settings}, "each_shot": whether each shot takes the one L2A selected for it, "every": whether every
    algorithm's ground and RH are written, "noise": whence the noise thresholds' mean and sd}): the L2A granule's
    beside it, else L2A's six algorithms as data (fwcore.metrics.algorithms); an LVIS L1B's: None, LVIS's own
    (fwcore.metrics.lvis), said in the source; None for other formats. `l2a_algorithms`: selected | all | 1..6
    (--l2a-algorithms)."""
    from fwcore.io.formats import GEDI_L1B, LVIS_L1B, format_of
    from fwcore.io.gedi import NOISE_ESTIMATED, l2a_algorithm_settings, l2a_beside, noise_recorded
    from fwcore.metrics.algorithms import L2A_ALGORITHMS
    from fwcore.metrics.lvis import LVIS_L2

    kind = format_of(path)
    if kind is LVIS_L1B:  # its reader asks for them (PulseBatch.metric_definition); said here for run.json
        return None, (f"LVIS Level 2's definitions (fwcore.metrics.lvis): {dataclasses.asdict(LVIS_L2)}, smoothed "
                      f"by the system pulse's sigma")
    if kind is not GEDI_L1B:
        return None, ""
    named = int(l2a_algorithms) if l2a_algorithms.isdigit() else None
    plan = {"each_shot": named is None, "every": l2a_algorithms == "all",
            "noise": "L1B noise_mean_corrected / noise_stddev_corrected" if noise_recorded(path) else NOISE_ESTIMATED}
    table = {str(a): s.to_dict() for a, s in L2A_ALGORITHMS.items()}
    l2a = l2a_beside(path)
    if l2a is None:
        return ({**plan, "default": named or 1, "algorithms": table},
                f"GEDI L2A algorithm {named or 1}'s ({'--l2a-algorithms' if named else 'no L2A granule beside the L1B'})")
    try:
        algorithm, settings = l2a_algorithm_settings(l2a)
    except (OSError, ValueError, KeyError) as err:
        return ({**plan, "default": named or 1, "algorithms": table},
                f"GEDI L2A algorithm {named or 1}'s ({l2a.name} unreadable: {err})")
    # the granule's settings over the table's: a granule that omits some keeps L2A's documented values
    plan.update(algorithms={**table, **{str(a): {**table.get(str(a), {}), **s} for a, s in settings.items()}})
    if named:
        return {**plan, "default": named}, f"{l2a.name}: algorithm {named} for every shot (--l2a-algorithms)"
    return ({**plan, "default": algorithm},
            f"{l2a.name}: each shot's selected algorithm (algorithm {algorithm} for most)")


def plan_input(item: InputToPlan, config: DecompositionConfig, points_per_range: int,
               limit: int | None = None) -> FilePlan:
    """One file's plan; a file that cannot be planned gives a Rejection naming the problem, never an exception
    but a fault of the machine (pipeline.faults: an I/O error, no memory), which is no fault of the file."""
    try:
        tasks = plan_file(item.path, item.name, item.stem, config, points_per_range, limit, item.crs, item.overrides,
                          item.l2a_algorithms)
    except Exception as err:  # noqa: BLE001  a damaged file is rejected, the others run
        fault = machine_fault(err, READING, item.path, f"planning {item.name}")
        if fault is not None:
            raise fault from err
        reason = str(err) if isinstance(err, (OSError, ValueError)) else f"{type(err).__name__}: {err}"
        return FilePlan(None, (), Rejection(item.name, item.stem, -1, -1, "open", reason))
    return FilePlan(tasks[0].source if tasks else None, tuple(t.point_range for t in tasks))


def inputs_to_plan(paths: list[str], names: InputNames, crs: str | None = None,
                   overrides: PulseOverrides = PulseOverrides(), l2a_algorithms: str = "selected") -> list[InputToPlan]:
    return [InputToPlan(p, names.name(p), names.stem(names.name(p)), crs, overrides, l2a_algorithms) for p in paths]


def plan_inputs(paths: list[str], names: InputNames, config: DecompositionConfig, points_per_range: int,
                limit: int | None = None) -> tuple[list[ReadTask], list[Rejection]]:
    """Every file planned here, one after another (the workers' stage does the same per file): the ranges of
    every file, and a Rejection naming the problem for each file that cannot be planned."""
    plans = [plan_input(i, config, points_per_range, limit) for i in inputs_to_plan(paths, names)]
    return [t for p in plans for t in p.tasks], [p.rejection for p in plans if p.rejection]


def read_plans(output: str | Path, inputs: list[InputToPlan]) -> dict[str, FilePlan]:
    """The plans the workers wrote, by input path; an input without one is a Rejection (its planning was lost)."""
    plans = {}
    for item in inputs:
        try:
            plans[item.path] = FilePlan.from_json(json.loads(plan_path(output, item.stem).read_text()))
        except (OSError, ValueError, KeyError, TypeError) as err:
            plans[item.path] = FilePlan(None, (), Rejection(item.name, item.stem, -1, -1, "open",
                                                            f"its plan was not written ({err})"))
    return plans


def planned_pulses(task: ReadTask) -> int:
    r = task.point_range
    return r.max_pulses if r.max_pulses is not None else r.n_pulses
