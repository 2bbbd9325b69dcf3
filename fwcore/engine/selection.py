"""Model-order selection: how many echoes the data supports, by the BIC under the noise model.

The progressive estimate peels heavy tails, ringing and flanks off as extra
echoes, and misses an echo that shows only as a shoulder. After the optimizer,
echoes the filter flags are dropped (weakest first) when the raw samples do
not need them, and an echo is added where the residual still holds one the
filter would keep (a missed return, not a bump it would flag as weak); both
decided by the Bayesian information criterion on the raw samples,
chi^2 = sum ((model - raw) / sigma_i)^2 with sigma_i from the noise model, each
echo costing its parameters x ln(m). Every candidate is an LM refit from a warm
start, so the step is cheap and runs only where the filter or the residual asks.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.bounds import echo_bounds
from fwcore.engine.filter import KEPT, mark_spurious
from fwcore.engine.model import (PARAMS_PER_ECHO, SQRT_2LN2, echo_positions_of, individual_model,
                                 table_peak_offset)
from fwcore.engine.optimizers.local import levenberg_marquardt, squared_error
from fwcore.engine.smoothing import gaussian_weights, smoothed_sample, smoothed_value, weighted_sums



@njit(**JIT)
def spurious_reasons(x, n_echoes, first, last, pulse_fwhm, noise, p):
    """The filter's reason for each echo of individual x, in the individual's order."""
    position = echo_positions_of(x, n_echoes)
    order = np.argsort(position)
    amplitude = np.empty(n_echoes)
    width = np.empty(n_echoes)
    for j in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * order[j]
        amplitude[j] = x[base]
        width[j] = 2.0 * x[base + 2] * SQRT_2LN2
    sorted_reasons = np.zeros(n_echoes, dtype=np.int8)
    mark_spurious(amplitude, position[order], width, first, last, pulse_fwhm, noise, p, sorted_reasons)
    reasons = np.empty(n_echoes, dtype=np.int8)
    for j in range(n_echoes):
        reasons[order[j]] = sorted_reasons[j]
    return reasons


@njit(**JIT)
def _without_echo(x, k):
    keep = np.ones(x.size, dtype=np.bool_)
    keep[1 + PARAMS_PER_ECHO * k:1 + PARAMS_PER_ECHO * (k + 1)] = False
    return x[keep]


@njit(**JIT)
def _with_room(x, extra):
    out = np.empty(x.size + extra)
    out[:x.size] = x
    return out


@njit(**JIT)
def drop_unneeded_echoes(p, shape, best, lower, upper, n_echoes, times, target, raw, weights, first, last,
                         pulse_fwhm, noise):
    """Drop flagged echoes, weakest first, while a refit without one raises chi^2 by no more than
    the BIC's price of an echo. Returns (best, lower, upper, n_echoes, dropped, Jacobians)."""
    penalty = (3 if p.alpha_fixed else PARAMS_PER_ECHO) * math.log(times.size)
    chi2 = np.nan  # computed once an echo is flagged: most fits have none
    dropped = 0
    n_jacobians = 0
    while n_echoes > 0:
        reasons = spurious_reasons(best, n_echoes, first, last, pulse_fwhm, noise, p)
        flagged = np.flatnonzero(reasons != KEPT)
        if flagged.size == 0:
            break
        if np.isnan(chi2):
            chi2 = squared_error(best, n_echoes, times, shape, raw, weights)
        amplitude = best[1 + PARAMS_PER_ECHO * flagged]
        removed = False
        for k in flagged[np.argsort(amplitude)]:
            reduced = _without_echo(best, k)
            reduced_lower, reduced_upper = _without_echo(lower, k), _without_echo(upper, k)
            _, used, _ = levenberg_marquardt(reduced, n_echoes - 1, times, shape, target, weights, reduced_lower,
                                             reduced_upper, p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance,
                                             p.lm_predicted_stop)
            n_jacobians += used
            reduced_chi2 = squared_error(reduced, n_echoes - 1, times, shape, raw, weights)
            if reduced_chi2 - chi2 <= penalty:
                best, lower, upper, chi2 = reduced, reduced_lower, reduced_upper, reduced_chi2
                n_echoes -= 1
                dropped += 1
                removed = True
                break
        if not removed:
            break
    return best, lower, upper, n_echoes, dropped, n_jacobians


@njit(**JIT)
def _residual_peak(standard, residual, valid, w, first, last, score, floor):
    """Where in [first, last] the standardized residual, smoothed with the pulse weights `w`, rises highest
    above `score` with an echo height of at least `floor`: (its sample, the echo's height), (-1, 0) if nowhere."""
    n = standard.size
    peak = -1
    amplitude = 0.0
    evidence = np.empty(n)  # the standardized residual smoothed with the pulse: its sums, then / norms
    norms = np.empty(n)
    weighted_sums(standard, valid, w, evidence, norms)
    for i in range(first, last + 1):
        if not valid[i]:
            continue
        smoothed = smoothed_value(evidence[i], norms[i], standard[i])
        if smoothed > score:
            # a pulse-wide echo smoothed by the pulse's own width keeps 1/sqrt(2) of its height
            echo = smoothed_sample(residual, valid, w, i) * math.sqrt(2.0)
            if echo >= floor:
                score = smoothed
                peak = i
                amplitude = echo
    return peak, amplitude


@njit(**JIT)
def add_missing_echoes(p, shape, best, lower, upper, n_echoes, samples, valid, times, target, raw, weights, first, last,
                       pulse_sigma, noise):
    """Where the residual, matched-filtered with the system pulse, rises above the noise threshold and its
    height clears the filter's weak-echo floor, try one more echo there; keep it when chi^2 falls by more
    than its BIC price. At most p.max_added_echoes. Returns (best, lower, upper, n_echoes, added, Jacobians)."""
    if p.max_added_echoes == 0 or n_echoes >= p.max_echoes:  # fast adds none: not even its residual's filter
        return best, lower, upper, n_echoes, 0, 0
    penalty = (3 if p.alpha_fixed else PARAMS_PER_ECHO) * math.log(times.size)
    chi2 = np.nan  # computed once a candidate is found: most fits have none
    n = samples.size
    model = np.empty(times.size)
    residual = np.zeros(n)
    standard = np.zeros(n)
    # the noise of a Gaussian-smoothed white residual: sqrt(sum w^2) / sum w
    w = gaussian_weights(pulse_sigma)
    filtered_noise = math.sqrt(np.sum(w * w)) / np.sum(w)
    added = 0
    n_jacobians = 0
    while added < p.max_added_echoes and n_echoes < p.max_echoes:
        individual_model(best, n_echoes, times, shape, model)
        score = p.noise_threshold * filtered_noise
        top = -np.inf
        highest = 0.0  # the residual's largest sample (0 where invalid)
        spread = 0.0  # and its largest magnitude
        for j in range(times.size):
            i = int(times[j])
            residual[i] = raw[j] - model[j]
            standard[i] = residual[i] * weights[j]
            top = max(top, standard[i])
            highest = max(highest, residual[i])
            spread = max(spread, abs(residual[i]))
        if top <= score:
            break  # a smoothing (a weighted mean) of the standardized residual cannot rise above its largest sample
        # an echo the filter would call weak is not a missed return: only candidates above its floor
        largest = 0.0
        for k in range(n_echoes):
            largest = max(largest, best[1 + PARAMS_PER_ECHO * k])
        floor = max(p.min_amplitude_ratio * largest, p.add_min_snr * noise)
        if (highest + 1e-9 * spread) * math.sqrt(2.0) < floor:
            break  # nor can the residual's smoothing rise above its largest sample (within its rounding)
        peak, amplitude = _residual_peak(standard, residual, valid, w, first, last, score, floor)
        if peak < 0:
            break
        d = best.size
        trial = _with_room(best, PARAMS_PER_ECHO)
        trial_lower = _with_room(lower, PARAMS_PER_ECHO)
        trial_upper = _with_room(upper, PARAMS_PER_ECHO)
        scratch = np.empty(d + PARAMS_PER_ECHO)
        # the residual's peak is where the echo, widened by the smoothing, peaks; a tabulated echo's position
        # is its lobe's centroid
        position = peak - table_peak_offset(shape, math.hypot(shape.s_min, pulse_sigma))
        echo_bounds(amplitude, position, pulse_sigma, amplitude, noise, first, last, p.alpha_fixed, p.alpha_min,
                    p.alpha_max, shape, d, trial, trial_lower, scratch, trial_upper)
        _, used, _ = levenberg_marquardt(trial, n_echoes + 1, times, shape, target, weights, trial_lower, trial_upper,
                                         p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance,
                                         p.lm_predicted_stop)
        n_jacobians += used
        trial_chi2 = squared_error(trial, n_echoes + 1, times, shape, raw, weights)
        if np.isnan(chi2):
            chi2 = squared_error(best, n_echoes, times, shape, raw, weights)
        if chi2 - trial_chi2 <= penalty:
            break
        best, lower, upper, chi2 = trial, trial_lower, trial_upper, trial_chi2
        n_echoes += 1
        added += 1
    return best, lower, upper, n_echoes, added, n_jacobians
