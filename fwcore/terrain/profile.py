"""What a cell's waveform energy says of the canopy, binned by height above the terrain: relative heights (the
height under which k % of the energy lies, GEDI L2A's definition) and the plant area volume density (L2B's, from
the gap probability above each height: fwcore.metrics.canopy).

Bins are `bin_height` metres from `bottom` (below the ground, so that the ground's own energy is in the
profile); within a bin the energy is taken as even, so heights are interpolated, not stepped.
"""

from __future__ import annotations

import numpy as np

from fwcore.metrics.canopy import RHOV_RHOG, ROSSG, OMEGA, gap_probability, plant_area_index


def relative_heights(sums: np.ndarray, bottom: float, bin_height: float, percent: float) -> np.ndarray:
    """Per row of `sums` (cells, bins: energy per bin from `bottom` up), the height under which `percent` % of
    its energy lies; NaN where a row has no energy."""
    sums = np.asarray(sums, float)
    total = sums.sum(axis=1)
    cumulative = np.cumsum(sums, axis=1)
    target = total * percent / 100.0
    k = np.minimum((cumulative < target[:, None]).sum(axis=1), sums.shape[1] - 1)  # the bin where it is reached
    rows = np.arange(sums.shape[0])
    below = np.where(k > 0, cumulative[rows, np.maximum(k - 1, 0)], 0.0)
    inside = sums[rows, k]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(inside > 0, (target - below) / inside, 0.0)
    return np.where(total > 0, bottom + (k + np.clip(frac, 0.0, 1.0)) * bin_height, np.nan)


ROUNDING = 1e-12  # a gap probability below this is the rounding of 1 - (canopy energy) / (all of it)


def plant_area_density(canopy: np.ndarray, rv: np.ndarray, rg: np.ndarray, bin_height: float,
                       cos_zenith: float | np.ndarray = 1.0, rhov_rhog: float = RHOV_RHOG, rossg: float = ROSSG,
                       omega: float = OMEGA) -> np.ndarray:
    """PAVD (m2/m3) per bin, (cells, bins) from the ground up: the PAI above each bin's lower edge less the PAI
    above its upper edge, over the bin's height; the gap probability above a height is 1 - (the canopy energy
    above it) / (rv + rhov/rhog rg). NaN where a cell has no energy; infinite in a bin below which no
    ground was seen (saturated: the map leaves it out)."""
    canopy = np.asarray(canopy, float)
    rv, rg = np.asarray(rv, float), np.asarray(rg, float)
    above_lower = np.cumsum(canopy[:, ::-1], axis=1)[:, ::-1]  # canopy energy above each bin's lower edge
    above_upper = above_lower - canopy
    denominator = (rv + rhov_rhog * rg)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        # a gap of the sums' rounding (1e-14 where no ground was seen) is none: its PAI is infinite, not 64
        pgap_lower = np.clip(1.0 - above_lower / denominator, 0.0, 1.0)
        pgap_lower[pgap_lower < ROUNDING] = 0.0
        pgap_upper = np.clip(1.0 - above_upper / denominator, 0.0, 1.0)
        pgap_upper[pgap_upper < ROUNDING] = 0.0
        pai_lower = plant_area_index(pgap_lower, np.asarray(cos_zenith)[..., None] if np.ndim(cos_zenith) else
                                     cos_zenith, rossg, omega)
        pai_upper = plant_area_index(pgap_upper, np.asarray(cos_zenith)[..., None] if np.ndim(cos_zenith) else
                                     cos_zenith, rossg, omega)
        pavd = (pai_lower - pai_upper) / bin_height
    return np.where(denominator > 0, pavd, np.nan)


def cover_and_pai(rv: np.ndarray, rg: np.ndarray, cos_zenith: float | np.ndarray = 1.0,
                  rhov_rhog: float = RHOV_RHOG, rossg: float = ROSSG,
                  omega: float = OMEGA) -> tuple[np.ndarray, np.ndarray]:
    """L2B's cover and PAI from the canopy and ground energies (NaN where both are 0)."""
    from fwcore.metrics.canopy import canopy_cover

    rv, rg = np.asarray(rv, float), np.asarray(rg, float)
    pgap = gap_probability(rv, rg, rhov_rhog)
    none = ~(rv + rg > 0)
    return (np.where(none, np.nan, canopy_cover(pgap, cos_zenith)),
            np.where(none, np.nan, plant_area_index(pgap, cos_zenith, rossg, omega)))
