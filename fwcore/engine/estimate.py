"""The initial estimate (the method's section 1.2): the echoes peeled off a denoised waveform one by one, each
placed at its peak and as wide as its inflection points (or half-height width) say, before any optimiser runs.

Positions and widths here are in samples; sample i lies at time i. The denoising, noise and background it
starts from are fwcore.engine.smoothing's.

    initial_estimate(...)   the kernel the engine runs: denoise, then peel up to max_echoes echoes off
    initial_echoes(...)     the same from Python, as an InitialEstimate
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE, searchsorted
from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.model import add_table_echo, analytic_shape, table_peak_offset, table_reach
from fwcore.engine.smoothing import as_waveform, denoise, smoothing_support
from fwcore.instrument.peak import half_height_crossings, parabola_height, parabola_vertex

_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
MIN_SIGMA = 0.5  # samples: narrower than this is below what a sampled echo can show
# A target widens both sides of a return, a neighbour one: where the wider side is within this factor of the
# narrower (each against the response's own), a tabulated echo starts as wide as its whole half-height width says
SIDE_BALANCE = 1.15


@njit(**JIT)
def _noise_threshold(smoothed, valid, background, noise, shape_tolerance, k, out):
    """k x the noise of each sample under the constant-plus-shape noise model:
    sqrt(sigma**2 + (shape_tolerance x signal)**2), signal the smoothed height above background."""
    for i in range(smoothed.size):
        s = max(smoothed[i] - background, 0.0) * shape_tolerance if valid[i] else 0.0
        out[i] = k * math.sqrt(noise * noise + s * s)


@njit(**JIT_INLINE)
def inflection_distance(residual, valid, peak, step):
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


@njit(**JIT_INLINE)
def half_height_sigma(residual, valid, peak):
    """sigma from the half-height width (a Gaussian's FWHM = 2.3548 sigma); -1.0 if not bracketed."""
    left, right = half_height_crossings(residual, valid, peak, residual[peak])
    if left >= 0.0 and right >= 0.0:
        return (right - left) / (2.0 * _SQRT_2LN2)
    if left >= 0.0:
        return (peak - left) / _SQRT_2LN2
    if right >= 0.0:
        return (right - peak) / _SQRT_2LN2
    return -1.0


@njit(**JIT_INLINE)
def _echo_sigma(residual, valid, peak, fallback):
    """sigma = |p1 - p2| / 2 from the inflection points; one side doubles the other; none: half height."""
    left = inflection_distance(residual, valid, peak, -1)
    right = inflection_distance(residual, valid, peak, 1)
    if left > 0.0 and right > 0.0:
        sigma = 0.5 * (left + right)
    elif left > 0.0:
        sigma = left
    elif right > 0.0:
        sigma = right
    else:
        sigma = half_height_sigma(residual, valid, peak)
        if sigma <= 0.0:
            sigma = fallback
    return max(sigma, MIN_SIGMA)


@njit(**JIT_INLINE)
def _vertex(values, valid, peak):
    """(position, height) of the parabola's vertex through a peak and its two neighbours, where both are valid."""
    if peak == 0 or peak == values.size - 1 or not (valid[peak - 1] and valid[peak + 1]):
        return float(peak), values[peak]
    shift = parabola_vertex(values, peak)
    return peak + shift, parabola_height(values, peak, shift)


@njit(**JIT_INLINE)
def _tabulated_width(residual, valid, peak, centre, height, shape):
    """A tabulated echo's starting width: the response broadened by how much wider than the response's the
    residual's peak is at half height: on both sides where they widened alike (a target), on its narrower
    side where one widened more (a neighbour widens one side only); the response itself where neither side
    falls to half height."""
    left, right = half_height_crossings(residual, valid, peak, height)
    response_left, response_right = shape.half_widths[0], shape.half_widths[1]
    has_left = left >= 0.0 and centre - left > 0.0
    has_right = right >= 0.0 and right - centre > 0.0
    if not (has_left or has_right):
        return shape.s_min
    left_ratio = (centre - left) / response_left if has_left else np.inf
    right_ratio = (right - centre) / response_right if has_right else np.inf
    ratio = min(left_ratio, right_ratio)
    if has_left and has_right and max(left_ratio, right_ratio) <= SIDE_BALANCE * ratio:
        ratio = (right - left) / (response_left + response_right)
    widest = shape.s_min + shape.s_step * (shape.rows.shape[0] - 1)
    return min(max(shape.s_min * ratio, shape.s_min), widest)


@njit(**JIT_INLINE)
def _label_returns(residual, valid, threshold, out):
    """Number each run of valid samples whose denoised height clears the threshold (a return: 1, 2, ...);
    0 elsewhere."""
    label = 0
    inside = False
    for i in range(residual.size):
        if valid[i] and residual[i] > threshold[i]:
            if not inside:
                label += 1
                inside = True
            out[i] = label
        else:
            inside = False
            out[i] = 0


@njit(**JIT_INLINE)
def _beside_an_echo(i, returns, echo_return, position, count, reach):
    """Whether sample i lies in the return of one of the first `count` echoes, or within `reach` samples of one."""
    for k in range(count):
        if (returns[i] > 0 and returns[i] == echo_return[k]) or abs(i - position[k]) <= reach:
            return True
    return False


# A peak this close to a peeled echo (in pulse widths), and weaker than p.flank_ratio of it, is mostly the
# residual of a peeled echo wider than its estimate (a sloped or rough target), not an echo (config: fast).
FLANK_REACH_W = 0.75


@njit(**JIT_INLINE)
def _on_a_flank(i, height, amplitude, position, count, reach, ratio):
    """Whether sample i, `height` above background, lies within `reach` samples of one of the first `count`
    echoes and under `ratio` times its amplitude."""
    for k in range(count):
        if abs(i - position[k]) < reach and height < ratio * amplitude[k]:
            return True
    return False


@njit(**JIT)
def _progressive_echoes(smoothed, valid, background, threshold, max_echoes, fallback_sigma, shape,
                        amplitude, position, sigma, floor_ratio, flank_ratio):
    """Extract echoes one by one from the largest remaining peak that rises above its sample's
    threshold, each subtracted in the model's shape (a tabulated response takes its tail and afterpulse
    with it); returns how many were found. Once the largest peak left is under floor_ratio x the first
    (the filter's weak echo), only peaks in the return of an echo or within one FWHM of one stay
    candidates: a shoulder or a broadened return's flank the fit needs, not a bump far from every echo.
    A peak within FLANK_REACH_W pulse widths of an echo and under flank_ratio x its amplitude is never one."""
    n = smoothed.size
    residual = smoothed - background
    sample_times = np.empty(n)
    for i in range(n):
        sample_times[i] = i
    returns = np.empty(n, dtype=np.int64)
    _label_returns(residual, valid, threshold, returns)
    echo_return = np.zeros(max_echoes, dtype=np.int64)
    searched = np.zeros(n, dtype=np.bool_)  # samples left out of the search for peaks
    reach = 2.0 * _SQRT_2LN2 * fallback_sigma  # a pulse width (FWHM)
    count = 0
    while count < max_echoes:
        peak = -1
        height = -np.inf
        for i in range(n):
            if valid[i] and not searched[i] and residual[i] > threshold[i] and residual[i] > height:
                height = residual[i]
                peak = i
        if peak < 0:
            break
        if count > 0 and height < floor_ratio * amplitude[0] and \
                not _beside_an_echo(peak, returns, echo_return, position, count, reach):
            for i in range(n):  # every peak left is as weak: only those beside an echo stay candidates
                searched[i] = searched[i] or not _beside_an_echo(i, returns, echo_return, position, count, reach)
            continue
        if _on_a_flank(peak, height, amplitude, position, count, FLANK_REACH_W * reach, flank_ratio):
            for i in range(n):  # the whole flank: its every sample is as close and as weak
                searched[i] = searched[i] or _on_a_flank(i, residual[i], amplitude, position, count,
                                                         FLANK_REACH_W * reach, flank_ratio)
            continue
        echo_return[count] = returns[peak]
        if shape.tabulated:
            # at the parabola's vertex through the peak and its neighbours (an echo subtracted half a sample
            # off leaves a flank that would be peeled as an echo of its own), as wide as its clean side says
            centre, top = _vertex(residual, valid, peak)
            s = _tabulated_width(residual, valid, peak, centre, top, shape)
            amplitude[count] = top
            position[count] = centre - table_peak_offset(shape, s)  # an echo's position is its lobe's centroid
            sigma[count] = s
            # over its table's support only: the rows are exactly 0 outside it, so the other samples keep their bits
            before, after = table_reach(shape, s)
            add_table_echo(shape, -top, position[count], s, sample_times,
                           searchsorted(sample_times, position[count] - before),
                           searchsorted(sample_times, position[count] + after, right=True), residual)
            count += 1
            continue
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


@njit(**JIT)
def initial_estimate(samples, valid, smoothing_sigma, pulse_sigma, p, shape, smoothed, amplitude, position, sigma,
                     noise_floor):
    """The method's section 1.2, the kernel the engine runs: denoise into `smoothed`, measure the
    noise and background (fwcore.engine.smoothing.denoise, robust where p.robust_noise), then peel up to
    p.max_echoes echoes off (fwcore.engine.config.KernelParams).
    Returns (noise sigma, background, echo count); the noise is at least `noise_floor` (the file's own, or 0)."""
    noise, background = denoise(samples, valid, smoothing_sigma, p.robust_noise, p.min_noise_sigma, smoothed)
    noise = max(noise, noise_floor)
    threshold = np.empty(samples.size)
    support = np.empty(samples.size, dtype=np.bool_)
    smoothing_support(valid, smoothing_sigma, support)
    _noise_threshold(smoothed, support, background, noise, p.shape_tolerance, p.noise_threshold, threshold)
    # with the selection on, no echo the filter would call weak is proposed (it was fitted, then dropped by a
    # refit: on riegl_example3.pls 0.27 echoes a pulse, a third of the engine's time); the method's own estimate
    # (no selection, the paper) proposes every peak above the threshold
    floor_ratio = p.min_amplitude_ratio if p.select_echoes else 0.0
    flank_ratio = p.flank_ratio if p.select_echoes else 0.0
    n = _progressive_echoes(smoothed, support, background, threshold, p.max_echoes, pulse_sigma, shape,
                            amplitude, position, sigma, floor_ratio, flank_ratio)
    return noise, background, n


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


def initial_echoes(samples, smoothing_sigma: float, fallback_sigma: float, valid=None,
                   noise_threshold: float = 3.0, max_echoes: int = 12, robust: bool = True,
                   min_noise_sigma: float = 1.0 / math.sqrt(12.0), shape_tolerance: float = 0.0,
                   shape=None) -> InitialEstimate:
    """The progressive estimate the engine starts from: smooth, measure noise, then peel echoes off
    one by one while the largest remaining peak rises more than noise_threshold x its sample's noise
    above the background (the smoothed minimum), each peeled off in `shape`'s form
    (fwcore.engine.model.EchoShape; None: a Gaussian). The settings are checked as DecompositionConfig
    checks them."""
    samples, valid = as_waveform(samples, valid)
    smoothed = np.empty_like(samples)
    amplitude = np.zeros(max_echoes)
    position = np.zeros(max_echoes)
    sigma = np.zeros(max_echoes)
    settings = DecompositionConfig(noise_threshold=noise_threshold, max_echoes=max_echoes,
                                   noise_estimator="robust" if robust else "residual", min_noise_sigma=min_noise_sigma)
    noise, background, n = initial_estimate(
        samples, valid, float(smoothing_sigma), float(fallback_sigma),
        settings.kernel_params(Model.GENERALIZED, shape_tolerance),
        analytic_shape() if shape is None else shape, smoothed, amplitude, position, sigma, 0.0)
    return InitialEstimate(smoothed, float(noise), float(background), amplitude[:n], position[:n], sigma[:n])
