"""The ground: the lowest mode of the smoothed waveform within the signal, as GEDI's L2A finds it (zcross).

A mode is a zero crossing, from rising to falling, of the smoothed waveform's first derivative (central
differences), placed between samples by linear interpolation and rounded to the sub-bin grid. The ground is the
lowest mode (the last in time) between toploc and botloc whose smoothed amplitude clears the back threshold.
"""

from __future__ import annotations

import numpy as np


def modes(smoothed: np.ndarray, subbins: int) -> tuple[np.ndarray, np.ndarray]:
    """Every local maximum of the smoothed waveform: its position (samples, on the sub-bin grid) and amplitude."""
    if smoothed.size < 3:
        return np.zeros(0), np.zeros(0)
    slope = np.gradient(smoothed)
    j = np.flatnonzero((slope[:-1] > 0) & (slope[1:] <= 0))
    crossing = j + slope[j] / (slope[j] - slope[j + 1])
    position = np.round(crossing * subbins) / subbins
    return position, np.interp(position, np.arange(smoothed.size), smoothed)


def lowest_mode(smoothed: np.ndarray, toploc: float, botloc: float, threshold: float, subbins: int) -> float:
    """The ground's position (samples from the first): the lowest mode within [toploc, botloc] above `threshold`;
    NaN when there is none."""
    position, amplitude = modes(smoothed, subbins)
    inside = (position >= toploc) & (position <= botloc) & (amplitude > threshold)
    return float(position[inside][-1]) if inside.any() else np.nan
