"""The echo's width as RIEGL's software reports it ("Pulse width": the full width at half maximum, in the LAS
extra bytes of a RiPROCESS export), measured on the waveform rather than read off the fitted model.

An echo's samples are the waveform less the background and the pulse's other fitted echoes; its width is the
distance between the half-maximum crossings on either side of its highest sample (linear between samples).
`fwhm_ps`, the fitted model's width, never falls under the system response's (the fit's bound), so that a
quarter of a RIEGL flight's echoes tie there; measured on the samples, a narrow echo reads narrow, as in
RIEGL's export, and the widths rank as RIEGL's do. NaN where the echo has no half-maximum crossing inside its
waveform (an echo cut by the record's end) or nothing above the rest of the model.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE
from fwcore.engine.model import analytic_shape, batch_model, echo_span, table_peak_offset, table_value
from fwcore.engine.records import BatchDecomposition


@njit(**JIT_INLINE)
def _alone(samples, model, shape, amplitude, position, sigma, alpha, first, stop, k):
    """Sample k of the echo alone: the samples less the model plus the echo's own term, as batch_model adds it
    (0 outside its span [first, stop), where it is exactly 0)."""
    own = 0.0
    if first <= k < stop:
        if shape.tabulated:
            own = 0.0 + table_value(shape, amplitude, position, sigma, float(k))  # add_table_echo's sum on a 0
        else:
            own = amplitude * math.exp(-abs(float(k) - position) ** (alpha * alpha) / (2.0 * sigma * sigma))
    return samples[k] - (model[k] - own)


@njit(**JIT_INLINE)
def _crossing(samples, model, shape, amplitude, position, sigma, alpha, first, stop, k, half, step):
    """From the peak k stepping by `step` (-1, +1): the fractional sample where the echo alone falls under `half`;
    NaN if it does not before the waveform's end."""
    n = samples.size
    j = k
    inner = _alone(samples, model, shape, amplitude, position, sigma, alpha, first, stop, j)
    while 0 <= j + step < n:
        outer = _alone(samples, model, shape, amplitude, position, sigma, alpha, first, stop, j + step)
        if not outer >= half:  # NaN too, as a sample under half
            return j + step * (inner - half) / (inner - outer)
        j += step
        inner = outer
    return math.nan


@njit(**JIT)
def _widths(rows, sample_offsets, echo_offsets, samples, model, amplitude, position, sigma, alpha, shape, out):
    """Each echo of the waveforms `rows`: its half-maximum width (samples) on the samples less the rest of the
    model, into out. The echo alone is evaluated only at the samples its peak and crossings read."""
    for i in rows:
        lo, hi = sample_offsets[i], sample_offsets[i + 1]
        n = hi - lo
        raw, fitted = samples[lo:hi], model[lo:hi]
        for e in range(echo_offsets[i], echo_offsets[i + 1]):
            a, u, s, al = amplitude[e], position[e], sigma[e], alpha[e]
            first, stop = echo_span(shape, u, s, al, n)
            peak = u + table_peak_offset(shape, s) if shape.tabulated else u
            k = min(max(int(round(peak)), 0), n - 1)
            top = _alone(raw, fitted, shape, a, u, s, al, first, stop, k)
            centre = k
            for j in (centre - 1, centre + 1):  # the highest sample next to the fitted peak
                if 0 <= j < n:
                    value = _alone(raw, fitted, shape, a, u, s, al, first, stop, j)
                    if value > top:
                        k, top = j, value
            if top <= 0.0:
                out[e] = math.nan
                continue
            half = 0.5 * top
            out[e] = (_crossing(raw, fitted, shape, a, u, s, al, first, stop, k, half, 1)
                      - _crossing(raw, fitted, shape, a, u, s, al, first, stop, k, half, -1))


def waveform_widths(samples: np.ndarray, sample_offsets: np.ndarray, result: BatchDecomposition,
                    model: np.ndarray | None = None) -> np.ndarray:
    """Per echo of `result`, its half-maximum width measured on the waveform (samples of each pulse's own spacing;
    NaN for an echo of a pulse not decomposed or without a crossing: see the module). `model`: the fitted model at
    every sample (fwcore.engine.records.fitted_model) where the caller has it, else computed here."""
    offsets = np.asarray(sample_offsets, dtype=np.int64)
    echo_offsets = np.asarray(result.echo_offsets, dtype=np.int64)
    samples = np.asarray(samples, dtype=np.float64)
    given = model is not None
    model = np.ascontiguousarray(model, dtype=np.float64) if given else np.zeros(samples.size)
    out = np.full(result.amplitude.size, np.nan)
    ok = result.status == 0
    groups = ([(analytic_shape(), ok)] if result.shapes is None else
              [(shape, ok & (result.sample_spacing_ps == spacing)) for spacing, shape in result.shapes.items()])
    args = (result.amplitude, result.position, result.sigma, result.alpha)
    for shape, rows in groups:
        rows = np.flatnonzero(rows)
        if not given:  # the groups' rows are disjoint: each row's model is the same either way
            batch_model(rows, offsets, echo_offsets, result.background.astype(np.float64), *args, shape, model)
        _widths(rows, offsets, echo_offsets, samples, model, *args, shape, out)
    return out
