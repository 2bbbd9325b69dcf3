"""Planning on the driver: input patterns -> files -> ranges of a few thousand pulses each.

The driver plans before the pipeline starts, so that the progress bar knows
the total and every runner receives the ranges as its first collection (the
Dask runner partitions that collection, one range per partition).
"""

from __future__ import annotations

import dataclasses

from fwcore.config import DecompositionConfig
from fwcore.io import input_summary, plan_point_ranges
from fwcore.survey import file_system_pulse
from pipeline.outputs import InputNames
from pipeline.records import InputFile, ReadTask, Rejection


def plan_file(path: str, name: str, stem: str, config: DecompositionConfig, points_per_range: int,
              limit: int | None) -> list[ReadTask]:
    ranges = plan_point_ranges(path, points_per_range)
    summary = input_summary(path)  # LAS or PulseWaves
    adjusted, count = summary.adjusted_standard_gps_time, summary.records
    pulse = file_system_pulse(path, count, config)  # the file does not record it: measured on its waveforms
    source = InputFile(path, name, stem, pulse.fwhm_ps, adjusted, pulse.shape_tolerance, pulse.fwhm_source,
                       pulse.shape_source, pulse.range_offset_ps, pulse.range_offset_source)
    tasks, remaining = [], limit
    for r in ranges:
        if remaining is not None:
            if remaining <= 0:
                break
            r = dataclasses.replace(r, max_pulses=min(remaining, r.n_pulses))
            remaining -= r.max_pulses
        tasks.append(ReadTask(source, r))
    return tasks


def plan_inputs(paths: list[str], names: InputNames, config: DecompositionConfig, points_per_range: int,
                limit: int | None = None) -> tuple[list[ReadTask], list[Rejection]]:
    """The ranges of every file, and a Rejection naming the problem for each file that cannot be planned."""
    tasks, rejected = [], []
    for path in paths:
        name = names.name(path)
        stem = names.stem(name)
        try:
            tasks.extend(plan_file(path, name, stem, config, points_per_range, limit))
        except Exception as err:  # noqa: BLE001  a damaged file is rejected, the others run
            reason = str(err) if isinstance(err, (OSError, ValueError)) else f"{type(err).__name__}: {err}"
            rejected.append(Rejection(name, stem, -1, -1, "open", reason))
    return tasks, rejected


def planned_pulses(task: ReadTask) -> int:
    r = task.point_range
    return r.max_pulses if r.max_pulses is not None else r.n_pulses
