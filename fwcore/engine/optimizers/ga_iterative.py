"""ga-iterative: the patented GA decomposition that adds echoes until the fit is good enough.

Gaussian echoes; the patent's peak search (a sample is a peak when it is the
largest within +-5 bins and above threshold) gives each echo its search
ranges: u in [peak - 5, peak + 5], A in [0, peak height], sigma up to
3 (p2 - p1) / 2 from the inflection points (3 |p - peak| with one, a triangle
estimate from the half-height width with none). A binary-coded GA fits them:
16 bits per parameter, linear ranking, stochastic universal sampling,
single-point crossover with probability 0.7, mutation with probability 0.15
per individual (each of its bits flips with probability 1 / length, at least
one), the best individual kept, population 60, up to 1000 generations (and we
stop after 100 without improvement: the patent is silent, and later
generations only repeat the best). While R^2 (raw samples) is below the
threshold, one echo is added with A in [0, largest amplitude], u in a 20-bin
range centred on the largest residual and sigma in the widest range of the
first fit, and the GA runs again, seeded with the previous best; the added
echo is dropped again, and the search stops, when it does not raise R^2.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.estimate import MIN_SIGMA, half_height_sigma, inflection_distance
from fwcore.engine.smoothing import as_waveform, gaussian_smooth, residual_noise_sigma, valid_min
from fwcore.rng import randint, uniform

PEAK_WINDOW = 5  # bins either side
ADDED_ECHO_RANGE = 10  # bins either side of the largest residual
CROSSOVER_PROBABILITY = 0.7
MUTATION_PROBABILITY = 0.15
BITS = 16
STALL_GENERATIONS = 100
_SQRT2 = math.sqrt(2.0)
_LEVELS = float((1 << BITS) - 1)


@njit(**JIT)
def patent_peaks(smoothed, valid, background, threshold, max_echoes, first, last, ranges):
    """The patent's peaks and search ranges, ranges[k] = (A_lo, A_hi, u_lo, u_hi, s_lo, s_hi, peak).
    Returns the count."""
    n = smoothed.size
    residual = smoothed - background
    count = 0
    i = 0
    while i < n and count < max_echoes:
        if valid[i] and residual[i] > threshold:
            is_peak = True
            for j in range(max(0, i - PEAK_WINDOW), min(n, i + PEAK_WINDOW + 1)):
                # strictly larger before, not smaller after: a flat top gives its first sample
                if valid[j] and (residual[j] > residual[i] or (j < i and residual[j] == residual[i])):
                    is_peak = False
                    break
            if is_peak:
                left = inflection_distance(residual, valid, i, -1)
                right = inflection_distance(residual, valid, i, 1)
                if left > 0.0 and right > 0.0:
                    sigma_hi = 3.0 * (left + right) / 2.0
                elif left > 0.0 or right > 0.0:
                    sigma_hi = 3.0 * max(left, right)
                else:
                    sigma_hi = 3.0 * max(half_height_sigma(residual, valid, i), MIN_SIGMA)
                ranges[count, 0] = 0.0
                ranges[count, 1] = residual[i]
                ranges[count, 2] = max(first, i - PEAK_WINDOW)
                ranges[count, 3] = min(last, i + PEAK_WINDOW)
                ranges[count, 4] = MIN_SIGMA
                ranges[count, 5] = max(sigma_hi, MIN_SIGMA)
                ranges[count, 6] = i
                count += 1
        i += 1
    return count


@njit(**JIT)
def _gaussian_ssr(x, n_echoes, times, target):
    """Sum of squared residuals of [b, (A, u, s) per echo] (Gaussian echoes) at times."""
    ssr = 0.0
    for i in range(times.size):
        v = x[0]
        for k in range(n_echoes):
            z = (times[i] - x[2 + 3 * k]) / x[3 + 3 * k]
            v += x[1 + 3 * k] * math.exp(-0.5 * z * z)
        ssr += (v - target[i]) ** 2
    return ssr


@njit(**JIT)
def _decode(bits, lower, upper, x):
    for j in range(x.size):
        value = 0
        for q in range(BITS):
            value = (value << 1) | bits[j * BITS + q]
        x[j] = lower[j] + (upper[j] - lower[j]) * value / _LEVELS


@njit(**JIT)
def _encode(x, lower, upper, bits):
    for j in range(x.size):
        span = upper[j] - lower[j]
        frac = (x[j] - lower[j]) / span if span > 0.0 else 0.0
        value = int(round(min(max(frac, 0.0), 1.0) * _LEVELS))
        for q in range(BITS):
            bits[j * BITS + q] = (value >> (BITS - 1 - q)) & 1


@njit(**JIT)
def binary_ga(lower, upper, start, n_echoes, times, target, population, generations, state):
    """Minimise the SSR of Gaussian echoes inside [lower, upper] with the patent's binary GA.
    Individual 0 starts at `start`. Returns (best individual, its SSR, evaluations)."""
    d = lower.size
    length = d * BITS
    pop = np.empty((population, length), dtype=np.uint8)
    for i in range(population):
        for q in range(length):
            pop[i, q] = np.uint8(randint(state, 2))
    _encode(start, lower, upper, pop[0])
    x = np.empty(d)
    ssr = np.empty(population)
    for i in range(population):
        _decode(pop[i], lower, upper, x)
        ssr[i] = _gaussian_ssr(x, n_echoes, times, target)
    nfev = population
    children = np.empty_like(pop)
    weights = np.empty(population)
    best = np.argmin(ssr)
    best_bits = pop[best].copy()
    best_ssr = ssr[best]
    stall = 0
    for _ in range(generations):
        # linear ranking, selective pressure 2: the best weighs 2, the worst 0
        order = np.argsort(ssr)
        for r in range(population):
            weights[order[r]] = 2.0 - 2.0 * r / (population - 1)
        # stochastic universal sampling: population pointers one mean weight apart
        total = weights.sum()
        step = total / population
        pointer = uniform(state) * step
        cumulative = weights[0]
        k = 0
        for i in range(population):
            while cumulative < pointer and k < population - 1:
                k += 1
                cumulative += weights[k]
            children[i] = pop[k]
            pointer += step
        # SUS returns parents in index order: shuffle before pairing
        for i in range(population - 1, 0, -1):
            j = randint(state, i + 1)
            tmp = children[i].copy()
            children[i] = children[j]
            children[j] = tmp
        for i in range(0, population - 1, 2):
            if uniform(state) < CROSSOVER_PROBABILITY:
                cut = 1 + randint(state, length - 1)
                for q in range(cut, length):
                    a = children[i, q]
                    children[i, q] = children[i + 1, q]
                    children[i + 1, q] = a
        for i in range(population):
            if uniform(state) < MUTATION_PROBABILITY:
                children[i, randint(state, length)] ^= np.uint8(1)
                for q in range(length):
                    if uniform(state) < 1.0 / length:
                        children[i, q] ^= np.uint8(1)
        children[0] = best_bits  # the best individual survives
        pop[:] = children
        for i in range(population):
            _decode(pop[i], lower, upper, x)
            ssr[i] = _gaussian_ssr(x, n_echoes, times, target)
        nfev += population
        best = np.argmin(ssr)
        if ssr[best] < best_ssr:
            best_ssr = ssr[best]
            best_bits = pop[best].copy()
            stall = 0
        else:
            stall += 1
            if stall >= STALL_GENERATIONS:
                break
    _decode(best_bits, lower, upper, x)
    return x, best_ssr, nfev


@njit(**JIT)
def _r2(x, n_echoes, times, raw):
    mean = raw.mean()
    total = 0.0
    for i in range(raw.size):
        total += (raw[i] - mean) ** 2
    return 1.0 - _gaussian_ssr(x, n_echoes, times, raw) / total if total > 0.0 else 0.0


@njit(**JIT)
def _bounds(ranges, n_echoes, background, noise):
    d = 1 + 3 * n_echoes
    lower = np.empty(d)
    upper = np.empty(d)
    lower[0] = background - 3.0 * noise
    upper[0] = background + 3.0 * noise
    for k in range(n_echoes):
        for j in range(3):
            lower[1 + 3 * k + j] = ranges[k, 2 * j]
            upper[1 + 3 * k + j] = ranges[k, 2 * j + 1]
    return lower, upper


@njit(**JIT)
def ga_iterative(valid, smoothed, background, noise, noise_threshold, max_echoes, first, last,
                 times, fit_target, raw, target_r2, population, generations, seed):
    """The patent's decomposition. Returns (individual in the engine's layout [b, (A, u, s, alpha)],
    echo count, peaks found by the search, evaluations)."""
    state = np.empty(1, dtype=np.uint64)
    state[0] = seed
    ranges = np.zeros((max_echoes, 7))
    n_echoes = patent_peaks(smoothed, valid, background, noise_threshold * noise, max_echoes, first, last,
                            ranges)
    n_peaks = n_echoes
    nfev = 0
    lower, upper = _bounds(ranges, n_echoes, background, noise)
    start = 0.5 * (lower + upper)
    start[0] = background
    for k in range(n_echoes):
        start[1 + 3 * k] = ranges[k, 1]
        start[2 + 3 * k] = 0.5 * (ranges[k, 2] + ranges[k, 3])
    best, _, used = binary_ga(lower, upper, start, n_echoes, times, fit_target, population, generations, state)
    nfev += used
    r2 = _r2(best, n_echoes, times, raw)
    widest = MIN_SIGMA
    for k in range(n_echoes):
        widest = max(widest, ranges[k, 5])
    peak = 0.0
    for i in range(fit_target.size):
        peak = max(peak, fit_target[i] - background)
    while r2 < target_r2 and 0 < n_echoes < max_echoes:
        model_residual = np.empty(times.size)
        for i in range(times.size):
            v = best[0]
            for k in range(n_echoes):
                z = (times[i] - best[2 + 3 * k]) / best[3 + 3 * k]
                v += best[1 + 3 * k] * math.exp(-0.5 * z * z)
            model_residual[i] = fit_target[i] - v
        centre = times[np.argmax(model_residual)]
        ranges[n_echoes, 0] = 0.0
        ranges[n_echoes, 1] = max(peak, 1e-9)
        ranges[n_echoes, 2] = max(first, centre - ADDED_ECHO_RANGE)
        ranges[n_echoes, 3] = min(last, centre + ADDED_ECHO_RANGE)
        ranges[n_echoes, 4] = MIN_SIGMA
        ranges[n_echoes, 5] = widest
        lower, upper = _bounds(ranges, n_echoes + 1, background, noise)
        start = np.empty(lower.size)
        start[:best.size] = best
        start[best.size] = 0.0
        start[best.size + 1] = centre
        start[best.size + 2] = 0.5 * (MIN_SIGMA + widest)
        trial, _, used = binary_ga(lower, upper, start, n_echoes + 1, times, fit_target, population,
                                   generations, state)
        nfev += used
        trial_r2 = _r2(trial, n_echoes + 1, times, raw)
        if trial_r2 <= r2:
            break
        best, r2 = trial, trial_r2
        n_echoes += 1
    out = np.empty(1 + 4 * n_echoes)
    out[0] = best[0]
    for k in range(n_echoes):
        out[1 + 4 * k] = best[1 + 3 * k]
        out[2 + 4 * k] = best[2 + 3 * k]
        out[3 + 4 * k] = best[3 + 3 * k]
        out[4 + 4 * k] = _SQRT2
    return out, n_echoes, n_peaks, nfev


# ---------------------------------------------------------------- Python API

@dataclasses.dataclass(frozen=True)
class PeakSearchRange:
    """The patent's estimate: peaks with a search range for each parameter (samples)."""

    background: float
    noise_sigma: float
    peak: np.ndarray  # sample index of each peak
    position_range: np.ndarray  # (n, 2)
    amplitude_range: np.ndarray  # (n, 2)
    sigma_range: np.ndarray  # (n, 2)


def patent_peak_ranges(samples, smoothing_sigma: float, valid=None, noise_threshold: float = 3.0,
                       max_echoes: int = 64) -> PeakSearchRange:
    """Peaks as the largest sample within +-5 bins and above noise_threshold x sigma_noise,
    each with the patent's search ranges for A, u and sigma."""
    samples, valid = as_waveform(samples, valid)
    smoothed = gaussian_smooth(samples, smoothing_sigma, valid)
    noise = float(residual_noise_sigma(samples, smoothed, valid))  # the method's formula, as the patent's peers use
    background = float(valid_min(smoothed, valid))
    ranges = np.zeros((max_echoes, 7))
    first, last = np.flatnonzero(valid)[[0, -1]]
    n = patent_peaks(smoothed, valid, background, noise_threshold * noise, max_echoes, float(first), float(last),
                     ranges)
    ranges = ranges[:n]
    return PeakSearchRange(background, noise, peak=ranges[:, 6].astype(np.int64), position_range=ranges[:, 2:4],
                           amplitude_range=ranges[:, 0:2], sigma_range=ranges[:, 4:6])
