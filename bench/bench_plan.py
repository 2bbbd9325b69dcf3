"""Where a file's plan spends its seconds: each step of `pipeline.plan.plan_file` timed in a fresh process.

    python bench/bench_plan.py FILE [FILE ...]

In the order a plan meets them: the imports (the engine's modules, numba), the header and the ranges, the head
of the file read (fwcore.instrument.measure.HEAD_PULSES records), numba's first kernel load (its target set
up: paid once per process, by whichever kernel comes first), the response on the single returns, the width
the generalized Gaussian takes, and per echo model the shape tolerance and the range offset (the system
model's echo table made on its first use), then `--model auto`'s choice; last the whole measurement again in
the same process, its kernels and echo tables loaded. Wall seconds (time.perf_counter).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class Clock:
    def __init__(self) -> None:
        self.last = time.perf_counter()

    def lap(self, what: str) -> None:
        now = time.perf_counter()
        print(f"  {what:44s} {now - self.last:7.3f} s", flush=True)
        self.last = now


def main() -> None:
    clock = Clock()
    import numpy as np

    from fwcore.engine.config import DecompositionConfig, Model
    from fwcore.engine.smoothing import noise_and_background
    import fwcore.instrument.measure as measure
    from fwcore.instrument.pulse import PulseOverrides, SystemPulse
    from fwcore.io import PointRange, input_summary, open_input, plan_point_ranges, read_pulses
    clock.lap("imports (engine, numba, readers)")
    config = DecompositionConfig()
    for path in sys.argv[1:]:
        print(Path(path).name)
        opened = open_input(path)
        plan_point_ranges(path, 5000, opened)
        records = input_summary(path, opened).records
        clock.lap("header, ranges, summary")
        pulses = read_pulses(PointRange(str(path), 0, min(records, measure.HEAD_PULSES)))
        single = measure._single_returns(pulses)
        clock.lap(f"head read ({len(pulses)} pulses, {single.size} single returns)")
        noise_and_background(np.r_[np.zeros(20), 5.0, np.zeros(20)])
        clock.lap("numba's first kernel load in the process")
        response = measure.file_response(pulses)
        clock.lap("response on the single returns")
        width = measure._file_width(pulses, Path(path).name)
        clock.lap("width for the generalized Gaussian")
        batch = measure._rows_batch(pulses, single, config.seed)
        for model, pulse in ((Model.SYSTEM, SystemPulse(response.fwhm_ps, "", 0.0, "", response=response)),
                             (Model.GENERALIZED, SystemPulse(width[0], "", 0.0, ""))):
            chosen = config.replace(model=model)
            tolerance = measure.measure_shape_tolerance(batch, chosen, pulse)
            clock.lap(f"shape tolerance, {model.value}")
            measure._with_range_offset(pulses, chosen, dataclasses.replace(pulse, shape_tolerance=tolerance))
            clock.lap(f"range offset, {model.value}")
        candidates = {m: measure._pulses_system_pulse(pulses, "", config.replace(model=m), PulseOverrides(),
                                                      range_offset=False) for m in measure.AUTO_MODELS}
        clock.last = time.perf_counter()
        measure.choose_system_pulse(candidates, measure._head_records(pulses, measure.MODEL_PULSES, config.seed),
                                    config)
        clock.lap("--model auto's choice")
        measure.file_system_pulse(path, records, config)
        clock.lap("the whole measurement again, all loaded")


if __name__ == "__main__":
    main()
