"""The population methods' objective: the method's Eq. 9 fit error, in float32 SIMD.

An individual is [b, (A, u, s, alpha) per echo], with s the equal-FWHM Gaussian
sigma (see fwcore.engine.model). Its fitness is sum_i |f(x_i) - y_i| over the valid
samples, each echo evaluated only over the aligned blocks where it exceeds eps
(the exact float64 metrics are fwcore.engine.model's).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT_INLINE, SIMD_JIT, bits_of_f32, fast_exp2, fast_log2
from fwcore.engine.model import PARAMS_PER_ECHO, bilinear, grid_column, table_reach, table_row

_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
_F32 = np.float32
_ZERO32 = _F32(0.0)

@njit(**JIT_INLINE)
def _echo_reach(amplitude, h, p, eps):
    """How far from its centre (in samples) an echo stays above eps: h * log2(A/eps)**(1/p),
    with log2(A/eps) bounded above by its float exponent + 1 (cheap, and only widens the window)."""
    ratio = _F32(amplitude / eps)
    if ratio <= _F32(1.0):
        return -1.0
    levels = _F32((bits_of_f32(ratio) >> np.int32(23)) - np.int32(126))
    if p == 2.0:
        return h * math.sqrt(levels)
    return h * fast_exp2(fast_log2(levels) / _F32(p))


LANES = 8  # float32 lanes of AVX2: echo windows and buffers are whole blocks of LANES samples


def padded_length(n: int) -> int:
    """Buffer length for an n-sample waveform: whole SIMD blocks, so no scalar remainder loop runs."""
    return (n + LANES - 1) // LANES * LANES


@njit(**SIMD_JIT)
def fill_model(x, n_echoes, tpos, alpha_fixed, shape, eps, model):
    """Write the model of individual x into `model` (float32, padded to whole blocks),
    evaluating each echo only over the aligned blocks where it exceeds eps (a tabulated shape over
    its table's support, scalar: a gather does not vectorise)."""
    n = model.size
    b = _F32(x[0])
    for i in range(n):
        model[i] = b
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        amplitude = x[base]
        if amplitude <= 0.0:
            continue
        u = x[base + 1]
        if shape.tabulated:
            before, after = table_reach(shape, x[base + 2])
            lo = max(0, int(math.floor(u - before)))
            hi = min(n, int(math.ceil(u + after)) + 1)
            w, a = table_row(shape, x[base + 2])
            rows = shape.rows
            step, origin, columns = shape.step, shape.origin, rows.shape[1]
            for i in range(lo, hi):
                j, b = grid_column(np.float64(tpos[i]) - u, step, origin, columns)
                if j >= 0:
                    model[i] += _F32(amplitude * bilinear(rows, w, a, j, b))
            continue
        h = x[base + 2] * _SQRT_2LN2
        p = x[base + 3] * x[base + 3]
        reach = _echo_reach(amplitude, h, p, eps)
        if reach < 0.0:
            continue
        lo = max(0, int(math.floor(u - reach))) // LANES * LANES
        hi = min(n, (int(math.ceil(u + reach)) + LANES) // LANES * LANES)
        a32 = _F32(amplitude)
        u32 = _F32(u)
        inv_h = _F32(1.0 / h)
        # unsigned indices: signed ones make numba emit wraparound checks that block SIMD
        if alpha_fixed:  # alpha = sqrt(2): the Gaussian, exp2(-z**2)
            for j in range(hi - lo):
                i = np.uint64(lo + j)
                z = (tpos[i] - u32) * inv_h
                model[i] += a32 * fast_exp2(-(z * z))
        else:
            p32 = _F32(p)
            for j in range(hi - lo):
                i = np.uint64(lo + j)
                z = abs(tpos[i] - u32) * inv_h
                model[i] += a32 * fast_exp2(-fast_exp2(p32 * fast_log2(z)))


@njit(**SIMD_JIT)
def fit_error(x, n_echoes, tpos, target, weight, alpha_fixed, shape, eps, model):
    """Eq. 9: sum of |model - target| over valid samples (weight 1, else 0). `model` is scratch."""
    fill_model(x, n_echoes, tpos, alpha_fixed, shape, eps, model)
    acc = _ZERO32
    for i in range(model.size):
        acc += weight[i] * abs(model[i] - target[i])
    return np.float64(acc)
