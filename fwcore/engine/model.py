"""The echo model the kernels evaluate: generalized Gaussians, or a tabulated system response, on a constant
background; their Python references, widths and energies.

    y(t) = b + sum_k A_k * exp(-|t - u_k|**(alpha_k**2) / (2 * sigma_k**2))

This is the form of Chauve et al. (2008): the absolute value and the squared
shape factor make alpha = sqrt(2) an ordinary Gaussian (the MDE paper prints the
exponent as (x - u)**alpha, for which that does not hold). Larger alpha gives
flatter tops, smaller alpha sharper peaks with heavier tails.

Units: t and u in samples (ps at the pipeline's boundary); sigma in
time**(alpha**2 / 2), so that the exponent is dimensionless.

Inside the optimizer an echo's width is carried as `s`, the sigma of the
ordinary Gaussian with the same FWHM: s and alpha then vary independently,
whereas Chauve's sigma spans orders of magnitude as alpha moves at a fixed
width. The functions below convert between the two.

Under the `system` model an echo is instead a row of an `EchoShape`: the
instrument's response broadened to the echo's width, tabulated
(fwcore.instrument.shape builds it); the kernels evaluate either form here.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE, exp_ieee, log_ieee, searchsorted

GAUSSIAN_ALPHA = math.sqrt(2.0)
LN2 = math.log(2.0)
SQRT_2LN2 = math.sqrt(2.0 * LN2)  # half width at half maximum of a unit-sigma Gaussian
# The layout of an individual: [b, (A, u, s, alpha) per echo], s the equal-FWHM Gaussian sigma.
PARAMS_PER_ECHO = 4
# exp(-x) is exactly 0 in float64 for x above 745.14: past this exponent an echo's term adds nothing, to the bit
UNDERFLOW = 746.0


class EchoShape(NamedTuple):
    """An echo model as the kernels see it. tabulated False: the generalized Gaussian (its parameters
    alone define it; the arrays are empty). True: rows[w] is the response broadened to the w-th width,
    peak 1, at times (j - origin) * step samples; slopes its time derivative per sample."""

    tabulated: bool
    rows: np.ndarray  # (widths, grid) float64
    slopes: np.ndarray  # (widths, grid) float64, d row / dt per sample
    areas: np.ndarray  # (widths,) integral of each row, samples
    support: np.ndarray  # (widths, 2) int64: grid indices [first, last] above fwcore.instrument.shape.SUPPORT_LEVEL
    peak_offsets: np.ndarray  # (widths,) where each row peaks, samples after the echo's position (its lobe's centroid)
    half_widths: np.ndarray  # (2,) row 0 from its peak to half height before and after it, samples
    step: float  # samples per grid point
    origin: float  # grid index of t = 0, the echo's position (the centroid of the response's main lobe)
    s_min: float  # the equal-FWHM Gaussian sigma (samples) of row 0: the response's own
    s_step: float  # between rows
    # the generalized Gaussian's tails: 0, an echo is evaluated where it is above 1e-12 of its amplitude; > 0 (long
    # records, fwcore.engine.decompose.TAIL_FLOOR), where it is above this many counts too (at least 1e-3 of it)
    tail_floor: float = 0.0


def analytic_shape() -> EchoShape:
    """The generalized Gaussian's (and the Gaussian's) EchoShape: no table."""
    empty = np.zeros((1, 2))
    return EchoShape(False, empty, empty, np.zeros(1), np.zeros((1, 2), dtype=np.int64), np.zeros(1), np.ones(2), 1.0,
                     0.0, 0.0, 1.0, 0.0)


@njit(**JIT_INLINE)
def echo_value(amplitude, position, s, alpha, t):
    """One echo of an individual at time t, float64 and libm: A exp(-ln2 (|t - u| / h)**(alpha**2)),
    h = s sqrt(2 ln 2) the half width at half maximum. The kernels' one formula."""
    return amplitude * math.exp(-LN2 * (abs(t - position) / (s * SQRT_2LN2)) ** (alpha * alpha))


@njit(**JIT_INLINE)
def add_echo_vectorized(amplitude, position, s, alpha, times, lo, hi, out):
    """echo_value's echo added into out[lo:hi] with fwcore._jit's branch-free exp and log, so the loop vectorizes:
    long records' (a tail floor) model. Each term within a few ulp of echo_value's, exactly the amplitude at the
    centre, 0 (not a subnormal) where it is below float64's normal range. Finite position, s and alpha."""
    inv_h = 1.0 / (s * SQRT_2LN2)
    p = alpha * alpha
    # unsigned indices: numba wraps a signed one that may be negative, a select per access that blocks SIMD
    for i in range(np.uint64(lo), np.uint64(hi)):
        z = abs(times[i] - position) * inv_h
        centre = z == 0.0
        e = exp_ieee(-LN2 * exp_ieee(p * log_ieee(1.0 if centre else z)))  # z = 1 at the centre: finite, masked
        out[i] += amplitude * (1.0 if centre else e)


# A tabulated echo's rows and grid are read once per echo, not per sample: inside a sample loop, every read
# of an array field of the shape tuple costs numba a reference count (an atomic) and blocks hoisting.
@njit(**JIT_INLINE)
def table_row(shape, s):
    """Where width s falls between the table's rows: (row, weight of the next row)."""
    fw = min(max((s - shape.s_min) / shape.s_step, 0.0), shape.rows.shape[0] - 1 - 1e-9)
    w = int(fw)
    return w, fw - w


@njit(**JIT_INLINE)
def grid_column(d, step, origin, columns):
    """Where time offset d (samples) falls on a table's grid of `columns` points: (column, weight of the
    next), column -1 outside the grid."""
    fg = d / step + origin
    if fg < 0.0 or fg >= columns - 1:
        return -1, 0.0
    j = int(fg)
    return j, fg - j


@njit(**JIT_INLINE)
def bilinear(table, w, a, j, b):
    """table between rows w, w + 1 (weight a) and columns j, j + 1 (weight b)."""
    return ((1.0 - a) * ((1.0 - b) * table[w, j] + b * table[w, j + 1])
            + a * ((1.0 - b) * table[w + 1, j] + b * table[w + 1, j + 1]))


@njit(**JIT_INLINE)
def table_value(shape, amplitude, position, s, t):
    """One echo of the system response's shape (EchoShape) at time t: A row(s)(t - u)."""
    w, a = table_row(shape, s)
    j, b = grid_column(t - position, shape.step, shape.origin, shape.rows.shape[1])
    if j < 0:
        return 0.0
    return amplitude * bilinear(shape.rows, w, a, j, b)


@njit(**JIT_INLINE)
def add_table_echo(shape, amplitude, position, s, times, lo, hi, out):
    """out[i] += the tabulated echo at times[i], for i in [lo, hi)."""
    w, a = table_row(shape, s)
    rows = shape.rows
    step, origin, columns = shape.step, shape.origin, rows.shape[1]
    for i in range(lo, hi):
        j, b = grid_column(times[i] - position, step, origin, columns)
        if j >= 0:
            out[i] += amplitude * bilinear(rows, w, a, j, b)


@njit(**JIT_INLINE)
def add_table_echo_derivatives(shape, amplitude, position, s, times, lo, hi, model, jac, base):
    """model[i] += the tabulated echo at times[i], and its Jacobian columns base (by A), base + 1 (by u:
    -A slope) and base + 2 (by s: across the rows, 0 outside the table's widths), for i in [lo, hi)."""
    w, a = table_row(shape, s)
    rows, slopes = shape.rows, shape.slopes
    step, origin, columns = shape.step, shape.origin, rows.shape[1]
    inside = shape.s_min <= s <= shape.s_min + shape.s_step * (rows.shape[0] - 1)
    s_step = shape.s_step
    for i in range(lo, hi):
        j, b = grid_column(times[i] - position, step, origin, columns)
        value, slope, by_width = 0.0, 0.0, 0.0
        if j >= 0:
            below = (1.0 - b) * rows[w, j] + b * rows[w, j + 1]  # row w at the offset, and row w + 1
            above = (1.0 - b) * rows[w + 1, j] + b * rows[w + 1, j + 1]
            value = (1.0 - a) * below + a * above  # bilinear's own sum, from the two it already holds
            slope = bilinear(slopes, w, a, j, b)
            by_width = (above - below) / s_step if inside else 0.0
        model[i] += amplitude * value
        jac[i, base] = value
        jac[i, base + 1] = -amplitude * slope
        jac[i, base + 2] = amplitude * by_width


@njit(**JIT_INLINE)
def table_reach(shape, s):
    """A tabulated echo of width s: its support, (before, after) its position, in samples (of the two rows
    it is interpolated between)."""
    w, _ = table_row(shape, s)
    first = min(shape.support[w, 0], shape.support[w + 1, 0])
    last = max(shape.support[w, 1], shape.support[w + 1, 1])
    # interpolation reaches one grid step past a row's last non-zero value
    return (shape.origin - first + 1.0) * shape.step, (last + 1.0 - shape.origin) * shape.step


@njit(**JIT_INLINE)
def table_peak_offset(shape, s):
    """Where an echo of width s peaks, in samples after its position: 0 for the analytic models; for a
    tabulated response, its main lobe's centroid is the position and a skewed response peaks before or after."""
    if not shape.tabulated:
        return 0.0
    fw = min(max((s - shape.s_min) / shape.s_step, 0.0), shape.peak_offsets.size - 1 - 1e-9)
    w = int(fw)
    return (1.0 - (fw - w)) * shape.peak_offsets[w] + (fw - w) * shape.peak_offsets[w + 1]


@njit(**JIT_INLINE)
def underflow_reach(h, p):
    """|t - u| beyond which a generalized Gaussian echo of half width h and exponent p = alpha**2 is exactly 0 in
    float64 (echo_value's exp underflows); inf where that is not finite (every sample, as without a reach)."""
    reach = h * (UNDERFLOW / LN2) ** (1.0 / p)
    return reach if reach < math.inf else math.inf


@njit(**JIT_INLINE)
def sample_span(u, reach, size):
    """The sample indices [lo, hi) of 0..size-1 within reach of u."""
    if not abs(u) + reach < 1e15:  # also NaN: every sample
        return 0, size
    return max(0, int(math.ceil(u - reach))), min(size, int(math.floor(u + reach)) + 1)


@njit(**JIT_INLINE)
def echo_positions_of(x, n_echoes):
    """The positions u of individual x's echoes, in its order, as an array of their own."""
    return x[2:1 + PARAMS_PER_ECHO * n_echoes:PARAMS_PER_ECHO].copy()


@njit(**JIT)
def individual_model(x, n_echoes, times, shape, out):
    """The model of individual x at `times` (float64, ascending) into `out`: a generalized Gaussian over the
    samples where it does not underflow, a tabulated echo over its table's support (each is exactly 0 elsewhere)."""
    for i in range(times.size):
        out[i] = x[0]
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        if x[base] <= 0.0:
            continue
        if shape.tabulated:
            before, after = table_reach(shape, x[base + 2])
            add_table_echo(shape, x[base], x[base + 1], x[base + 2], times,
                           searchsorted(times, x[base + 1] - before),
                           searchsorted(times, x[base + 1] + after, right=True), out)
            continue
        lo, hi = 0, times.size
        reach = underflow_reach(x[base + 2] * SQRT_2LN2, x[base + 3] * x[base + 3])
        if abs(x[base + 1]) + reach < 1e15:  # not NaN: NaN's searchsorted would skip what it adds everywhere
            lo, hi = searchsorted(times, x[base + 1] - reach), searchsorted(times, x[base + 1] + reach, right=True)
            if shape.tail_floor > 0.0:  # long records: the vectorizable exp and log (short ones keep libm's bits)
                add_echo_vectorized(x[base], x[base + 1], x[base + 2], x[base + 3], times, lo, hi, out)
                continue
        for i in range(lo, hi):
            out[i] += echo_value(x[base], x[base + 1], x[base + 2], x[base + 3], times[i])


@njit(**JIT)
def batch_model(rows, sample_offsets, echo_offsets, background, amplitude, position, sigma, alpha, shape, out):
    """The fitted model of each waveform `rows` at its sample times 0, 1, ... into out (flat like the samples):
    the background plus Chauve's generalized Gaussians (sigma, alpha), or, for a tabulated shape, the system
    response's echoes (sigma the equal-FWHM Gaussian sigma), in each waveform's echo order. Each echo is
    evaluated where it is not exactly 0 (echo_span): the same values as over every sample."""
    for i in rows:
        lo, hi = sample_offsets[i], sample_offsets[i + 1]
        times = np.arange(hi - lo).astype(np.float64)
        model = out[lo:hi]
        model[:] = background[i]
        for e in range(echo_offsets[i], echo_offsets[i + 1]):
            first, stop = echo_span(shape, position[e], sigma[e], alpha[e], times.size)
            if shape.tabulated:
                add_table_echo(shape, amplitude[e], position[e], sigma[e], times, first, stop, model)
                continue
            power, scale = alpha[e] * alpha[e], 2.0 * sigma[e] * sigma[e]
            for k in range(first, stop):
                model[k] += amplitude[e] * math.exp(-abs(times[k] - position[e]) ** power / scale)


@njit(**JIT_INLINE)
def echo_span(shape, position, sigma, alpha, size):
    """The samples [lo, hi) of 0..size-1 where an echo of batch_model's (Chauve's sigma and alpha, or a tabulated
    echo's width) may be non-zero: outside, exp underflows to 0, or the table's grid (not its support) ends."""
    if shape.tabulated:  # grid_column's -1: before the grid's first point or at its last
        before, after = shape.origin * shape.step, (shape.rows.shape[1] - 1 - shape.origin) * shape.step
        return sample_span(position + 0.5 * (after - before), 0.5 * (after + before) + 1.0, size)
    power = alpha * alpha
    reach = (UNDERFLOW * 2.0 * sigma * sigma) ** (1.0 / power)  # |t - u|**power / (2 sigma**2) = UNDERFLOW
    return sample_span(position, reach if reach < math.inf else math.inf, size)


def model_of_individual(x, t) -> np.ndarray:
    """The NumPy twin of individual_model: [b, (A, u, s, alpha)...] -> model at t, through Chauve's sigma."""
    x = np.asarray(x, dtype=float)
    echoes = x[1:].reshape(-1, PARAMS_PER_ECHO)
    return waveform_model(t, x[0], echoes[:, 0], echoes[:, 1],
                          sigma_from_equivalent(echoes[:, 2], echoes[:, 3]), echoes[:, 3])

_gamma = np.vectorize(math.gamma, otypes=[float])


def generalized_gaussian(t, amplitude, position, sigma, alpha):
    """One echo, Chauve's form, in float64 (the reference every kernel is tested against)."""
    t = np.asarray(t, dtype=float)
    return amplitude * np.exp(-np.abs(t - position) ** (alpha * alpha) / (2.0 * sigma * sigma))


def waveform_model(t, background, amplitude, position, sigma, alpha) -> np.ndarray:
    """Background plus the sum of echoes, evaluated at times t (float64 reference)."""
    t = np.asarray(t, dtype=float)
    y = np.full(t.shape, float(background))
    for a, u, s, al in zip(np.atleast_1d(amplitude), np.atleast_1d(position),
                           np.atleast_1d(sigma), np.atleast_1d(alpha)):
        y += generalized_gaussian(t, a, u, s, al)
    return y


def tabulated_row(shape, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tabulated echo of width s on its table's grid (samples from its position): (times, values, slopes),
    interpolated between the table's rows."""
    fw = min(max((s - shape.s_min) / shape.s_step, 0.0), shape.rows.shape[0] - 1 - 1e-9)
    w, a = int(fw), fw - int(fw)
    grid = (np.arange(shape.rows.shape[1]) - shape.origin) * shape.step
    return (grid, (1.0 - a) * shape.rows[w] + a * shape.rows[w + 1],
            (1.0 - a) * shape.slopes[w] + a * shape.slopes[w + 1])


def tabulated_model(t, background, amplitude, position, s, shape) -> np.ndarray:
    """The NumPy twin of individual_model for echoes of a tabulated response (EchoShape):
    background plus A row(s)(t - u), interpolated between rows and grid points."""
    t = np.asarray(t, dtype=float)
    y = np.full(t.shape, float(background))
    for a, u, width in zip(np.atleast_1d(amplitude), np.atleast_1d(position), np.atleast_1d(s)):
        grid, row, _ = tabulated_row(shape, width)
        y += a * np.interp(t - u, grid, row, left=0.0, right=0.0)
    return y


def tabulated_areas(shape, s) -> np.ndarray:
    """The NumPy twin of tabulated_area, over an array of widths s."""
    widths = shape.s_min + shape.s_step * np.arange(shape.areas.size)
    return np.interp(np.asarray(s, dtype=float), widths, shape.areas)


@njit(**JIT)
def tabulated_area(shape, s):
    """The area (samples) under a unit-amplitude tabulated echo of width s."""
    fw = min(max((s - shape.s_min) / shape.s_step, 0.0), shape.areas.size - 1 - 1e-9)
    w = int(fw)
    return (1.0 - (fw - w)) * shape.areas[w] + (fw - w) * shape.areas[w + 1]


def half_width(sigma, alpha):
    """Half width at half maximum: |t - u| where the echo falls to A / 2."""
    p = np.asarray(alpha, dtype=float) ** 2
    return (2.0 * np.asarray(sigma, dtype=float) ** 2 * LN2) ** (1.0 / p)


def fwhm(sigma, alpha):
    """Full width at half maximum of a generalized Gaussian echo."""
    return 2.0 * half_width(sigma, alpha)


def sigma_from_half_width(h, alpha):
    """Chauve's sigma of the echo whose half width at half maximum is h."""
    p = np.asarray(alpha, dtype=float) ** 2
    return np.sqrt(np.asarray(h, dtype=float) ** p / (2.0 * LN2))


def equivalent_gaussian_sigma(sigma, alpha):
    """The sigma of the ordinary Gaussian with the same FWHM (the optimizer's width `s`)."""
    return half_width(sigma, alpha) / SQRT_2LN2


def sigma_from_equivalent(s, alpha):
    """Chauve's sigma from the equal-FWHM Gaussian sigma s."""
    return sigma_from_half_width(np.asarray(s, dtype=float) * SQRT_2LN2, alpha)


def echo_energy(amplitude, sigma, alpha):
    """Area under the echo: 2 A Gamma(1 + 1/p) (2 sigma**2)**(1/p), p = alpha**2.

    For alpha = sqrt(2) this is the Gaussian's A * sigma * sqrt(2 pi).
    """
    p = np.asarray(alpha, dtype=float) ** 2
    return 2.0 * np.asarray(amplitude, dtype=float) * _gamma(1.0 + 1.0 / p) * (
        2.0 * np.asarray(sigma, dtype=float) ** 2) ** (1.0 / p)


def sigma_to_time_unit(sigma, alpha, spacing):
    """Chauve's sigma measured in samples -> the same echo's sigma with t in units where a sample is `spacing`.

    |t|**p / (2 sigma**2) is invariant when t scales by c and sigma by c**(p/2).
    """
    p = np.asarray(alpha, dtype=float) ** 2
    return np.asarray(sigma, dtype=float) * np.asarray(spacing, dtype=float) ** (p / 2.0)
