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
from fwcore.metrics.l4a_algorithm import A10_STAND_IN, EBT_REGIONS, l4a_algorithm, rx_maxamp, stratum_parts
from fwcore.metrics.pulses import batch_metrics, metric_columns, rows_metrics
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

    def l4a_rh(self, pulses: PulseBatch, result: BatchDecomposition, pulse: SystemPulse, strata: np.ndarray,
               metrics: WaveformMetrics, chosen: np.ndarray, every: dict[int, WaveformMetrics] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Per shot the RH (n, 101) GEDI L4A predicts its biomass from and that algorithm (int8, 0 where no
        prediction stratum: `metrics`' RH kept), chosen by L4A's rule (fwcore.metrics.l4a_algorithm) from the
        grounds of algorithms 1 and 2 (and, for EBT_Af / EBT_SA, algorithm 5's standing in for L4A's 10).
        An algorithm's metrics are measured only for the shots with a stratum whose own (`chosen`) is another."""
        strata = np.asarray(strata, dtype=object)
        rows = np.flatnonzero(strata != "")
        pft, region = stratum_parts(strata[rows])
        ebt = rows[(pft == "EBT") & np.isin(region, EBT_REGIONS)]
        found = {a: self._algorithm_metrics(a, wanted, pulses, result, pulse, metrics, chosen, every)
                 for a, wanted in ((1, rows), (2, rows), (A10_STAND_IN, ebt))}
        ground_a10 = np.full(len(chosen), np.nan)
        ground_a10[ebt] = found[A10_STAND_IN][0][ebt]
        noise_mean = metric_columns(pulses, result, pulse)[0]
        peak = rx_maxamp(pulses.samples, pulses.sample_offsets, noise_mean)
        rule = l4a_algorithm(strata[rows], peak[rows], found[1][0][rows], found[2][0][rows], ground_a10[rows])
        rule[rule == 10] = A10_STAND_IN  # L4A's algorithm 10 is not L2A's: algorithm 5 measured in its place
        algorithm = np.zeros(len(chosen), np.int8)
        algorithm[rows] = rule
        rh = metrics.rh.copy()
        for a, (_, a_rh) in found.items():
            at = rows[rule == a]
            rh[at] = a_rh[at]
        return rh, algorithm

    def _algorithm_metrics(self, a: int, rows: np.ndarray, pulses: PulseBatch, result: BatchDecomposition,
                           pulse: SystemPulse, metrics: WaveformMetrics, chosen: np.ndarray,
                           every: dict[int, WaveformMetrics] | None) -> tuple[np.ndarray, np.ndarray]:
        """Algorithm a's ground and RH at `rows` (NaN elsewhere): from `every` where measured, else the shots'
        own metrics where they are a's, else measured now for the rest."""
        n = len(chosen)
        if every and a in every:
            return every[a].ground_z, every[a].rh
        ground, rh = np.full(n, np.nan), np.full((n, metrics.rh.shape[1]), np.nan)
        own = rows[chosen[rows] == a]
        ground[own], rh[own] = metrics.ground_z[own], metrics.rh[own]
        other = rows[chosen[rows] != a]
        if other.size:
            settings = self.algorithms[a] if a in self.algorithms else l2a_algorithm(a)
            measured = rows_metrics(pulses, result, pulse, settings, other)
            ground[other], rh[other] = measured.ground_z, measured.rh
        return ground, rh
