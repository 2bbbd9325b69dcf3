"""The local optimizers: Levenberg-Marquardt and L-BFGS, on the model's analytic Jacobian.

LM is the catalogue's fast path and the engine's refiner: it polishes a
global optimizer's best individual (mde-lm) and refits the model when the
engine tries an echo count one smaller. L-BFGS is the projected, bounded
limited-memory BFGS of the method's comparison, written here in numba (not
SciPy's L-BFGS-B) so that it runs in the same parallel batch as the rest.
Both minimise the sum of squared residuals over the valid samples (the
reported fit error stays the method's Eq. 9). Bounds are kept by projecting
onto the box; parameters with lower == upper (alpha in the Gaussian model)
never move. Float64 and libm throughout: a few dozen Jacobians per waveform
do not need the SIMD tricks of the evolutionary kernels.
On long records (a generalized Gaussian with a tail floor: GEDI, LVIS) LM
builds W^1/2 J (weighted_trial) and its normal equations without a weight in
their products: the exact path's values to rounding, not its bits, which
short records (Leica, RIEGL, NEON) keep.

The individual is the engine's: [b, (A, u, s, alpha) per echo], s the
equal-FWHM Gaussian sigma, so an echo is A exp(-ln2 (|t - u| / h)**(alpha**2))
with h = s sqrt(2 ln 2). With z = |t - u| / h, p = alpha**2, e = the echo / A:
    d/dA = e,  d/du = A e ln2 p z**(p-1) sign(t - u) / h,
    d/ds = A e ln2 p z**p / s,  d/dalpha = -2 alpha A e ln2 z**p ln z.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE, exp_ieee, log_ieee, searchsorted
from fwcore._simd import CHOLESKY_LANES, block_sums, cholesky_lanes, weighted_block_sums
from fwcore.engine.model import (PARAMS_PER_ECHO, add_echo_vectorized, add_table_echo, add_table_echo_derivatives,
                                 analytic_shape, echo_value, table_reach)

_LN2 = math.log(2.0)
_SQRT_2LN2 = math.sqrt(2.0 * _LN2)
_NEGLIGIBLE = 40.0  # ln2 z**p above this: the echo is below 1e-12 of its amplitude
_LEAST_CUT = math.log(1e3)  # with a tail floor: an echo is evaluated at least where it is above 1e-3 of its amplitude


@njit(**JIT_INLINE)
def tail_cut(amplitude, tail_floor):
    """ln2 z**p beyond which a generalized Gaussian echo of `amplitude` is left out of the model and its Jacobian:
    below 1e-12 of it, and, where the shape has a tail floor (long records), below the floor (but not before
    1e-3 of it: a weak echo keeps the columns it needs to grow). Without a floor, exactly _NEGLIGIBLE."""
    if tail_floor > 0.0 and amplitude > 0.0:
        return min(_NEGLIGIBLE, max(_LEAST_CUT, math.log(amplitude / tail_floor)))
    return _NEGLIGIBLE


@njit(**JIT_INLINE)
def _echo_window(a, u, s, alpha, times, tail_floor):
    """A generalized Gaussian echo's samples [lo, hi) in the model (times ascending: above tail_cut), with its
    half width at half maximum h, its exponent p = alpha**2 and that cut, which the samples' terms share."""
    h = s * _SQRT_2LN2
    p = alpha * alpha
    cut = tail_cut(a, tail_floor)
    extent = h * (cut / _LN2) ** (1.0 / p)
    return searchsorted(times, u - extent), searchsorted(times, u + extent, right=True), h, p, cut


@njit(**JIT)
def model_and_jacobian(x, n_echoes, times, shape, model, jac, windows):
    """The model at `times` (float64, ascending) and its Jacobian (len(times) x len(x)) with respect to x;
    windows[k] = [lo, hi): the samples where echo k's columns may be non-zero. A tabulated shape
    (fwcore.engine.model.EchoShape) differentiates its table: d/du = -A slope, d/ds across its rows."""
    m = times.size
    for i in range(m):
        model[i] = x[0]
        jac[i, 0] = 1.0
        for j in range(1, jac.shape[1]):
            jac[i, j] = 0.0
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
        if shape.tabulated:
            before, after = table_reach(shape, s)
            lo = searchsorted(times, u - before)
            hi = searchsorted(times, u + after, right=True)
            windows[k, 0] = lo
            windows[k, 1] = hi
            add_table_echo_derivatives(shape, a, u, s, times, lo, hi, model, jac, base)
            continue
        # only the samples where the echo is above 1e-12 of its amplitude, and above the shape's tail floor
        lo, hi, h, p, cut = _echo_window(a, u, s, alpha, times, shape.tail_floor)
        windows[k, 0] = lo
        windows[k, 1] = hi
        for i in range(lo, hi):
            d = times[i] - u
            z = abs(d) / h
            if z == 0.0:
                model[i] += a
                jac[i, base] = 1.0
                continue
            lnz = math.log(z)
            zp = math.exp(p * lnz)
            if _LN2 * zp > cut:
                continue
            e = math.exp(-_LN2 * zp)
            ae = a * e * _LN2
            model[i] += a * e
            jac[i, base] = e
            jac[i, base + 1] = ae * p * zp / z * (1.0 if d > 0.0 else -1.0) / h
            jac[i, base + 2] = ae * p * zp / s
            jac[i, base + 3] = -2.0 * alpha * ae * zp * lnz


@njit(**JIT)
def trial_model_and_jacobian(x, n_echoes, times, shape, target, weights, bound, model, jac, windows, reach):
    """LM's trial point: model_and_jacobian's model, Jacobian and windows, and sum (weights (model - target))**2,
    built sample by sample so that it stops as soon as the partial sum reaches `bound` (the current point's: LM
    then rejects the trial whatever the rest adds). Returns the sum, or a partial one >= bound with model, jac
    and windows left part-filled. Every value it completes is model_and_jacobian's to the bit: each sample's
    model adds the echoes in the same order, from the same expressions. `reach` is (n_echoes x 3 or more) scratch.
    Only the background's column and each echo's columns inside its window are written (LM's normal equations
    read no others): the rest of `jac` keeps what it held, where model_and_jacobian writes zeros."""
    m = times.size
    if shape.tabulated:  # the system model's echoes: a table row pair each, left as they are
        model_and_jacobian(x, n_echoes, times, shape, model, jac, windows)
        ssr = 0.0
        for i in range(m):
            r = weights[i] * (model[i] - target[i])
            ssr += r * r
        return ssr
    for k in range(n_echoes):  # each echo's window and the constants its samples share
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
        windows[k, 0], windows[k, 1], h, p, cut = _echo_window(a, u, s, alpha, times, shape.tail_floor)
        reach[k, 0], reach[k, 1], reach[k, 2] = h, p, cut
    ssr = 0.0
    for i in range(m):
        value = x[0]
        jac[i, 0] = 1.0
        for k in range(n_echoes):
            if i < windows[k, 0] or i >= windows[k, 1]:
                continue
            base = 1 + PARAMS_PER_ECHO * k
            a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
            h, p, cut = reach[k, 0], reach[k, 1], reach[k, 2]
            dt = times[i] - u
            z = abs(dt) / h
            if z == 0.0:
                value += a
                jac[i, base], jac[i, base + 1], jac[i, base + 2], jac[i, base + 3] = 1.0, 0.0, 0.0, 0.0
                continue
            lnz = math.log(z)
            zp = math.exp(p * lnz)
            if _LN2 * zp > cut:
                jac[i, base] = jac[i, base + 1] = jac[i, base + 2] = jac[i, base + 3] = 0.0
                continue
            e = math.exp(-_LN2 * zp)
            ae = a * e * _LN2
            value += a * e
            jac[i, base] = e
            jac[i, base + 1] = ae * p * zp / z * (1.0 if dt > 0.0 else -1.0) / h
            jac[i, base + 2] = ae * p * zp / s
            jac[i, base + 3] = -2.0 * alpha * ae * zp * lnz
        model[i] = value
        r = weights[i] * (value - target[i])
        ssr += r * r
        if ssr >= bound:  # a sum of squares only grows: the trial is rejected
            return ssr
    return ssr


# weighted_trial's block of samples: its echo terms are computed a block at a time into contiguous scratch, in a loop
# LLVM vectorizes, and its early stop is checked after each block
TRIAL_BLOCK = 64
_LANES = 8  # float64 lanes of AVX-512 (twice AVX2's): a loop of a multiple of it leaves no scalar remainder


@njit(**JIT_INLINE)
def _weighted_echo_terms(times, weights, first, last, lo, hi, start, a, u, inv_h, p, cut, da, ds, dalpha, block):
    """Echo terms for samples [first, last) of the block at `start`, 0 outside [lo, hi): a e added into block[0] (the
    block's model) and the Jacobian's row entries w (e, da ezp / dt, ds ezp, dalpha ezp lnz) into block[1:5].
    No branch (selects), so it vectorizes: at the centre (dt == 0) e = 1 and the rest 0, beyond the cut all 0."""
    value, d_amplitude, d_position, d_width, d_shape = block[0], block[1], block[2], block[3], block[4]
    # unsigned indices: numba wraps a signed one that may be negative, a select per access that blocks SIMD
    lo, hi = np.uint64(lo), np.uint64(hi)
    for i in range(np.uint64(first), np.uint64(last)):
        j = i - np.uint64(start)
        inside = i >= lo and i < hi
        dt = times[i] - u
        centre = dt == 0.0
        z = 1.0 if centre else abs(dt) * inv_h  # z = 1: lnz = 0, finite, masked below
        lnz = log_ieee(z)
        zp = exp_ieee(p * lnz)
        kept = _LN2 * zp <= cut and inside and not centre
        e = exp_ieee(-_LN2 * zp)
        e = 1.0 if centre and inside else (e if kept else 0.0)
        value[j] += a * e
        we = weights[i] * e
        wezp = we * zp if kept else 0.0
        d_amplitude[j] = we
        d_position[j] = da * wezp / (1.0 if centre else dt)
        d_width[j] = ds * wezp
        d_shape[j] = dalpha * wezp * lnz


@njit(**JIT)
def weighted_trial(x, n_echoes, times, shape, target, weights, bound, model, jac, windows, reach, block):
    """Long records' LM point (a generalized Gaussian with a tail floor, fwcore.engine.model.EchoShape): the model,
    windows and sum of trial_model_and_jacobian, with the Jacobian's rows scaled by `weights` (W^1/2 J:
    _normal_equations then needs no weight in its products) and one division an echo sample, not four.
    The exps and log are fwcore._jit's vectorizable ones, over TRIAL_BLOCK samples at a time; each sample's model adds
    its echoes in echo order. The sum stops early, after the first block where it reaches `bound`, with model, jac
    and windows left part-filled. Only the background's column and each echo's columns inside its window are
    written. Not model_and_jacobian's bits: short records (Leica, RIEGL, NEON) never come here.
    `reach` is (n_echoes x 6) scratch, `block` (5 x TRIAL_BLOCK)."""
    m = times.size
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
        windows[k, 0], windows[k, 1], h, p, cut = _echo_window(a, u, s, alpha, times, shape.tail_floor)
        reach[k, 0], reach[k, 1], reach[k, 2] = 1.0 / h, p, cut
        reach[k, 3], reach[k, 4], reach[k, 5] = _LN2 * a * p, _LN2 * a * p / s, -2.0 * alpha * _LN2 * a
    ssr = 0.0
    for start in range(0, m, TRIAL_BLOCK):
        stop = min(start + TRIAL_BLOCK, m)
        for i in range(start, stop):
            block[0, i - start] = x[0]
            jac[i, 0] = weights[i]
        for k in range(n_echoes):
            lo, hi = max(windows[k, 0], start), min(windows[k, 1], stop)
            if lo >= hi:
                continue
            base = 1 + PARAMS_PER_ECHO * k
            # a multiple of the vector width of samples inside the block (the rest masked): no scalar remainder
            width = (hi - lo + _LANES - 1) // _LANES * _LANES
            first = max(min(lo, stop - width), start)
            _weighted_echo_terms(times, weights, first, min(first + width, stop), lo, hi, start, x[base], x[base + 1],
                                 reach[k, 0], reach[k, 1], reach[k, 2], reach[k, 3], reach[k, 4], reach[k, 5], block)
            for i in range(np.uint64(lo), np.uint64(hi)):
                j = i - np.uint64(start)
                jac[i, base], jac[i, base + 1] = block[1, j], block[2, j]
                jac[i, base + 2], jac[i, base + 3] = block[3, j], block[4, j]
        for i in range(start, stop):  # the sum in sample order, as an unblocked loop adds it
            value = block[0, i - start]
            model[i] = value
            r = weights[i] * (value - target[i])
            ssr += r * r
        if ssr >= bound:  # a sum of squares only grows: the trial is rejected
            return ssr
    return ssr


@njit(**JIT)
def squared_error(x, n_echoes, times, shape, target, weights):
    """sum (weights (model(x, times) - target))**2, the model alone (no Jacobian), over the echo windows. With a tail
    floor (long records) the echoes take fwcore._jit's vectorizable exp and log (model.add_echo_vectorized)."""
    model = np.full(times.size, x[0])
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
        if shape.tabulated:
            before, after = table_reach(shape, s)
            add_table_echo(shape, a, u, s, times, searchsorted(times, u - before),
                           searchsorted(times, u + after, right=True), model)
            continue
        reach = s * _SQRT_2LN2 * (tail_cut(a, shape.tail_floor) / _LN2) ** (1.0 / (alpha * alpha))
        lo, hi = searchsorted(times, u - reach), searchsorted(times, u + reach, right=True)
        if shape.tail_floor > 0.0 and abs(u) + reach < 1e15:  # long records (finite): the vectorizable exp and log
            add_echo_vectorized(a, u, s, alpha, times, lo, hi, model)
            continue
        for i in range(lo, hi):
            model[i] += echo_value(a, u, s, alpha, times[i])
    acc = 0.0
    for i in range(times.size):
        acc += (weights[i] * (model[i] - target[i])) ** 2
    return acc


@njit(**JIT)
def _solve_damped(jtj, grad, lam, free, step, a):
    """Solve (JtJ + lam diag(JtJ)) step = -grad over the free parameters by Cholesky, `a` (d x d) its
    scratch; False if singular. The factor L is kept transposed (a[q, r] = L[r, q], q <= r): column c's
    entries are then finished as one loop over contiguous rows a q at a time, which LLVM vectorizes, each
    entry's sum still taken in q order (the bits of the row-by-row dot products)."""
    d = grad.size
    largest = 0.0
    for j in range(d):
        largest = max(largest, jtj[j, j])
    floor = 1e-12 * largest + 1e-300  # an echo of amplitude 0 has zero columns: keep the system regular
    for r in range(d):
        for c in range(d):
            a[r, c] = jtj[r, c] if free[r] and free[c] else 0.0
        a[r, r] = (jtj[r, r] * (1.0 + lam) + floor) if free[r] else 1.0
    # in-place Cholesky into the upper triangle (the system is symmetric: row c's upper part is column c)
    for c in range(d):
        acc = a[c, c]
        for q in range(c):
            acc -= a[q, c] * a[q, c]
        if acc <= 0.0:
            return False
        pivot = math.sqrt(acc)
        a[c, c] = pivot
        r = c + 1
        while r + CHOLESKY_LANES <= d:
            cholesky_lanes(a, c, r, pivot)
            r += CHOLESKY_LANES
        for rest in range(r, d):  # the last few entries, the same expression a lane at a time
            acc = a[c, rest]
            for q in range(c):
                acc -= a[q, rest] * a[q, c]
            a[c, rest] = acc / pivot
    for r in range(d):  # forward: L y = -grad
        acc = -grad[r] if free[r] else 0.0
        for q in range(r):
            acc -= a[q, r] * step[q]
        step[r] = acc / a[r, r]
    for r in range(d - 1, -1, -1):  # back: L^T step = y
        acc = step[r]
        for q in range(r + 1, d):
            acc -= a[r, q] * step[q]
        step[r] = acc / a[r, r]
    return True


assert PARAMS_PER_ECHO == 4, "_echo_block and _pair_block keep one accumulator per pair of an echo's 4 columns"


@njit(**JIT_INLINE)
def _echo_block(jac, residual, weights, lo, hi, base, jtj, grad):
    """One echo's gradient entries and its rows of J^T W J with itself and the background (columns 0 and
    base..base + 3), summed over its window [lo, hi): each sum in sample order as (j j w) w, (j w) r and (j w) w,
    a sample's sums in vector lanes (fwcore._simd)."""
    sums = block_sums(jac, weights, residual, lo, hi, base, base)
    _store_echo_block(jtj, grad, base, sums)


@njit(**JIT_INLINE)
def _store_echo_block(jtj, grad, base, sums):
    """An echo's block_sums into its gradient entries and its symmetric rows of J^T W J (with the background,
    column 0): sums[4 a + b] its columns' products, sums[16 + a] with the residual, sums[20 + a] with the weight."""
    for a in range(4):
        grad[base + a] = sums[16 + a]
        jtj[0, base + a] = jtj[base + a, 0] = sums[20 + a]
        for b in range(a, 4):
            jtj[base + a, base + b] = jtj[base + b, base + a] = sums[4 * a + b]


@njit(**JIT_INLINE)
def _store_pair_block(jtj, r, c, sums):
    """Two echoes' 16 cross sums (sums[4 a + b]: columns r + a and c + b) into both of their places in J^T W J."""
    for a in range(4):
        for b in range(4):
            jtj[r + a, c + b] = jtj[c + b, r + a] = sums[4 * a + b]


@njit(**JIT_INLINE)
def _pair_block(jac, weights, lo, hi, r, c, jtj):
    """The rows of J^T W J of two echoes' columns (r..r + 3 with c..c + 3), summed over [lo, hi) in one pass: 16
    sums, each in sample order with the product taken as jac jac w w, a sample's 16 in vector lanes
    (fwcore._simd), so the bits are those of a pass per pair of columns."""
    _store_pair_block(jtj, r, c, block_sums(jac, weights, None, lo, hi, r, c))


@njit(**JIT)
def _normal_equations(jac, residual, weights, windows, jtj, grad, weighted=False):
    """J^T W J and J^T W r, W = diag(weights**2); `residual` is already weighted. `jac` is J (model_and_jacobian's
    rows), or W^1/2 J where `weighted` (weighted_trial's: J^T W J = jac^T jac, its products need no weight).
    Each sum runs only over the samples where both columns can be non-zero (their echoes' windows): the terms
    left out are exact zeros, so the result is the full sum's, bit for bit. An echo's own block (its columns
    with each other and with the background's) is summed in one pass over its window, every sum in
    its own accumulator and in the same order as alone: the same bits, without a pass per pair."""
    m, d = jac.shape
    n_echoes = (d - 1) // PARAMS_PER_ECHO
    g = 0.0
    acc = 0.0
    for i in range(m):  # the background's column is 1 everywhere (W^1/2 J's: the weights): exact without it
        g += weights[i] * residual[i]
        acc += weights[i] * weights[i]
    grad[0] = g
    jtj[0, 0] = acc
    for k in range(n_echoes):
        lo, hi, col = windows[k, 0], windows[k, 1], 1 + PARAMS_PER_ECHO * k
        if weighted:
            _weighted_echo_block(jac, residual, weights, lo, hi, col, jtj, grad)
        else:
            _echo_block(jac, residual, weights, lo, hi, col, jtj, grad)
    for k in range(n_echoes):  # two echoes' columns meet where their windows overlap
        for q in range(k + 1, n_echoes):
            lo, hi = max(windows[k, 0], windows[q, 0]), min(windows[k, 1], windows[q, 1])
            if weighted:
                _weighted_pair_block(jac, weights, lo, hi, 1 + PARAMS_PER_ECHO * k, 1 + PARAMS_PER_ECHO * q, jtj)
            else:
                _pair_block(jac, weights, lo, hi, 1 + PARAMS_PER_ECHO * k, 1 + PARAMS_PER_ECHO * q, jtj)


@njit(**JIT_INLINE)
def _weighted_echo_block(jw, residual, weights, lo, hi, base, jtj, grad):
    """_echo_block from weighted rows: no weight in the products (j j, j r and j w)."""
    _store_echo_block(jtj, grad, base, weighted_block_sums(jw, weights, residual, lo, hi, base, base))


@njit(**JIT_INLINE)
def _weighted_pair_block(jw, weights, lo, hi, r, c, jtj):
    """_pair_block from weighted rows: one product an entry and sample, not three."""
    _store_pair_block(jtj, r, c, weighted_block_sums(jw, weights, None, lo, hi, r, c))


@njit(**JIT)
def _predicted_gain(grad, jtj, x, trial):
    """How much the linearised model says the step x -> trial lowers the sum of squares: -(2 g.delta +
    delta' JtJ delta), g = J^T W r (the gradient's half)."""
    d = x.size
    predicted = 0.0
    for r in range(d):
        delta = trial[r] - x[r]
        predicted -= 2.0 * grad[r] * delta
        for c in range(d):
            predicted -= delta * jtj[r, c] * (trial[c] - x[c])
    return predicted


@njit(**JIT)
def _damping_after_gain(lam, gain, grad, jtj, x, trial):
    """Nielsen's damping update after an accepted step x -> trial: by how well the linear model predicted
    the gain, so that a step into a curved valley (overlapping echoes trading amplitude) is not followed
    by a bolder one."""
    predicted = _predicted_gain(grad, jtj, x, trial)
    # a clipped step's prediction means little: ratio 0.5 leaves the damping as it is
    ratio = gain / predicted if predicted > 0.0 else 0.5
    return max(lam * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3), 1e-9)


_UNDAMPED = 1e-3  # LM's first damping, and the most at which its step is taken as the Gauss-Newton one


@njit(**JIT)
def _lm_scratch(m, d):
    """LM's float work arrays for m samples and d parameters: (model, trial_model, residual (m each), jac,
    trial_jac (m x d), jtj, factor (d x d, factor the damped system's Cholesky factor), grad, step, trial (d))."""
    # the float scratch is views of one allocation: LM runs a few times a pulse, and on RIEGL's short
    # waveforms a dozen allocations a call cost a sizeable share of its arithmetic
    scratch = np.empty(3 * m + 2 * m * d + 2 * d * d + 3 * d)
    model, trial_model, residual = scratch[:m], scratch[m:2 * m], scratch[2 * m:3 * m]
    o = 3 * m
    jac = scratch[o:o + m * d].reshape((m, d))
    trial_jac = scratch[o + m * d:o + 2 * m * d].reshape((m, d))
    o += 2 * m * d
    jtj = scratch[o:o + d * d].reshape((d, d))
    factor = scratch[o + d * d:o + 2 * d * d].reshape((d, d))
    o += 2 * d * d
    grad, step, trial = scratch[o:o + d], scratch[o + d:o + 2 * d], scratch[o + 2 * d:o + 3 * d]
    return model, trial_model, residual, jac, trial_jac, jtj, factor, grad, step, trial


@njit(**JIT)
def levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper, max_iterations, tolerance,
                        chi2_tolerance=0.0, predict=False):
    """Minimise sum (weights (model(x, times) - target))**2 inside [lower, upper], x updated in place
    (weights: 1 / the noise sigma of each sample, or ones).

    Returns (weighted sum of squares, Jacobians evaluated, converged): converged when an accepted
    step lowers the sum by less than `tolerance` of it or by less than `chi2_tolerance`, when the next
    step's linear model promises less than `chi2_tolerance` (it is not taken; with `predict`), or when no
    step can lower it (damping runs away); not when max_iterations ran out first.
    """
    m = times.size
    d = x.size
    free = lower < upper
    model, trial_model, residual, jac, trial_jac, jtj, factor, grad, step, trial = _lm_scratch(m, d)
    both_windows = np.zeros((2, n_echoes, 2), dtype=np.int64)
    windows, trial_windows = both_windows[0], both_windows[1]
    # long records (a generalized Gaussian with a tail floor): the weighted Jacobian, cheaper normal equations
    weighted = shape.tail_floor > 0.0 and not shape.tabulated
    reach, block = np.empty((n_echoes, 6)), np.empty((5, TRIAL_BLOCK))  # the trials' scratch (block: weighted_trial's)
    if weighted:
        weighted_trial(x, n_echoes, times, shape, target, weights, np.inf, model, jac, windows, reach, block)
    else:
        model_and_jacobian(x, n_echoes, times, shape, model, jac, windows)
    ssr = 0.0
    for i in range(m):
        residual[i] = weights[i] * (model[i] - target[i])
        ssr += residual[i] * residual[i]
    n_jacobians = 1
    lam = _UNDAMPED
    growth = 2.0
    done = False
    _normal_equations(jac, residual, weights, windows, jtj, grad, weighted)
    active = free.copy()
    for _ in range(max_iterations):
        # a parameter held at a bound with the descent pushing outwards stays there for the step
        for j in range(d):
            active[j] = free[j] and not ((x[j] <= lower[j] and grad[j] > 0.0) or (x[j] >= upper[j] and grad[j] < 0.0))
        if not _solve_damped(jtj, grad, lam, active, step, factor):
            lam *= 10.0
            if lam > 1e12:
                done = True
                break
            continue
        for j in range(d):
            trial[j] = min(max(x[j] + step[j], lower[j]), upper[j])
        # a step whose linear model promises under chi2_tolerance is not worth its Jacobian: stop before it
        # (undamped steps only: a damped one is short by design and promises little anywhere)
        if predict and chi2_tolerance > 0.0 and lam <= _UNDAMPED \
                and _predicted_gain(grad, jtj, x, trial) <= chi2_tolerance:
            done = True
            break
        # a trial LM rejects stops where its sum of squares passes the current one, part of a Jacobian
        if weighted:
            trial_ssr = weighted_trial(trial, n_echoes, times, shape, target, weights, ssr, trial_model, trial_jac,
                                       trial_windows, reach, block)
        else:
            trial_ssr = trial_model_and_jacobian(trial, n_echoes, times, shape, target, weights, ssr, trial_model,
                                                 trial_jac, trial_windows, reach)
        n_jacobians += 1
        if trial_ssr < ssr:
            gain = ssr - trial_ssr
            lam = _damping_after_gain(lam, gain, grad, jtj, x, trial)
            growth = 2.0
            x[:] = trial
            jac, trial_jac = trial_jac, jac  # the trial's Jacobian becomes the current one
            windows, trial_windows = trial_windows, windows
            for i in range(m):
                residual[i] = weights[i] * (trial_model[i] - target[i])
            ssr = trial_ssr
            if gain <= tolerance * ssr or gain <= chi2_tolerance:
                done = True
                break
            _normal_equations(jac, residual, weights, windows, jtj, grad, weighted)
        else:
            lam *= growth
            growth *= 2.0
            if lam > 1e12:
                done = True
                break
    return ssr, n_jacobians, done


@njit(**JIT)
def _ssr_and_gradient(x, n_echoes, times, shape, target, weights, free, model, jac, grad):
    """sum (weights (model - target))**2 at x and its gradient (0 for the parameters that never move)."""
    windows = np.empty((n_echoes, 2), dtype=np.int64)
    model_and_jacobian(x, n_echoes, times, shape, model, jac, windows)
    ssr = 0.0
    for j in range(x.size):
        grad[j] = 0.0
    for i in range(times.size):
        r = weights[i] * (model[i] - target[i])
        ssr += r * r
        for j in range(x.size):
            grad[j] += 2.0 * r * weights[i] * jac[i, j]
    for j in range(x.size):
        if not free[j]:
            grad[j] = 0.0
    return ssr


@njit(**JIT_INLINE)
def _dot(a, b):
    """sum a * b in index order: np.dot is BLAS, whose kernels (and so its last bits) differ from one CPU
    to another, and a run must give the same echoes on every machine."""
    acc = 0.0
    for j in range(a.size):
        acc += a[j] * b[j]
    return acc


@njit(**JIT)
def _two_loop_direction(x, grad, lower, upper, free, s_hist, y_hist, rho, alpha_hist, stored, head, active,
                        direction):
    """The L-BFGS direction from the `stored` newest (s, y) pairs by the two-loop recursion, zero for the
    parameters held (`active`, set here: fixed, or at a bound with the gradient pushing outwards)."""
    d = x.size
    memory = rho.size
    for j in range(d):
        active[j] = (not free[j]) or (x[j] <= lower[j] and grad[j] > 0.0) or (x[j] >= upper[j] and grad[j] < 0.0)
        direction[j] = 0.0 if active[j] else -grad[j]
    for q in range(stored):  # newest pair first
        slot = (head - 1 - q) % memory
        a = rho[slot] * _dot(s_hist[slot], direction)
        alpha_hist[slot] = a
        direction -= a * y_hist[slot]
    if stored > 0:
        last = (head - 1) % memory
        direction *= _dot(s_hist[last], y_hist[last]) / _dot(y_hist[last], y_hist[last])
    for q in range(stored - 1, -1, -1):
        slot = (head - 1 - q) % memory
        b = rho[slot] * _dot(y_hist[slot], direction)
        direction += (alpha_hist[slot] - b) * s_hist[slot]
    for j in range(d):
        if active[j]:
            direction[j] = 0.0


@njit(**JIT)
def _line_search(x, direction, ssr, grad, n_echoes, times, shape, target, weights, lower, upper, free, model, jac,
                 trial, new_grad):
    """A backtracking (Armijo) search along the projected path from x: (sum of squares at `trial`, accepted,
    gradients evaluated); `new_grad` holds the gradient at `trial`."""
    step = 1.0
    new_ssr = ssr
    for k in range(30):
        for j in range(x.size):
            trial[j] = min(max(x[j] + step * direction[j], lower[j]), upper[j])
        new_ssr = _ssr_and_gradient(trial, n_echoes, times, shape, target, weights, free, model, jac, new_grad)
        if new_ssr <= ssr + 1e-4 * _dot(grad, trial - x):
            return new_ssr, True, k + 1
        step *= 0.5
    return new_ssr, False, 30


@njit(**JIT)
def lbfgs(x, n_echoes, times, shape, target, weights, lower, upper, max_iterations, memory, tolerance):
    """Projected L-BFGS on sum (weights (model - target))**2 inside [lower, upper], x updated in place.

    The two-loop recursion gives the direction; parameters held at a bound with the
    gradient pushing outwards are frozen for the step; a backtracking (Armijo) line
    search along the projected path accepts it. Returns (sum of squares, gradients, converged):
    converged unless max_iterations ran out first.
    """
    m = times.size
    d = x.size
    free = lower < upper
    model = np.empty(m)
    jac = np.empty((m, d))
    grad = np.empty(d)
    new_grad = np.empty(d)
    trial = np.empty(d)
    direction = np.empty(d)
    s_hist = np.zeros((memory, d))
    y_hist = np.zeros((memory, d))
    rho = np.zeros(memory)
    alpha_hist = np.zeros(memory)
    stored = 0
    head = 0
    ssr = _ssr_and_gradient(x, n_echoes, times, shape, target, weights, free, model, jac, grad)
    n_gradients = 1
    done = False
    for _ in range(max_iterations):
        active = np.zeros(d, dtype=np.bool_)
        _two_loop_direction(x, grad, lower, upper, free, s_hist, y_hist, rho, alpha_hist, stored, head, active,
                            direction)
        slope = _dot(grad, direction)
        if slope >= 0.0:  # not a descent direction: restart from steepest descent
            stored = 0
            for j in range(d):
                direction[j] = 0.0 if active[j] else -grad[j]
            slope = _dot(grad, direction)
            if slope >= 0.0:
                done = True
                break
        new_ssr, accepted, used = _line_search(x, direction, ssr, grad, n_echoes, times, shape, target, weights,
                                               lower, upper, free, model, jac, trial, new_grad)
        n_gradients += used
        if not accepted:  # no step lowers the sum: a minimum to the line search's precision
            done = True
            break
        slot = head % memory
        s_hist[slot] = trial - x
        y_hist[slot] = new_grad - grad
        sy = _dot(s_hist[slot], y_hist[slot])
        gain = ssr - new_ssr
        x[:] = trial
        grad[:] = new_grad
        ssr = new_ssr
        if sy > 1e-12 * _dot(y_hist[slot], y_hist[slot]):  # keep the inverse Hessian positive
            rho[slot] = 1.0 / sy
            head = (head + 1) % memory
            stored = min(stored + 1, memory)
        if gain <= tolerance * ssr:
            done = True
            break
    return ssr, n_gradients, done


# ---------------------------------------------------------------- Python API

def fit_levenberg_marquardt(x0, n_echoes: int, times, target, lower, upper, max_iterations: int = 50,
                            tolerance: float = 1e-8, shape=None) -> tuple[np.ndarray, float, int]:
    """LM from x0 inside the bounds: (best individual, sum of squares, Jacobians evaluated); echoes of
    `shape` (fwcore.engine.model.EchoShape; None: the generalized Gaussian)."""
    x = np.array(x0, dtype=np.float64)
    lower = np.ascontiguousarray(lower, dtype=np.float64)
    upper = np.ascontiguousarray(upper, dtype=np.float64)
    if x.size != 1 + PARAMS_PER_ECHO * n_echoes or lower.shape != x.shape or upper.shape != x.shape:
        raise ValueError(f"an individual of {n_echoes} echoes has {1 + PARAMS_PER_ECHO * n_echoes} parameters")
    x = np.clip(x, lower, upper)
    times = np.ascontiguousarray(times, dtype=np.float64)
    shape = analytic_shape() if shape is None else shape
    ssr, n_jacobians, _ = levenberg_marquardt(x, int(n_echoes), times, shape,
                                              np.ascontiguousarray(target, dtype=np.float64),
                                              np.ones(times.size), lower, upper, int(max_iterations),
                                              float(tolerance))
    return x, float(ssr), int(n_jacobians)


def fit_lbfgs(x0, n_echoes: int, times, target, lower, upper, max_iterations: int = 200, memory: int = 10,
              tolerance: float = 1e-9, shape=None) -> tuple[np.ndarray, float, int]:
    """Projected L-BFGS from x0 inside the bounds: (best individual, sum of squares, gradients evaluated)."""
    x = np.clip(np.array(x0, dtype=np.float64), lower, upper)
    shape = analytic_shape() if shape is None else shape
    times = np.ascontiguousarray(times, dtype=np.float64)
    ssr, n_gradients, _ = lbfgs(x, int(n_echoes), times, shape, np.ascontiguousarray(target, dtype=np.float64),
                                np.ones(times.size), np.ascontiguousarray(lower, dtype=np.float64),
                                np.ascontiguousarray(upper, dtype=np.float64), int(max_iterations), int(memory),
                                float(tolerance))
    return x, float(ssr), int(n_gradients)
