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

from fwcore.metrics.waveform import GEDI_ALGORITHM_1, MetricSettings

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
