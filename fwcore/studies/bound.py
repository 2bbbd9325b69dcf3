"""What an ideal engine could resolve on a simulated flight: the joint Cramer-Rao bound of its echo times.

Per pulse, every true echo's amplitude, time and width and the background are unknowns; the Fisher
information of the simulator's noise (Gaussian sigma_noise^2 + shot x signal, plus 1/12 DN^2 of
quantisation) over the packet's samples bounds the variance of each echo's time given all the others.
An unbiased estimator at that bound, told how many echoes there are and their shape, lands within the
match window of `fwl evaluate` with probability erf(window / (sigma sqrt 2)). Summed over the resolvable
echoes, that is the recall no unbiased engine beats on average (a biased estimator is not held to the
bound), and the RMS error of the echoes that land is the range RMSE it would report: `fwl evaluate`'s
resolvable rows beside the instrument's own limit. The single-echo CRLB column of `fwl evaluate` leaves the
neighbours out; two echoes a pulse width apart share their samples, and their times trade against each
other's amplitude and width. With `widths_known` the widths are given, not estimated: the Fisher information
without the width parameters, the limit an engine told each echo's width (issue 38's "widths known") reaches.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.special import erf

from fwcore.engine.model import tabulated_model, waveform_model
from fwcore.instrument.shape import echo_shape
from fwcore.studies.simulate import RESPONSE_WIDEST, SensorConfig

_QUANTISATION_VARIANCE = 1.0 / 12.0  # DN^2: rounding to integer counts


@dataclasses.dataclass(frozen=True)
class BoundMatch:
    """The bound's expectation over a set of true echoes."""

    true_echoes: int
    expected_matched: float  # sum of each echo's probability to land within the match window
    range_rmse_cm: float  # RMS of the errors that land (each a Gaussian truncated at the window)

    @property
    def recall(self) -> float:
        return self.expected_matched / self.true_echoes if self.true_echoes else float("nan")


def _pulse_model(sensor: SensorConfig, shape, amplitude, time_ps, sigma_ps, alpha, background, t_ps) -> np.ndarray:
    """The noise-free packet of one pulse's echoes, as the simulator draws it (fwcore.studies.simulate)."""
    if shape is None:
        return waveform_model(t_ps, background, amplitude, time_ps, sigma_ps, alpha)
    spacing = sensor.sample_spacing_ps  # the response's table is in samples
    return tabulated_model(t_ps / spacing, background, amplitude, time_ps / spacing, sigma_ps / spacing, shape)


def echo_time_bounds_ps(pulse_id: np.ndarray, time_ps: np.ndarray, amplitude: np.ndarray, sigma_ps: np.ndarray,
                        alpha: np.ndarray, sensor: SensorConfig, wanted: np.ndarray | None = None,
                        widths_known: bool = False) -> np.ndarray:
    """Per true echo, the joint Cramer-Rao bound (ps, one sigma) of its time, with every echo of its pulse's
    amplitude, time and width (given, with `widths_known`) and the background unknown; NaN for pulses with no
    `wanted` echo (all by default)."""
    pulse_id, time_ps, amplitude, sigma_ps, alpha = (np.asarray(a) for a in (pulse_id, time_ps, amplitude, sigma_ps,
                                                                              alpha))
    wanted = np.ones(pulse_id.size, bool) if wanted is None else np.asarray(wanted, bool)
    shape = echo_shape(sensor.response, sensor.sample_spacing_ps, RESPONSE_WIDEST) if sensor.response is not None \
        else None
    t_ps = np.arange(sensor.samples_per_packet, dtype=float) * sensor.sample_spacing_ps
    out = np.full(pulse_id.size, np.nan)
    order = np.argsort(pulse_id, kind="stable")
    starts = np.flatnonzero(np.r_[True, pulse_id[order][1:] != pulse_id[order][:-1]])
    for lo, hi in zip(starts, np.r_[starts[1:], order.size]):
        echoes = order[lo:hi]
        if not wanted[echoes].any():
            continue
        # parameters: (amplitude, time, width) per echo, then the background
        params = np.concatenate([np.column_stack([amplitude[echoes], time_ps[echoes], sigma_ps[echoes]]).ravel(), [0.0]])

        def model(q: np.ndarray) -> np.ndarray:
            return _pulse_model(sensor, shape, q[0:-1:3], q[1:-1:3], q[2:-1:3], alpha[echoes], q[-1], t_ps)

        jacobian = np.empty((t_ps.size, params.size))
        for j in range(params.size):  # central differences: the tabulated shape has no closed-form derivative
            step = 1e-4 * max(abs(params[j]), 1.0)
            up, down = params.copy(), params.copy()
            up[j] += step
            down[j] -= step
            jacobian[:, j] = (model(up) - model(down)) / (2.0 * step)
        signal = np.maximum(model(params), 0.0)
        variance = sensor.noise_sigma ** 2 + sensor.shot_noise * signal + _QUANTISATION_VARIANCE
        unknown = np.ones(params.size, bool)
        if widths_known:  # a known width is no parameter: its rows and columns leave the information
            unknown[2:-1:3] = False
        information = jacobian[:, unknown].T @ (jacobian[:, unknown] / variance[:, None])
        try:
            covariance = np.linalg.inv(information)
        except np.linalg.LinAlgError:  # an echo the samples do not constrain at all (outside the packet)
            out[echoes] = np.inf
            continue
        times = np.zeros(params.size, bool)
        times[1:-1:3] = True
        out[echoes] = np.sqrt(np.maximum(np.diag(covariance)[times[unknown]], 0.0))
    return out


def expected_match(bound_ps: np.ndarray, match_ps: float, cm_per_ps: float) -> BoundMatch:
    """The recall and the range RMSE of the matched echoes that an unbiased estimator at the bound would reach."""
    bound_ps = np.asarray(bound_ps, float)
    bound_ps = np.where(np.isnan(bound_ps), np.inf, bound_ps)  # not computed: nothing known, nothing lands
    window = match_ps / bound_ps  # the window in bound sigmas (0 for an unconstrained echo)
    land = erf(window / math.sqrt(2.0))
    expected = float(land.sum())
    if expected == 0.0:
        return BoundMatch(int(bound_ps.size), expected, float("nan"))
    lands = land > 0.0
    a, sigma = window[lands], bound_ps[lands]
    # variance of a normal truncated to +-window: sigma^2 (1 - 2 a phi(a) / (2 Phi(a) - 1))
    truncated = sigma ** 2 * (1.0 - 2.0 * a * np.exp(-a ** 2 / 2.0) / math.sqrt(2.0 * math.pi) / land[lands])
    return BoundMatch(int(bound_ps.size), expected, math.sqrt(float((land[lands] * truncated).sum()) / expected)
                      * cm_per_ps)
