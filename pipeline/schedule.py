"""The order in which a run's workers claim its ranges: the costliest first (longest processing time first), so
that no worker is left with a long range after the others have finished.

    range_cost(task, config)        the engine's model evaluations on a sample of the range's shots, times the
                                    samples a waveform, scaled to the range's pulses
    longest_first(tasks, config)    the ranges, costliest first (ties in file order); None where no estimate applies

A large-footprint file's ranges differ in cost by beam and by forest (GEDI's bundled savanna beams, repeated:
the fourth beam's ranges took 2.4x the first's), and Beam's DirectRunner deals a job's elements to its threads
in equal numbers before any runs: the worker dealt the costly ranges ran alone for a range's time at the end
(docs/benchmarks.md, issue 58's eleventh pass). Only the order changes: every range's outputs are its own.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.io import read_pulses
from fwcore.io.formats import GEDI_L1B, LVIS_L1B, format_of
from fwcore.pulses import pulse_waveforms
from pipeline.plan import planned_pulses
from pipeline.records import ReadTask

SAMPLE_SHOTS = 16  # a range's shots decomposed for its estimate: ~20 ms of a savanna range's 6-15 s
# beyond this many ranges a worker, its last range is a small part of its work, and the estimates (a fixed cost a
# range, in the driver before any range) would cost more than the order saves
MAX_RANGES_A_WORKER = 16


def estimated(task: ReadTask) -> bool:
    """Whether a range's cost can be estimated from a slice of its records: one record is one shot (GEDI, LVIS
    L1B), so any slice reads whole pulses."""
    return format_of(task.source.path) in (GEDI_L1B, LVIS_L1B)


def range_cost(task: ReadTask, config: DecompositionConfig, sample: int = SAMPLE_SHOTS) -> float:
    """A range's cost in sample evaluations: the engine's model evaluations of `sample` shots from its middle,
    each times its samples, scaled to the range's pulses (0 when none of them can be read)."""
    r = task.point_range
    start = max(r.start, (r.start + r.stop - sample) // 2)
    pulses = read_pulses(dataclasses.replace(r, start=start, stop=min(r.stop, start + sample), n_pulses=-1,
                                             max_pulses=None))
    if not len(pulses):
        return 0.0
    result = decompose_batch(pulse_waveforms(pulses, config.seed), config, task.source.pulse, threads=1)
    samples = np.diff(pulses.sample_offsets)
    return float(np.sum(result.nfev * samples)) * planned_pulses(task) / len(pulses)


def longest_first(tasks: list[ReadTask], config: DecompositionConfig, workers: int,
                  sample: int = SAMPLE_SHOTS) -> list[ReadTask] | None:
    """The ranges costliest first (a stable sort: equal costs in their file order), for workers that each claim
    the next as they finish; None where the order cannot help (no more ranges than workers, or so many that a
    worker's last range is a small part of its work: MAX_RANGES_A_WORKER) or a range's cost cannot be estimated
    (estimated; a sample that cannot be read: its range's own reading rejects what it must)."""
    if not workers < len(tasks) <= MAX_RANGES_A_WORKER * workers:
        return None
    try:
        if not all(estimated(t) for t in tasks):
            return None
        costs = [range_cost(t, config, sample) for t in tasks]
    except Exception:  # noqa: BLE001  only an order is lost: the ranges run as dealt, and fail there if they must
        return None
    order = sorted(range(len(tasks)), key=lambda i: -costs[i])
    return [tasks[i] for i in order]
