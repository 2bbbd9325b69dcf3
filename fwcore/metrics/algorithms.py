"""GEDI L2A's six waveform-processing algorithms as data: each one's rx_processing_aN/ancillary settings (the
same in every granule read so far: v001 and v002), for shots whose L2A granule does not lie beside the L1B.

    algorithm  smoothing (locs / zcross)  thresholds (front / back, noise sd)  mode selection
    1          6.5 / 6.5                  3 / 6                                 off: the lowest mode
    2          6.5 / 3.5                  3 / 3                                 on: weak modes near the end passed over
    3          6.5 / 3.5                  3 / 6                                 off
    4          6.5 / 6.5                  6 / 6                                 off
    5          6.5 / 3.5                  3 / 2                                 off
    6          6.5 / 3.5                  3 / 4                                 off

An L2A granule beside the L1B gives its own (fwcore.io.gedi.l2a_settings), which win.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fwcore.engine.records import BatchDecomposition
from fwcore.instrument.pulse import SystemPulse
from fwcore.io.records import PulseBatch
from fwcore.metrics.pulses import batch_metrics
from fwcore.metrics.waveform import GEDI_ALGORITHM_1, MetricSettings, WaveformMetrics

_ZCROSS_3_5 = dataclasses.replace(GEDI_ALGORITHM_1, smoothing_width_zcross=3.5)
L2A_ALGORITHMS: dict[int, MetricSettings] = {
    1: GEDI_ALGORITHM_1,
    2: dataclasses.replace(_ZCROSS_3_5, back_threshold_sd=3.0, select_mode=True, cumulative_energy_minimum=1.5,
                           cumulative_energy_thresh=2.5),
    3: _ZCROSS_3_5,
    4: dataclasses.replace(GEDI_ALGORITHM_1, front_threshold_sd=6.0),
    5: dataclasses.replace(_ZCROSS_3_5, back_threshold_sd=2.0),
    6: dataclasses.replace(_ZCROSS_3_5, back_threshold_sd=4.0),
}


def l2a_algorithm(number: int) -> MetricSettings:
    """The settings of L2A's algorithm `number` (1..6); a clear error for any other."""
    if number not in L2A_ALGORITHMS:
        raise ValueError(f"GEDI L2A has algorithms {min(L2A_ALGORITHMS)}..{max(L2A_ALGORITHMS)}, not {number}")
    return L2A_ALGORITHMS[number]


@dataclasses.dataclass(frozen=True)
class AlgorithmPlan:
    """Which algorithm's settings each GEDI shot's metrics take (a file's plan: pipeline.plan.file_metric_settings):
    `default` for shots L2A selected none for (or every shot, without `each_shot`), and whether every algorithm's
    ground and RH are measured too (`every`)."""

    default: int
    algorithms: dict[int, MetricSettings]
    each_shot: bool = True
    every: bool = False

    @classmethod
    def from_dict(cls, planned: dict) -> "AlgorithmPlan":
        return cls(int(planned["default"]), {int(a): MetricSettings.from_dict(s)
                                             for a, s in planned["algorithms"].items()},
                   bool(planned.get("each_shot", True)), bool(planned.get("every", False)))

    @property
    def settings(self) -> MetricSettings:
        return self.algorithms[self.default] if self.default in self.algorithms else l2a_algorithm(self.default)

    def shot_algorithms(self, metric_algorithm: np.ndarray | None, n: int) -> np.ndarray:
        """Per shot the algorithm whose ground and RH are its ground_z and rh (int8)."""
        chosen = np.full(n, self.default, np.int8)
        if self.each_shot and metric_algorithm is not None:
            known = np.isin(metric_algorithm, list(self.algorithms))
            chosen[known] = metric_algorithm[known]
        return chosen

    def metrics(self, pulses: PulseBatch, result: BatchDecomposition, pulse: SystemPulse
                ) -> tuple[WaveformMetrics, np.ndarray, dict[int, WaveformMetrics] | None]:
        """The shots' metrics by their algorithms, those algorithms, and every algorithm's where asked (`every`)."""
        metrics = batch_metrics(pulses, result, pulse, self.settings, self.algorithms if self.each_shot else None)
        chosen = self.shot_algorithms(pulses.metric_algorithm, len(pulses))
        every = ({a: batch_metrics(pulses, result, pulse, s) for a, s in sorted(self.algorithms.items())}
                 if self.every else None)
        return metrics, chosen, every
