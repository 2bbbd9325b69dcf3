"""Deconvolution methods of the catalogue: Gold and Richardson-Lucy with the system response, then echoes.

The waveform above its background is the targets' cross-section profile
convolved with the system response (waveformlidar, gediMetric). Both methods
recover that profile by multiplicative, non-negative iterations, with h the
response sampled on the digitizer's grid and normalised to unit area:

    Richardson-Lucy:  x <- x * (h~ * (y / (h * x)))
    Gold:             x <- x * (h~ * y) / (h~ * h * x)

(h~ the response reversed). An echo is then each peak of the recovered profile
that holds more than the noise threshold: at the centroid of its lobe, with the
lobe's mass as its energy and the response's own width broadened by the lobe's
spread (its amplitude the peak of that echo of that energy). A linear least-squares
pass then sets the amplitudes and background on the raw samples, the echoes' times
and widths held: lobes of a deconvolved profile overlap, so their masses alone
overstate the echoes. The echoes come out as an individual of the engine, so the metrics and
the filter treat them like any optimizer's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.model import GAUSSIAN_ALPHA, PARAMS_PER_ECHO, table_reach, table_value, tabulated_area
from fwcore.engine.optimizers.local import levenberg_marquardt

_FLOOR = 1e-12  # keeps the multiplicative updates off zero divisions


@njit(**JIT)
def response_kernel(shape, pulse_sigma):
    """The response on the sample grid, unit area, and the index of its time 0: the tabulated shape's
    narrowest row, or a Gaussian of pulse_sigma samples."""
    if shape.tabulated:
        before, after = table_reach(shape, shape.s_min)
        lo = -int(math.floor(before))
        hi = int(math.floor(after))
        kernel = np.empty(hi - lo + 1)
        for j in range(lo, hi + 1):
            kernel[j - lo] = max(table_value(shape, 1.0, 0.0, shape.s_min, float(j)), 0.0)
        centre = -lo
    else:
        half = int(math.ceil(4.0 * pulse_sigma))
        kernel = np.empty(2 * half + 1)
        for j in range(-half, half + 1):
            kernel[j + half] = math.exp(-0.5 * (j / pulse_sigma) ** 2)
        centre = half
    total = kernel.sum()
    for j in range(kernel.size):
        kernel[j] /= total
    return kernel, centre


@njit(**JIT)
def _shift_sum(x, kernel, centre, sign, out):
    """out[i] = sum_j kernel[j] x[i - sign (j - centre)] over the samples x has: sign 1 places the response
    at each sample of x (the convolution), sign -1 is its adjoint (the correlation)."""
    n = x.size
    for i in range(n):
        # the j whose sample i - sign (j - centre) lies in [0, n)
        if sign > 0:
            lo, hi = max(0, i + centre - n + 1), min(kernel.size, i + centre + 1)
        else:
            lo, hi = max(0, centre - i), min(kernel.size, n - i + centre)
        acc = 0.0
        for j in range(lo, hi):
            acc += kernel[j] * x[i - sign * (j - centre)]
        out[i] = acc


@njit(**JIT)
def _convolve(x, kernel, centre, out):
    _shift_sum(x, kernel, centre, 1, out)


@njit(**JIT)
def _correlate(x, kernel, centre, out):
    _shift_sum(x, kernel, centre, -1, out)


@njit(**JIT)
def richardson_lucy(signal, kernel, centre, iterations):
    """The non-negative profile whose convolution with the kernel best explains `signal` (Poisson likelihood)."""
    n = signal.size
    x = np.full(n, max(signal.mean(), _FLOOR))
    blurred = np.empty(n)
    ratio = np.empty(n)
    update = np.empty(n)
    for _ in range(iterations):
        _convolve(x, kernel, centre, blurred)
        for i in range(n):
            ratio[i] = signal[i] / max(blurred[i], _FLOOR)
        _correlate(ratio, kernel, centre, update)
        for i in range(n):
            x[i] *= update[i]
    return x


@njit(**JIT)
def gold(signal, kernel, centre, iterations):
    """Gold's ratio method: the non-negative least-squares profile by multiplicative updates."""
    n = signal.size
    x = np.full(n, max(signal.mean(), _FLOOR))
    numerator = np.empty(n)
    _correlate(signal, kernel, centre, numerator)
    blurred = np.empty(n)
    denominator = np.empty(n)
    for _ in range(iterations):
        _convolve(x, kernel, centre, blurred)
        _correlate(blurred, kernel, centre, denominator)
        for i in range(n):
            x[i] *= numerator[i] / max(denominator[i], _FLOOR)
    return x


@njit(**JIT)
def _unit_echo_area(shape, s):
    """The area (samples) under an echo of peak 1 and equal-FWHM sigma s: a row of the table, or a Gaussian."""
    return tabulated_area(shape, s) if shape.tabulated else s * math.sqrt(2.0 * math.pi)


@njit(**JIT)
def deconvolution_echoes(samples, valid, background, noise, noise_threshold, max_echoes, first, last, shape,
                         pulse_sigma, gold_method, iterations):
    """Echoes from the deconvolved waveform: [b, (A, u, s, alpha)...] and their count. Each lobe of the
    recovered profile (between its minima) whose mass x the response's peak rises above noise_threshold x
    noise becomes an echo at the lobe's centroid; the strongest max_echoes are kept."""
    n = samples.size
    signal = np.zeros(n)
    for i in range(first, last + 1):
        if valid[i]:
            signal[i] = max(samples[i] - background, 0.0)
    kernel, centre = response_kernel(shape, pulse_sigma)
    profile = gold(signal, kernel, centre, iterations) if gold_method else richardson_lucy(
        signal, kernel, centre, iterations)
    s_min = shape.s_min if shape.tabulated else pulse_sigma
    masses = np.zeros(n)
    centres = np.zeros(n)
    spreads = np.zeros(n)
    count = 0
    i = 0
    start = 0  # a lobe begins after the previous one ends: the minimum between two belongs to one
    while i < n:
        if profile[i] <= 0.0 or (i > 0 and profile[i - 1] > profile[i]) or (i + 1 < n and profile[i + 1] > profile[i]):
            i += 1
            continue
        lo = i  # a local maximum: its lobe runs down to the minima either side
        while lo > start and profile[lo - 1] <= profile[lo] and profile[lo - 1] > 0.0:
            lo -= 1
        hi = i
        while hi < n - 1 and profile[hi + 1] <= profile[hi] and profile[hi + 1] > 0.0:
            hi += 1
        mass = 0.0
        moment = 0.0
        for k in range(lo, hi + 1):
            mass += profile[k]
            moment += profile[k] * k
        if mass * kernel.max() > noise_threshold * noise:
            mean = moment / mass
            var = 0.0
            for k in range(lo, hi + 1):
                var += profile[k] * (k - mean) ** 2
            masses[count] = mass
            centres[count] = mean
            spreads[count] = var / mass
            count += 1
        i = hi + 1
        start = i
    order = np.argsort(-masses[:count])
    n_echoes = min(count, max_echoes)
    x = np.empty(1 + PARAMS_PER_ECHO * n_echoes)
    x[0] = background
    widest = shape.s_min + shape.s_step * (shape.rows.shape[0] - 1) if shape.tabulated else 3.0 * pulse_sigma
    for j in range(n_echoes):
        k = order[j]
        base = 1 + PARAMS_PER_ECHO * j
        s = min(math.sqrt(s_min * s_min + spreads[k]), widest)
        x[base] = masses[k] / _unit_echo_area(shape, s)
        x[base + 1] = centres[k]
        x[base + 2] = s
        x[base + 3] = GAUSSIAN_ALPHA
    return x, n_echoes


@njit(**JIT)
def fit_amplitudes(x, n_echoes, times, shape, raw, weights, lm_iterations, lm_tolerance):
    """The amplitudes and background of x by least squares on the raw samples, times and widths held;
    returns the Jacobians evaluated."""
    lower = x.copy()
    upper = x.copy()
    lower[0], upper[0] = -np.inf, np.inf
    for k in range(n_echoes):
        lower[1 + PARAMS_PER_ECHO * k] = 0.0
        upper[1 + PARAMS_PER_ECHO * k] = np.inf
    _, used, _ = levenberg_marquardt(x, n_echoes, times, shape, raw, weights, lower, upper, lm_iterations,
                                     lm_tolerance)
    return used
