"""The noise model of a sample: sigma**2 + g s + (shape_tolerance s)**2 for signal s above background.

sigma is the white noise of the digitizer (fwcore.engine.smoothing), the shape tolerance
how far the system's pulse departs from the model (fwcore.instrument.measure), and g the
Poisson-like shot noise, fitted per waveform to the residual of a fit. The
optimizers' gate, the LM weights and the selection's BIC all read it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.model import individual_model


@njit(**JIT)
def noise_variance(smoothed, valid, background, noise, shape_tolerance, out):
    """Per valid sample, sigma**2 + (shape_tolerance x signal)**2, signal the smoothed height above background."""
    m = 0
    for i in range(smoothed.size):
        if valid[i]:
            s = max(smoothed[i] - background, 0.0) * shape_tolerance
            out[m] = noise * noise + s * s
            m += 1


@njit(**JIT)
def add_shot_noise(x, n_echoes, times, shape, raw, signal, variance):
    """Add the Poisson-like term g x signal to `variance`, g >= 0 fitted by least squares to the
    squared residuals of x that the variance does not explain; returns g."""
    model = np.empty(times.size)
    individual_model(x, n_echoes, times, shape, model)
    num = 0.0
    den = 0.0
    for i in range(times.size):
        if signal[i] > 0.0:
            r = model[i] - raw[i]
            num += signal[i] * (r * r - variance[i])
            den += signal[i] * signal[i]
    g = max(num / den, 0.0) if den > 0.0 else 0.0
    for i in range(times.size):
        variance[i] += g * max(signal[i], 0.0)
    return g
