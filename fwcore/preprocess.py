"""Denoising and the initial estimate of background, noise and echoes (the method's section 1.2).

Positions and widths here are in samples; sample i lies at time i. A waveform
is its samples plus a validity mask: a recorded waveform may have gaps (NEON
pads with zeros between segments) and every valid sample keeps its own time.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from fwcore._jit import JIT

_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
MIN_SIGMA = 0.5  # samples: narrower than this is below what a sampled echo can show


@njit(**JIT)
def _smooth(samples, valid, sigma, out):
    """Gaussian filter by normalized convolution, so gaps do not pull the signal to zero."""
    n = samples.size
    if sigma <= 0.0:
        for i in range(n):
            out[i] = samples[i]
        return
    half = int(math.ceil(4.0 * sigma))
    weights = np.empty(2 * half + 1)
    for j in range(-half, half + 1):
        weights[j + half] = math.exp(-0.5 * (j / sigma) ** 2)
    for i in range(n):
        acc = 0.0
        norm = 0.0
        for j in range(max(0, i - half), min(n, i + half + 1)):
            if valid[j]:
                w = weights[j - i + half]
                acc += w * samples[j]
                norm += w
        out[i] = acc / norm if norm > 0.0 else samples[i]


@njit(**JIT)
def _noise_sigma(samples, smoothed, valid):
    acc = 0.0
    m = 0
    for i in range(samples.size):
        if valid[i]:
            d = samples[i] - smoothed[i]
            acc += d * d
            m += 1
    return math.sqrt(acc / m) if m > 0 else 0.0


@njit(**JIT)
def _valid_min(values, valid):
    best = np.inf
    for i in range(values.size):
        if valid[i] and values[i] < best:
            best = values[i]
    return best


@njit(**JIT)
def _inflection(residual, valid, peak, step):
    """Distance from the peak to the first inflection point walking by `step` (+1 or -1).

    The second difference is negative at a peak; the inflection point is where it
    turns non-negative, interpolated linearly. Returns -1.0 when none is found
    before the waveform's edge or a gap.
    """
    n = residual.size
    prev = residual[peak - 1] - 2.0 * residual[peak] + residual[peak + 1] if 0 < peak < n - 1 else -1.0
    i = peak + step
    while 0 < i < n - 1:
        if not (valid[i - 1] and valid[i] and valid[i + 1]):
            return -1.0
        d2 = residual[i - 1] - 2.0 * residual[i] + residual[i + 1]
        if d2 >= 0.0:
            frac = prev / (prev - d2) if prev < 0.0 else 1.0
            return abs(i - peak) - 1.0 + frac
        prev = d2
        i += step
    return -1.0


@njit(**JIT)
def _half_height_sigma(residual, valid, peak):
    """sigma from the half-height width (a Gaussian's FWHM = 2.3548 sigma); -1.0 if not bracketed."""
    n = residual.size
    half = 0.5 * residual[peak]
    left = -1.0
    i = peak
    while i > 0 and valid[i - 1]:
        if residual[i - 1] <= half:
            left = (i - 1) + (half - residual[i - 1]) / (residual[i] - residual[i - 1])
            break
        i -= 1
    right = -1.0
    i = peak
    while i < n - 1 and valid[i + 1]:
        if residual[i + 1] <= half:
            right = i + (residual[i] - half) / (residual[i] - residual[i + 1])
            break
        i += 1
    if left >= 0.0 and right >= 0.0:
        return (right - left) / (2.0 * _SQRT_2LN2)
    if left >= 0.0:
        return (peak - left) / _SQRT_2LN2
    if right >= 0.0:
        return (right - peak) / _SQRT_2LN2
    return -1.0


@njit(**JIT)
def _echo_sigma(residual, valid, peak, fallback):
    """sigma = |p1 - p2| / 2 from the inflection points; one side doubles the other; none: half height."""
    left = _inflection(residual, valid, peak, -1)
    right = _inflection(residual, valid, peak, 1)
    if left > 0.0 and right > 0.0:
        sigma = 0.5 * (left + right)
    elif left > 0.0:
        sigma = left
    elif right > 0.0:
        sigma = right
    else:
        sigma = _half_height_sigma(residual, valid, peak)
        if sigma <= 0.0:
            sigma = fallback
    return max(sigma, MIN_SIGMA)


@njit(**JIT)
def _progressive_echoes(smoothed, valid, background, threshold, max_echoes, fallback_sigma,
                        amplitude, position, sigma):
    """Extract echoes one by one from the largest remaining peak; returns how many were found."""
    n = smoothed.size
    residual = smoothed - background
    count = 0
    while count < max_echoes:
        peak = -1
        height = -np.inf
        for i in range(n):
            if valid[i] and residual[i] > height:
                height = residual[i]
                peak = i
        if peak < 0 or height <= threshold:
            break
        s = _echo_sigma(residual, valid, peak, fallback_sigma)
        amplitude[count] = height
        position[count] = peak
        sigma[count] = s
        count += 1
        inv = 1.0 / (2.0 * s * s)
        for i in range(n):
            d = i - peak
            residual[i] -= height * math.exp(-d * d * inv)
    return count


@dataclasses.dataclass(frozen=True)
class InitialEstimate:
    """Background, noise and Gaussian echoes (alpha = sqrt(2)) before optimisation, in samples."""

    smoothed: np.ndarray
    noise_sigma: float
    background: float
    amplitude: np.ndarray
    position: np.ndarray
    sigma: np.ndarray

    @property
    def n_echoes(self) -> int:
        return int(self.amplitude.size)


def _as_waveform(samples, valid) -> tuple[np.ndarray, np.ndarray]:
    samples = np.ascontiguousarray(samples, dtype=np.float64)
    valid = np.ones(samples.size, bool) if valid is None else np.ascontiguousarray(valid, dtype=bool)
    if valid.shape != samples.shape:
        raise ValueError(f"valid mask has shape {valid.shape}, samples {samples.shape}")
    if not np.isfinite(samples[valid]).all():
        raise ValueError("waveform has non-finite samples")
    return samples, valid


def gaussian_smooth(samples, sigma: float, valid=None) -> np.ndarray:
    """Denoise with a Gaussian filter of `sigma` samples (0: no smoothing), ignoring invalid samples."""
    samples, valid = _as_waveform(samples, valid)
    out = np.empty_like(samples)
    _smooth(samples, valid, float(sigma), out)
    return out


def estimate_noise(samples, smoothed, valid=None) -> float:
    """sigma_noise = sqrt(sum((raw - smoothed)**2) / m) over the m valid samples."""
    samples, valid = _as_waveform(samples, valid)
    return float(_noise_sigma(samples, np.ascontiguousarray(smoothed, dtype=np.float64), valid))


def initial_echoes(samples, smoothing_sigma: float, fallback_sigma: float, valid=None,
                   noise_threshold: float = 3.0, max_echoes: int = 12) -> InitialEstimate:
    """The method's progressive estimate: smooth, measure noise, then peel echoes off one by one.

    An echo is accepted while the largest remaining peak rises more than
    noise_threshold * sigma_noise above the background (the smoothed minimum).
    """
    samples, valid = _as_waveform(samples, valid)
    smoothed = np.empty_like(samples)
    _smooth(samples, valid, float(smoothing_sigma), smoothed)
    noise = _noise_sigma(samples, smoothed, valid)
    background = _valid_min(smoothed, valid)
    amplitude = np.zeros(max_echoes)
    position = np.zeros(max_echoes)
    sigma = np.zeros(max_echoes)
    n = _progressive_echoes(smoothed, valid, background, noise_threshold * noise, max_echoes,
                            float(fallback_sigma), amplitude, position, sigma)
    return InitialEstimate(smoothed, noise, background, amplitude[:n], position[:n], sigma[:n])


def half_height_width(samples) -> float:
    """Width (samples) of the highest peak at half its height above the minimum, crossings interpolated."""
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


def median_pulse_fwhm(waveforms, min_samples: int = 5) -> float:
    """The median half-height width (samples) over waveforms of single pulses: outgoing pulses, or
    returns that the system itself saw as single. Raises when no waveform is usable."""
    widths = [half_height_width(w) for w in waveforms if len(w) >= min_samples and np.ptp(w) > 0]
    if not widths:
        raise ValueError("no usable waveform to measure the system pulse width")
    return float(np.median(widths))
