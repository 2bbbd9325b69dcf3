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

from fwcore._jit import JIT, JIT_INLINE
from fwcore.engine.config import DecompositionConfig, Model
from fwcore.instrument.peak import half_height_crossings, parabola_height, parabola_vertex
from fwcore.engine.model import add_table_echo, analytic_shape, table_peak_offset

_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
MIN_SIGMA = 0.5  # samples: narrower than this is below what a sampled echo can show
# A target widens both sides of a return, a neighbour one: where the wider side is within this factor of the
# narrower (each against the response's own), a tabulated echo starts as wide as its whole half-height width says
SIDE_BALANCE = 1.15


@njit(**JIT_INLINE)
def filter_half_width(sigma):
    """How many samples the Gaussian filter of `sigma` reaches on each side: ceil(4 sigma)."""
    return int(math.ceil(4.0 * sigma))


@njit(**JIT)
def gaussian_weights(sigma):
    """The Gaussian filter's unnormalised weights exp(-j^2 / (2 sigma^2)) for |j| <= filter_half_width(sigma)."""
    half = filter_half_width(sigma)
    weights = np.empty(2 * half + 1)
    for j in range(-half, half + 1):
        weights[j + half] = math.exp(-0.5 * (j / sigma) ** 2)
    return weights


@njit(**JIT_INLINE)
def smoothed_value(total, norm, sample):
    """The filter's value from weighted_sums' numerator and weight: the sample itself where no valid one is near."""
    return total / norm if norm > 0.0 else sample


@njit(**JIT_INLINE)
def _window_sums(samples, valid, weights, i):
    """Sample i's numerator and weight, over j ascending (what weighted_sums computes for every i)."""
    n = samples.size
    half = weights.size // 2
    acc = 0.0
    norm = 0.0
    for j in range(max(0, i - half), min(n, i + half + 1)):
        if valid[j]:
            w = weights[j - i + half]
            acc += w * samples[j]
            norm += w
    return acc, norm


@njit(**JIT_INLINE)
def smoothed_sample(samples, valid, weights, i):
    """The filter of weighted_sums at sample i alone."""
    acc, norm = _window_sums(samples, valid, weights, i)
    return smoothed_value(acc, norm, samples[i])


@njit(**JIT_INLINE)
def _whole_windows(valid, half):
    """The samples [lo, hi) whose window of half samples on each side is whole (no gap, not past an end): the
    interior of a waveform without gaps, none of one with gaps (its windows are summed one by one)."""
    n = valid.size
    for i in range(n):
        if not valid[i]:
            return 0, 0
    return half, max(n - half, half)


@njit(**JIT)
def weighted_sums(samples, valid, weights, sums, norms):
    """The Gaussian filter by normalized convolution over the valid samples: for every sample i, the numerator
    sums[i] = sum_j weights[j - i + half] samples[j] and the weight norms[i] = sum_j weights[j - i + half],
    j over the valid samples within half = weights.size // 2 of i, ascending (smoothed_value divides).
    Where a window is whole (no gap, not at an end), four samples are summed at once, each in its own
    accumulator and in the same order: the same bits, without waiting on each add."""
    n = samples.size
    half = weights.size // 2
    lo, hi = _whole_windows(valid, half)
    whole = 0.0
    for k in range(weights.size):
        whole += weights[k]
    blocked = lo + (hi - lo) // 4 * 4  # [lo, blocked): four at a time
    for i in range(lo, blocked, 4):
        a0 = a1 = a2 = a3 = 0.0
        for k in range(weights.size):
            w = weights[k]
            j = i - half + k
            a0 += w * samples[j]
            a1 += w * samples[j + 1]
            a2 += w * samples[j + 2]
            a3 += w * samples[j + 3]
        sums[i], sums[i + 1], sums[i + 2], sums[i + 3] = a0, a1, a2, a3
        norms[i] = norms[i + 1] = norms[i + 2] = norms[i + 3] = whole
    for i in range(n):
        if i < lo or i >= blocked:
            sums[i], norms[i] = _window_sums(samples, valid, weights, i)


@njit(**JIT)
def _smooth(samples, valid, sigma, out):
    """Gaussian filter by normalized convolution, so gaps do not pull the signal to zero."""
    n = samples.size
    if sigma <= 0.0:
        for i in range(n):
            out[i] = samples[i]
        return
    norms = np.empty(n)
    weighted_sums(samples, valid, gaussian_weights(sigma), out, norms)
    for i in range(n):
        out[i] = smoothed_value(out[i], norms[i], samples[i])


@njit(**JIT)
def residual_noise_sigma(samples, smoothed, valid):
    """The method's sigma_noise = sqrt(mean((raw - smoothed)**2)) over the valid samples."""
    acc = 0.0
    m = 0
    for i in range(samples.size):
        if valid[i]:
            d = samples[i] - smoothed[i]
            acc += d * d
            m += 1
    return math.sqrt(acc / m) if m > 0 else 0.0


@njit(**JIT)
def _residual_attenuation(valid, sigma, out):
    """Per sample, the standard deviation of raw - smoothed per unit of white noise,
    sqrt(1 - 2 w_ii + sum_j w_ij**2), with w the filter's weights normalised over the valid samples."""
    n = valid.size
    if sigma <= 0.0:
        out[:] = 0.0
        return
    weights = gaussian_weights(sigma)
    half = weights.size // 2
    lo, hi = _whole_windows(valid, half)
    for i in range(n):
        if lo < i < hi:  # a whole window's value is the same for every such sample
            out[i] = out[lo]
            continue
        norm = 0.0
        square = 0.0
        for j in range(max(0, i - half), min(n, i + half + 1)):
            if valid[j]:
                w = weights[j - i + half]
                norm += w
                square += w * w
        if not valid[i] or norm <= 0.0:
            out[i] = 0.0
            continue
        own = weights[half] / norm
        out[i] = math.sqrt(max(1.0 - 2.0 * own + square / (norm * norm), 0.0))


@njit(**JIT_INLINE)
def _select(values, m, k):
    """The k-th smallest of values[:m] (0-based), rearranging them in place so that none before index k is
    larger: quickselect, median-of-three pivot, a partition without branches on the data (on random
    residuals an insertion sort mispredicts its every step); the pivot's equals are gathered beside it, so
    quantised samples (a few distinct counts over thousands of samples) take a pass each, not one a sample."""
    lo, hi = 0, m - 1
    while hi > lo:
        mid = (lo + hi) >> 1
        x, y, z = values[lo], values[mid], values[hi]
        if (x <= y) == (y <= z):
            p = mid
        elif (y <= x) == (x <= z):
            p = lo
        else:
            p = hi
        pivot = values[p]
        values[p] = values[hi]
        values[hi] = pivot
        store = lo
        for i in range(lo, hi):
            v = values[i]
            values[i] = values[store]
            values[store] = v
            store += v < pivot
        values[hi] = values[store]
        values[store] = pivot
        if k < store:
            hi = store - 1
            continue
        equal = store + 1  # [store, equal): the pivot's value (the rest of the right part is above it)
        for i in range(store + 1, hi + 1):
            v = values[i]
            values[i] = values[equal]
            values[equal] = v
            equal += v == pivot
        if k < equal:
            return pivot
        lo = equal
    return values[k]


@njit(**JIT_INLINE)
def _median_of_smallest(values, m, k):
    """The median of the k smallest of values[:m] (np.median's value, to the bit), values[:m] rearranged;
    1 <= k <= m."""
    j = k // 2
    upper = _select(values, m, j)
    if k % 2 == 1:
        return upper
    lower = values[0]  # the middle pair's lower value: the largest of the j smallest, which now lead
    for i in range(1, j):
        lower = max(lower, values[i])
    return (lower + upper) / 2


@njit(**JIT_INLINE)
def _median_in_place(values, m):
    """np.median(values[:m]) to the bit (an order statistic, or the mean of the middle two), values[:m]
    rearranged; m >= 1."""
    return _median_of_smallest(values, m, m)


_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): a normal's sigma from its median absolute deviation
_MIN_ATTENUATION = 0.05  # below this a sample's residual says too little about the noise


@njit(**JIT)
def _robust_noise_sigma(samples, smoothed, valid, attenuation):
    """sigma of white noise from the median absolute residual, each residual divided by its
    attenuation: the echoes, which the light smoothing follows, barely move a median. Where gaps
    leave out samples (held-out samples), only those with both neighbours valid count, when they are
    at least half of them: next to a gap the filter leans on one side, and quantised samples then
    leave residuals of a fraction of a count that pull the median towards 0.
    Without smoothing, the same from first differences of consecutive valid samples (/ sqrt 2)."""
    n = samples.size
    values = np.empty(n)
    m = 0
    k = 0  # of them, with both neighbours valid
    for i in range(n):
        if valid[i] and attenuation[i] > _MIN_ATTENUATION:
            values[m] = (samples[i] - smoothed[i]) / attenuation[i]
            m += 1
            k += (i == 0 or valid[i - 1]) and (i == n - 1 or valid[i + 1])
    if k < m and 2 * k >= m and k >= 3:  # gaps: keep the flanked residuals only (in order, over the same slots)
        m = 0
        for i in range(n):
            if valid[i] and attenuation[i] > _MIN_ATTENUATION and (i == 0 or valid[i - 1]) \
                    and (i == n - 1 or valid[i + 1]):
                values[m] = (samples[i] - smoothed[i]) / attenuation[i]
                m += 1
    scale = 1.0
    if m < 3:
        m = 0
        for i in range(n - 1):
            if valid[i] and valid[i + 1]:
                values[m] = samples[i + 1] - samples[i]
                m += 1
        scale = 1.0 / math.sqrt(2.0)
    if m == 0:
        return 0.0
    centre = _median_in_place(values, m)
    for i in range(m):
        values[i] = abs(values[i] - centre)
    return _MAD_TO_SIGMA * _median_in_place(values, m) * scale


@njit(**JIT)
def _baseline(samples, valid, noise):
    """The background level robustly: the median of the samples, repeatedly leaving out those more
    than 3 noise sigma above it (the echoes), then the mean of those within 3 sigma of it. The method's minimum of the smoothed waveform sits
    at the undershoot after a strong return, and the baseline then looks like signal."""
    values = np.empty(samples.size)
    m = 0
    for i in range(samples.size):
        if valid[i]:
            values[m] = samples[i]
            m += 1
    # the samples up to a level are the k smallest: each median is a selection (values keep their order)
    scratch = values[:m].copy()
    level = _median_in_place(scratch, m)
    for _ in range(8):
        threshold = level + 3.0 * noise
        k = m  # a NaN threshold counts every sample, as np.searchsorted sorts NaN last
        if not np.isnan(threshold):
            k = 0
            for i in range(m):
                k += values[i] <= threshold
        new = _median_of_smallest(scratch, m, k)
        if new == level:
            break
        level = new
    # the mean within +-3 sigma (in the samples' order): a median of integer samples is itself an integer
    total = 0.0
    near = 0
    for i in range(m):
        if abs(values[i] - level) <= 3.0 * noise:
            total += values[i]
            near += 1
    return total / near if near > 0 else level


_MAX_CORRELATION = 0.9


_MIN_BACKGROUND_PAIRS = 20


@njit(**JIT)
def _correlation_inflation(samples, smoothed, valid, level, noise):
    """How much more variance the noise has at an echo's bandwidth than white noise of the same
    sigma: (1 + rho) / (1 - rho) for lag-1 correlation rho (AR(1)) of the background: pairs of
    neighbours whose smoothed values stay within 1.5 sigma of the baseline, so that no echo's
    flank counts as correlation (1 when fewer than 20 such pairs). Digitizers low-pass their
    input, so neighbouring samples share noise (Leica: rho ~ 0.4)."""
    num = 0.0
    den = 0.0
    pairs = 0
    limit = 1.5 * noise
    for i in range(samples.size - 1):
        if valid[i] and valid[i + 1] and abs(smoothed[i] - level) <= limit and abs(smoothed[i + 1] - level) <= limit:
            a = samples[i] - level
            b = samples[i + 1] - level
            num += a * b
            den += 0.5 * (a * a + b * b)
            pairs += 1
    if pairs < _MIN_BACKGROUND_PAIRS or den <= 0.0:
        return 1.0
    rho = min(max(num / den, 0.0), _MAX_CORRELATION)
    return (1.0 + rho) / (1.0 - rho)


@njit(**JIT)
def _noise_threshold(smoothed, valid, background, noise, shape_tolerance, k, out):
    """k x the noise of each sample under the constant-plus-shape noise model:
    sqrt(sigma**2 + (shape_tolerance x signal)**2), signal the smoothed height above background."""
    for i in range(smoothed.size):
        s = max(smoothed[i] - background, 0.0) * shape_tolerance if valid[i] else 0.0
        out[i] = k * math.sqrt(noise * noise + s * s)


@njit(**JIT)
def valid_min(values, valid):
    best = np.inf
    for i in range(values.size):
        if valid[i] and values[i] < best:
            best = values[i]
    return best


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
    sample_times = np.arange(n).astype(np.float64)
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
            add_table_echo(shape, -top, position[count], s, sample_times, 0, n, residual)
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
def _smoothing_support(valid, sigma, out):
    """Where the denoised signal stands for the waveform: the valid samples, and the invalid ones that the
    filter interpolates, with valid samples on both sides inside its window (a held-out sample, a short gap),
    so that a peak's width is measured across them; a long gap stays out."""
    n = valid.size
    half = filter_half_width(sigma) if sigma > 0.0 else 0
    for i in range(n):
        out[i] = valid[i]
        if valid[i] or half == 0:
            continue
        before = False
        for j in range(max(0, i - half), i):
            before = before or valid[j]
        after = False
        for j in range(i + 1, min(n, i + half + 1)):
            after = after or valid[j]
        out[i] = before and after


@njit(**JIT)
def initial_estimate(samples, valid, smoothing_sigma, pulse_sigma, p, shape, smoothed, amplitude, position, sigma,
                     noise_floor):
    """The method's section 1.2, the kernel the engine runs: denoise into `smoothed`, measure the
    noise and background, then peel up to p.max_echoes echoes off (fwcore.engine.config.KernelParams).
    Returns (noise sigma, background, echo count); the noise is at least `noise_floor` (the file's own, or 0).

    p.robust_noise: the noise is the robust white sigma, inflated for the correlation of neighbouring
    samples (the noise an echo-wide feature sees), and the background the robust baseline;
    otherwise the method's residual formula and the smoothed minimum."""
    _smooth(samples, valid, smoothing_sigma, smoothed)
    if p.robust_noise:
        attenuation = np.empty(samples.size)
        _residual_attenuation(valid, smoothing_sigma, attenuation)
        noise = max(_robust_noise_sigma(samples, smoothed, valid, attenuation), p.min_noise_sigma)
        background = _baseline(samples, valid, noise)
        noise *= math.sqrt(_correlation_inflation(samples, smoothed, valid, background, noise))
    else:
        noise = max(residual_noise_sigma(samples, smoothed, valid), p.min_noise_sigma)
        background = valid_min(smoothed, valid)
    noise = max(noise, noise_floor)
    threshold = np.empty(samples.size)
    support = np.empty(samples.size, dtype=np.bool_)
    _smoothing_support(valid, smoothing_sigma, support)
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


def as_waveform(samples, valid) -> tuple[np.ndarray, np.ndarray]:
    samples = np.ascontiguousarray(samples, dtype=np.float64)
    valid = np.ones(samples.size, bool) if valid is None else np.ascontiguousarray(valid, dtype=bool)
    if valid.shape != samples.shape:
        raise ValueError(f"valid mask has shape {valid.shape}, samples {samples.shape}")
    if not np.isfinite(samples[valid]).all():
        raise ValueError("waveform has non-finite samples")
    return samples, valid


def gaussian_smooth(samples, sigma: float, valid=None) -> np.ndarray:
    """Denoise with a Gaussian filter of `sigma` samples (0: no smoothing), ignoring invalid samples."""
    samples, valid = as_waveform(samples, valid)
    out = np.empty_like(samples)
    _smooth(samples, valid, float(sigma), out)
    return out


def estimate_noise(samples, smoothing_sigma: float, valid=None, robust: bool = True) -> float:
    """sigma_noise of a waveform smoothed with `smoothing_sigma` samples: robust (median absolute
    residual over its white-noise attenuation) or the method's sqrt(mean((raw - smoothed)**2))."""
    samples, valid = as_waveform(samples, valid)
    smoothed = np.empty_like(samples)
    _smooth(samples, valid, float(smoothing_sigma), smoothed)
    if not robust:
        return float(residual_noise_sigma(samples, smoothed, valid))
    attenuation = np.empty_like(samples)
    _residual_attenuation(valid, float(smoothing_sigma), attenuation)
    return float(_robust_noise_sigma(samples, smoothed, valid, attenuation))


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


def smoothed_noise_baseline(samples: np.ndarray, valid: np.ndarray, smoothing_sigma: float):
    """(smoothed waveform, robust white-noise sigma floored at the quantisation's, robust baseline)."""
    smoothed = np.empty_like(samples)
    _smooth(samples, valid, float(smoothing_sigma), smoothed)
    attenuation = np.empty_like(samples)
    _residual_attenuation(valid, float(smoothing_sigma), attenuation)
    noise = max(float(_robust_noise_sigma(samples, smoothed, valid, attenuation)), 1.0 / math.sqrt(12.0))
    return smoothed, noise, float(_baseline(samples, valid, noise))


def noise_and_background(samples, valid=None, smoothing_sigma: float = 1.0) -> tuple[float, float]:
    """A waveform's robust white-noise sigma (floored at the quantisation's) and its robust baseline."""
    _, noise, background = smoothed_noise_baseline(*as_waveform(samples, valid), smoothing_sigma)
    return noise, background
