"""The ground: a mode of the smoothed waveform within the signal, as GEDI's L2A finds it (zcross), for every L2A
algorithm.

A mode is a zero crossing, from rising to falling, of the zcross-smoothed waveform's first derivative (central
differences), placed between samples by linear interpolation and rounded to the sub-bin grid; L2A keeps the modes
between toploc and botloc whose smoothed amplitude clears the back threshold (rx_modelocs, rx_modeamps).

Without mode selection (L2A's algorithms 1, 3, 4, 5, 6: enable_select_mode 0) the ground is the lowest of them.
With it (algorithm 2) L2A walks up from the lowest mode and passes over weak modes near the signal's end: a mode
is skipped while it lies within `pulse_sep_thresh` samples of botloc, or its amplitude above the noise mean is
under the back threshold's, or the cumulative energy at it is under `cumulative_energy_minimum` %; the first mode
not skipped is the ground if its local energy exceeds `energy_thresh`, or its amplitude above the mean
`amp_thresh`, or the cumulative energy `cumulative_energy_thresh` %. If no mode qualifies the lowest stays.
The walk covers the lowest rx_max_mode_count modes (fwcore.metrics.waveform.ground_mode): L2A stores that many.
Reverse-engineered from L2A's rx_processing_aN results (selected_mode, rx_modelocalenergy, rx_iwaveamps) on the
shared granule and John Armston's gedipy (its L2A file class); the L2A ATBD (Hofton & Blair) names the steps:

- the cumulative energy at a mode (rx_iwaveamps, as a fraction): the share of the zcross-smoothed waveform's
  energy above the noise mean, on the sub-bin grid between toploc and botloc, from botloc up to the mode inclusive;
- a mode's local energy (rx_modelocalenergy): that waveform's energy above the noise mean within
  +-pulse_sep_thresh samples of the mode, less the straight line between the window's ends (a mode on the
  flank of a larger one keeps only its own bump), in sample units (the sub-bin sum / subbins).
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


def signal_modes(smoothed: np.ndarray, toploc: float, botloc: float, threshold: float,
                 subbins: int) -> tuple[np.ndarray, np.ndarray]:
    """The modes L2A keeps (top to bottom): within [toploc, botloc] and above `threshold`."""
    position, amplitude = modes(smoothed, subbins)
    inside = (position >= toploc) & (position <= botloc) & (amplitude > threshold)
    return position[inside], amplitude[inside]


def lowest_mode(smoothed: np.ndarray, toploc: float, botloc: float, threshold: float, subbins: int) -> float:
    """The ground's position (samples from the first): the lowest mode within [toploc, botloc] above `threshold`;
    NaN when there is none."""
    position, _ = signal_modes(smoothed, toploc, botloc, threshold, subbins)
    return float(position[-1]) if position.size else np.nan


def cumulative_energy_at(x: np.ndarray, energy: np.ndarray, toploc: float, botloc: float,
                         positions: np.ndarray) -> np.ndarray:
    """The share (0..1) of the signal's energy from botloc up to each position inclusive (L2A's rx_iwaveamps)."""
    inside = (x >= toploc) & (x <= botloc)
    total = energy[inside].sum()
    return np.array([energy[inside & (x >= p)].sum() / total if total > 0 else np.nan for p in positions])


def local_energy(energy: np.ndarray, positions: np.ndarray, half_width: float, subbins: int) -> np.ndarray:
    """Each mode's energy within +-half_width samples less the line between the window's ends, in sample units
    (`energy` on the sub-bin grid; L2A's rx_modelocalenergy)."""
    h = int(round(half_width * subbins))
    out = np.empty(positions.size)
    for i, p in enumerate(positions):
        k = int(round(p * subbins))
        window = energy[max(k - h, 0):min(k + h, energy.size - 1) + 1]
        out[i] = (window.sum() - 0.5 * (window[0] + window[-1]) * window.size) / subbins
    return out


def selected_mode(positions: np.ndarray, amplitude_above_mean: np.ndarray, cumulative_percent: np.ndarray,
                  local: np.ndarray, botloc: float, back_above_mean: float, pulse_sep_thresh: float,
                  cumulative_energy_minimum: float, energy_thresh: float, amp_thresh: float,
                  cumulative_energy_thresh: float) -> int:
    """L2A's mode selection: the index (modes top to bottom) of the ground mode; the lowest when none qualifies."""
    for j in range(positions.size - 1, -1, -1):
        if (botloc - positions[j] < pulse_sep_thresh or amplitude_above_mean[j] < back_above_mean
                or cumulative_percent[j] < cumulative_energy_minimum):
            continue
        if (local[j] > energy_thresh or amplitude_above_mean[j] > amp_thresh
                or cumulative_percent[j] > cumulative_energy_thresh):
            return j
    return positions.size - 1
