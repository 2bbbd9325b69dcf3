"""Relative heights (GEDI L2A): RHk is the height above the ground below which k % of the waveform's energy lies,
the energy being the smoothed waveform above the noise mean between the signal's end (botloc, RH0, below the
ground) and its start (toploc, RH100).

Positions are found on the sub-bin grid from the bottom up: the k % position is the last sub-bin whose
cumulative energy is still under k % (NASA's rx_cumulative); heights are truncated toward zero to centimetres as
L2A stores them.
"""

from __future__ import annotations

import numpy as np

PERCENTILES = np.arange(101)


def energy_positions(x: np.ndarray, energy: np.ndarray, toploc: float, botloc: float) -> np.ndarray:
    """The 101 positions (samples from the first) where the cumulative energy from botloc upward reaches 0..100 %;
    RH0 at botloc, RH100 at toploc."""
    inside = (x >= toploc) & (x <= botloc)
    position, e = x[inside][::-1], energy[inside][::-1]  # from the bottom up
    cumulative = np.cumsum(e)
    total = cumulative[-1]
    if position.size < 2 or not total > 0:
        return np.full(PERCENTILES.size, np.nan)
    index = np.searchsorted(cumulative / total, PERCENTILES / 100.0) - 1
    out = position[np.clip(index, 0, position.size - 1)]
    out[0], out[-1] = botloc, toploc
    return out


def relative_heights(positions: np.ndarray, ground: float, metres_per_sample: float) -> np.ndarray:
    """RH0..RH100 in metres above the ground (RH0 negative: the signal ends below it), truncated to centimetres."""
    return np.trunc((ground - positions) * metres_per_sample * 100.0) / 100.0
