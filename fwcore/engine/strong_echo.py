"""A cheaper fit for a pulse of one strong echo (a RIEGL export's: a 16-bit return hundreds of sigma strong, with
weak candidates beside it that the filter will drop).

The initial estimate peels a strong return and the residue of its misfit (the afterpulse behind it, grass just
above the ground, a rising edge slower than the response) as weak candidates. The full path fits them all
jointly (LM crawls along the valley where a strong echo and a weak one beside it trade amplitude), tries to drop
each by a refit, and refits the raw samples where they fail the noise model: a dozen Jacobians a pulse for an echo
the filter then keeps alone. Here, where the filter would call every candidate but the strongest weak (under 5% of
it: not a piece of a broadened return, which NEON's forest peels as narrow echoes a few tens of % strong) and the
strongest starts narrow (BROADEST_START), LM (Gauss-Newton steps from the peak's parabola, where the estimate
placed it) fits the strongest echo alone on the tabulated response, and the candidates are set aside unfitted.
The engine's selection then looks at that fit's residual as after any fit: its add step puts back an echo where
the residual holds one the filter would keep; and the raw polish runs only where the raw samples still fail the
noise model. A pulse of one candidate, or of two the filter would keep, takes the full path as before (the same
bits).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.filter import KEPT, WEAK
from fwcore.engine.model import PARAMS_PER_ECHO
from fwcore.engine.optimizers.local import levenberg_marquardt
from fwcore.engine.selection import spurious_reasons

# the strongest echo's starting width at most this x the response's: a hard target's return (RIEGL's, within
# 1.2x), not a forest's broadened one (NEON's narrowest strong returns are 1.25-1.3x its impulse), whose weak
# candidates are pieces of its shape that the joint fit needs (NEON with its impulse: held-out 3.76 -> 4.01 DN
# without this bound)
BROADEST_START = 1.2


@njit(**JIT)
def strongest_alone(x, n_echoes, first, last, pulse_fwhm, noise, p):
    """The index of the strongest echo of individual x where the filter would call every other echo weak (under
    p.min_amplitude_ratio of the strongest, or under p.min_snr x the noise); -1 where another would be kept or
    dropped for another reason (too close: a broadened return peeled as narrow echoes, NEON's), or x has no other
    echo."""
    if n_echoes < 2:
        return -1
    reasons = spurious_reasons(x, n_echoes, first, last, pulse_fwhm, noise, p)
    strongest = 0
    for k in range(1, n_echoes):
        if x[1 + PARAMS_PER_ECHO * k] > x[1 + PARAMS_PER_ECHO * strongest]:
            strongest = k
    if reasons[strongest] != KEPT:
        return -1
    for k in range(n_echoes):
        if k != strongest and reasons[k] != WEAK:
            return -1
    return strongest


@njit(**JIT)
def strong_echo_fit(wanted, p, shape, x0, lower, upper, n_echoes, times, fit_target, raw, weights, first, last,
                    pulse_fwhm, noise):
    """The strongest echo of the initial individual x0 fitted alone, where `wanted`, the shape is tabulated, the
    echo stands alone (strongest_alone) and starts at most BROADEST_START x the response's width. Returns (the
    individual of the background and that echo, its lower and upper bounds, Jacobians evaluated, whether it was
    fitted). Where it was not, the caller runs the full path."""
    d = 1 + PARAMS_PER_ECHO
    x = np.empty(d)
    x_lower = np.empty(d)
    x_upper = np.empty(d)
    k = strongest_alone(x0, n_echoes, first, last, pulse_fwhm, noise, p) if wanted and shape.tabulated else -1
    if k < 0 or x0[1 + PARAMS_PER_ECHO * k + 2] > BROADEST_START * shape.s_min:
        return x, x_lower, x_upper, 0, False
    base = 1 + PARAMS_PER_ECHO * k
    for source, out in ((x0, x), (lower, x_lower), (upper, x_upper)):
        out[0] = source[0]
        out[1:] = source[base:base + PARAMS_PER_ECHO]
    _, used, _ = levenberg_marquardt(x, 1, times, shape, fit_target, weights, x_lower, x_upper, p.lm_iterations,
                                     p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
    return x, x_lower, x_upper, used, True
