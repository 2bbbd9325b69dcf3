"""Which L2A algorithm's RH GEDI L4A predicts a shot's biomass from: L4A's own choice, which is not always L2A's
selected_algorithm (John Armston's gedipy, `predict_algorithm_setting_selection`):

    algorithm 1
    algorithm 2   where the shot is a tree (ENT, EBT, DNT, DBT), its waveform's peak above the noise (L2A's
                  rx_assess/rx_maxamp) is under 400 and algorithm 2's ground lies below algorithm 1's
    algorithm 10  where it is EBT in Africa or South America (Af, SA) and algorithm 10's ground lies more than 2 m
                  below algorithm 1's
    algorithm 5   where that holds and algorithm 10's mode selection flag is 4

The plant functional type and the region are decided by NAME (the prediction stratum, e.g. EBT_SA), not by code:
gedipy's region codes (4, 5) are an older numbering; L4A version 2's region_lut has Af = 4 and SA = 6.
This reproduces L4A's selected_algorithm for all 966 shots of the shared L4A granule
(tests/fwcore/metrics/test_l4a_algorithm.py).

Algorithm 10 is a setting group of L4A only (L2A has algorithms 1..6): without it, its ground and RH are
algorithm 5's (A10_STAND_IN), the L2A algorithm whose agbd lies nearest L4A's where L4A chose algorithm 10
(docs/gedi.md: 21 % median relative off on the shared granule's 480 such shots).
"""

from __future__ import annotations

import numpy as np

TREES = ("ENT", "EBT", "DNT", "DBT")  # the plant functional types algorithm 2 may serve
EBT_REGIONS = ("Af", "SA")  # the tropical evergreen broadleaf strata where algorithm 10 (or 5) may serve
MAXAMP_LIMIT = 400.0  # algorithm 2 only for waveforms whose peak lies under this above the noise (digital numbers)
A10_BELOW_A1_M = 2.0  # algorithm 10 only where its ground lies more than this below algorithm 1's
A10_MODE_FLAG_A5 = 4  # algorithm 10's selected_mode_flag that sends the shot to algorithm 5
A10_STAND_IN = 5  # the L2A algorithm whose settings stand in for L4A's algorithm 10


def stratum_parts(strata: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each prediction stratum's plant functional type and region (e.g. EBT_SA -> EBT, SA); '' for ''."""
    parts = [str(s).split("_", 1) if s else ["", ""] for s in np.asarray(strata, dtype=object).tolist()]
    return (np.array([p[0] for p in parts], dtype=object),
            np.array([p[1] if len(p) > 1 else "" for p in parts], dtype=object))


def l4a_algorithm(strata: np.ndarray, rx_maxamp: np.ndarray, ground_a1: np.ndarray, ground_a2: np.ndarray,
                  ground_a10: np.ndarray | None = None, mode_flag_a10: np.ndarray | None = None) -> np.ndarray:
    """Per shot the algorithm L4A takes its RH from (int8: 1, 2, 5 or 10), from its prediction stratum
    (PFT_region names, '' where none), its waveform's peak above the noise and the algorithms' grounds (m; NaN
    compares false: algorithm 1). Without `ground_a10`, EBT_Af / EBT_SA shots never leave algorithms 1 and 2;
    without `mode_flag_a10`, algorithm 10 stays 10."""
    pft, region = stratum_parts(strata)
    algorithm = np.ones(len(pft), np.int8)
    with np.errstate(invalid="ignore"):
        two = np.isin(pft, TREES) & (np.asarray(rx_maxamp, float) < MAXAMP_LIMIT) & (ground_a2 < ground_a1)
        algorithm[two] = 2
        if ground_a10 is not None:
            ebt = (pft == "EBT") & np.isin(region, EBT_REGIONS)
            ten = ebt & (np.asarray(ground_a10, float) < np.asarray(ground_a1, float) - A10_BELOW_A1_M)
            algorithm[ten] = 10
            if mode_flag_a10 is not None:
                algorithm[ten & (np.asarray(mode_flag_a10) == A10_MODE_FLAG_A5)] = 5
    return algorithm


def rx_maxamp(samples: np.ndarray, offsets: np.ndarray, noise_mean: np.ndarray) -> np.ndarray:
    """Each waveform's peak above its noise mean (L2A's rx_assess/rx_maxamp: max(rxwaveform) -
    noise_mean_corrected); NaN for an empty waveform."""
    lengths = np.diff(offsets)
    peak = np.full(lengths.size, np.nan)
    full = lengths > 0
    peak[full] = np.maximum.reduceat(np.asarray(samples, float)[:offsets[-1]], offsets[:-1][full])
    return peak - np.asarray(noise_mean, float)
