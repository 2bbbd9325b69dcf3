"""The initial individual and the box every optimizer searches, all physical (A >= 0, s > 0, u inside)."""

from __future__ import annotations

from numba import njit

from fwcore._jit import JIT
from fwcore.engine.model import GAUSSIAN_ALPHA, PARAMS_PER_ECHO


@njit(**JIT)
def echo_bounds(amplitude, position, sigma, height, noise, first, last, gaussian, alpha_min, alpha_max, shape,
                base, x0, lower, upper, local_upper):
    """One echo's start and box at x0[base:base + 4]: amplitude up to 1.5 x the estimate for the
    population methods; up to 1.5 x the signal's height at the echo for the local ones
    (local_upper): the progressive estimate gives a flank echo only what the stronger one left,
    and a gradient can grow it to its true height, where a population spread over that range
    would mostly split single echoes in two. A tabulated shape bounds the width to its table's rows
    (no echo narrower than the instrument's response)."""
    shift = max(1.5 * sigma, 2.0)
    x0[base], lower[base], upper[base] = amplitude, 0.0, 1.5 * amplitude + 3.0 * noise
    local_upper[base] = 1.5 * max(amplitude, height) + 3.0 * noise
    x0[base + 1] = position
    lower[base + 1] = max(first, position - shift)
    upper[base + 1] = min(last, position + shift)
    x0[base + 2], lower[base + 2], upper[base + 2] = sigma, max(0.25 * sigma, 0.3), 3.0 * sigma
    if shape.tabulated:
        widest = shape.s_min + shape.s_step * (shape.rows.shape[0] - 1)
        lower[base + 2], upper[base + 2] = shape.s_min, widest
        x0[base + 2] = min(max(sigma, shape.s_min), widest)
    x0[base + 3] = GAUSSIAN_ALPHA
    lower[base + 3] = GAUSSIAN_ALPHA if gaussian else alpha_min
    upper[base + 3] = GAUSSIAN_ALPHA if gaussian else alpha_max
    for j in range(1, PARAMS_PER_ECHO):
        local_upper[base + j] = upper[base + j]


@njit(**JIT)
def parameter_bounds(background, noise, amplitude, position, sigma, signal, first, last, gaussian,
                     alpha_min, alpha_max, shape, scale, x0, lower, upper, local_upper):
    """The initial individual [b, (A, u, s, alpha)...] and its bounds: the background within
    max(3 noise, scale) of its estimate, each echo as echo_bounds."""
    spread_b = max(3.0 * noise, scale)
    x0[0] = background
    lower[0] = background - spread_b
    upper[0] = background + spread_b
    local_upper[0] = upper[0]
    for k in range(amplitude.size):
        height = signal[min(max(int(round(position[k])), 0), signal.size - 1)] - background
        echo_bounds(amplitude[k], position[k], sigma[k], height, noise, first, last, gaussian, alpha_min,
                    alpha_max, shape, 1 + PARAMS_PER_ECHO * k, x0, lower, upper, local_upper)
