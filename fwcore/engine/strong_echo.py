"""A cheaper fit for a pulse of one strong echo (a RIEGL export's: a 16-bit return hundreds of sigma strong, with
weak candidates beside it that the filter will drop).

The initial estimate peels a strong return and the residue of its misfit (the afterpulse behind it, grass just
above the ground, a rising edge slower than the response) as weak candidates. The full path fits them all
jointly (LM crawls along the valley where a strong echo and a weak one beside it trade amplitude), tries to drop
each by a refit, and refits the raw samples where they fail the noise model: a dozen Jacobians a pulse for an echo
the filter then keeps alone. Here, where every candidate but the strongest would be filtered against it (weak, or
too close to it), LM (Gauss-Newton steps from the peak's parabola, where the estimate placed it) fits the strongest
echo alone on the tabulated response, and the candidates are set aside unfitted. The engine's selection then
looks at that fit's residual as after any fit: its add step puts back an echo where the residual holds one the
filter would keep; and the raw polish runs only where the raw samples still fail the noise model. A pulse of one
candidate, or of two the filter would keep, takes the full path as before (the same bits).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.filter import KEPT
from fwcore.engine.model import PARAMS_PER_ECHO
from fwcore.engine.optimizers.local import levenberg_marquardt
from fwcore.engine.selection import spurious_reasons


@njit(**JIT)
def strongest_alone(x, n_echoes, first, last, pulse_fwhm, noise, p):
    """The index of the strongest echo of individual x where every other echo would be filtered against it (as
    the filter marks them, in the individual's order); -1 where another would be kept, or x has no other echo."""
    if n_echoes < 2:
        return -1
    reasons = spurious_reasons(x, n_echoes, first, last, pulse_fwhm, noise, p)
    strongest = 0
    for k in range(1, n_echoes):
        if x[1 + PARAMS_PER_ECHO * k] > x[1 + PARAMS_PER_ECHO * strongest]:
            strongest = k
    for k in range(n_echoes):
        if (reasons[k] == KEPT) != (k == strongest):
            return -1
    return strongest


@njit(**JIT)
def strong_echo_fit(wanted, p, shape, x0, lower, upper, n_echoes, times, fit_target, raw, weights, first, last,
                    pulse_fwhm, noise):
    """The strongest echo of the initial individual x0 fitted alone, where `wanted`, the shape is tabulated and the
    echo stands alone (strongest_alone). Returns (the individual of the background and that echo, its lower and
    upper bounds, Jacobians evaluated, whether it was fitted). Where it was not, the caller runs the full path."""
    d = 1 + PARAMS_PER_ECHO
    x = np.empty(d)
    x_lower = np.empty(d)
    x_upper = np.empty(d)
    k = strongest_alone(x0, n_echoes, first, last, pulse_fwhm, noise, p) if wanted and shape.tabulated else -1
    if k < 0:
        return x, x_lower, x_upper, 0, False
    base = 1 + PARAMS_PER_ECHO * k
    for source, out in ((x0, x), (lower, x_lower), (upper, x_upper)):
        out[0] = source[0]
        out[1:] = source[base:base + PARAMS_PER_ECHO]
    _, used, _ = levenberg_marquardt(x, 1, times, shape, fit_target, weights, x_lower, x_upper, p.lm_iterations,
                                     p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
    return x, x_lower, x_upper, used, True
