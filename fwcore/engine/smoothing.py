"""Denoising, noise and baseline: a waveform's Gaussian filter, its white-noise sigma and its background (the
method's section 1.2, before any echo).

Positions and widths here are in samples; sample i lies at time i. A waveform
is its samples plus a validity mask: a recorded waveform may have gaps (NEON
pads with zeros between segments) and every valid sample keeps its own time.

    denoise(...)                   the kernel: smoothed samples, noise sigma and background in one call
    gaussian_smooth, estimate_noise, noise_and_background, smoothed_noise_baseline   the same from Python
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE


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
    counted = m  # the level is the median of the `counted` smallest
    for _ in range(8):
        threshold = level + 3.0 * noise
        k = m  # a NaN threshold counts every sample, as np.searchsorted sorts NaN last
        if not np.isnan(threshold):
            k = 0
            for i in range(m):
                k += values[i] <= threshold
        if k == counted:  # the same samples: their median is the level (a selection less a waveform)
            break
        counted = k
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
def valid_min(values, valid):
    best = np.inf
    for i in range(values.size):
        if valid[i] and values[i] < best:
            best = values[i]
    return best


@njit(**JIT)
def smoothing_support(valid, sigma, out):
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
def denoise(samples, valid, smoothing_sigma, robust, min_noise_sigma, smoothed):
    """Denoise into `smoothed` and measure the noise and background: (noise sigma, background).

    robust: the noise is the robust white sigma (at least min_noise_sigma), inflated for the correlation of
    neighbouring samples (the noise an echo-wide feature sees), and the background the robust baseline;
    otherwise the method's residual formula and the smoothed minimum."""
    _smooth(samples, valid, smoothing_sigma, smoothed)
    if robust:
        attenuation = np.empty(samples.size)
        _residual_attenuation(valid, smoothing_sigma, attenuation)
        noise = max(_robust_noise_sigma(samples, smoothed, valid, attenuation), min_noise_sigma)
        background = _baseline(samples, valid, noise)
        noise *= math.sqrt(_correlation_inflation(samples, smoothed, valid, background, noise))
    else:
        noise = max(residual_noise_sigma(samples, smoothed, valid), min_noise_sigma)
        background = valid_min(smoothed, valid)
    return noise, background


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
