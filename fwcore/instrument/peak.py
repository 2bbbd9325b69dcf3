"""A peak of a waveform or a response: its sub-sample vertex, its half-height width and crossings, its main lobe,
and whether it is one strong echo standing alone in its record.

The half height is measured three ways, each where it was measured first: changing how one rounds changes the
widths the method runs with in their last bit (the outputs are kept bit for bit), so each is named for its use.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT_INLINE


@njit(**JIT_INLINE)
def parabola_vertex(v, i):
    """Where the parabola through v[i - 1], v[i], v[i + 1] peaks, in samples from i (within half a sample;
    0 at an edge or where v does not bend down there)."""
    if i <= 0 or i >= v.size - 1:
        return 0.0
    den = v[i - 1] - 2.0 * v[i] + v[i + 1]
    return min(max(0.5 * (v[i - 1] - v[i + 1]) / den, -0.5), 0.5) if den < 0 else 0.0


@njit(**JIT_INLINE)
def parabola_height(v, i, shift):
    """That parabola's height `shift` samples from i."""
    if i <= 0 or i >= v.size - 1:
        return float(v[i])
    return v[i] - 0.25 * (v[i - 1] - v[i + 1]) * shift


@njit(**JIT_INLINE)
def half_height_crossings(values, valid, peak, height):
    """(left, right): where the values first fall to half of `height` walking out from index `peak` over valid
    samples, interpolated; -1.0 for a side that does not fall that far. The kernels' (echo widths)."""
    half = 0.5 * height
    left = -1.0
    i = peak
    while i > 0 and valid[i - 1]:
        if values[i - 1] <= half:
            left = (i - 1) + (half - values[i - 1]) / (values[i] - values[i - 1])
            break
        i -= 1
    right = -1.0
    i = peak
    while i < values.size - 1 and valid[i + 1]:
        if values[i + 1] <= half:
            right = i + (values[i] - half) / (values[i] - values[i + 1])
            break
        i += 1
    return left, right


def half_height_width(t: np.ndarray, v: np.ndarray) -> float:
    """The FWHM of the highest peak of v(t) (a response, peak above 0), crossings interpolated in t; a side
    that does not fall to half height ends at the grid's edge."""
    peak = int(np.argmax(v))
    half = 0.5 * v[peak]
    left = peak
    while left > 0 and v[left - 1] > half:
        left -= 1
    right = peak
    while right < v.size - 1 and v[right + 1] > half:
        right += 1
    lx = np.interp(half, [v[left - 1], v[left]], [t[left - 1], t[left]]) if left > 0 else t[0]
    rx = np.interp(half, [v[right + 1], v[right]], [t[right + 1], t[right]]) if right < v.size - 1 else t[-1]
    return float(rx - lx)


def width_above_minimum(samples) -> float:
    """Width (samples) of the highest peak at half its height above the record's minimum, crossings
    interpolated: a pulse on its own background (an outgoing pulse, a single return)."""
    y = np.asarray(samples, dtype=float)
    base = y.min()
    half = base + 0.5 * (y.max() - base)
    peak = int(np.argmax(y))
    left = peak
    while left > 0 and y[left - 1] >= half:
        left -= 1
    right = peak
    while right < y.size - 1 and y[right + 1] >= half:
        right += 1
    lx = left - (y[left] - half) / (y[left] - y[left - 1]) if left > 0 else float(left)
    rx = right + (y[right] - half) / (y[right] - y[right + 1]) if right < y.size - 1 else float(right)
    return float(rx - lx)


def main_lobe(signal: np.ndarray, peak: int, fraction: float) -> tuple[int, int]:
    """The first and last sample of the run around `peak` where signal stays above fraction x its height."""
    above = signal > fraction * signal[peak]
    lo = peak
    while lo > 0 and above[lo - 1]:
        lo -= 1
    hi = peak
    while hi < signal.size - 1 and above[hi + 1]:
        hi += 1
    return lo, hi


LOBE_FRACTION = 0.1  # of the peak: where an echo's support begins


def isolated_lobe(signal: np.ndarray, peak: int, min_height: float,
                  outside_fraction: float) -> tuple[int, int] | None:
    """The main lobe (first, last sample above LOBE_FRACTION of the peak) of a strong echo standing alone in its
    record, or None: the peak below min_height, the lobe cut by the record's edge, or a sample outside it above
    outside_fraction of the peak (another return). The two callers ask for different strengths: the response
    (SNR 30, 15%) wants tails clean, the width estimate (SNR 20, 10%) more echoes."""
    height = signal[peak]
    if height < min_height:
        return None
    lo, hi = main_lobe(signal, peak, LOBE_FRACTION)
    if lo == 0 or hi == signal.size - 1:
        return None
    outside = np.concatenate([signal[:lo], signal[hi + 1:]])
    if outside.size and outside.max() > outside_fraction * height:
        return None
    return lo, hi


def local_maxima(values: np.ndarray) -> int:
    """How many interior local maxima (higher than the sample before, at least the one after) values has."""
    return int(np.count_nonzero((values[1:-1] > values[:-2]) & (values[1:-1] >= values[2:])))
