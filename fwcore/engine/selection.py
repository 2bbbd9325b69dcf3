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

On a long waveform of many echoes (LVIS, GEDI over tall canopy: a thousand
samples, a dozen echoes; at least LOCAL_MIN_SAMPLES) a candidate's refit is local: only the echoes whose
reach meets the dropped (or added) echo's move, over the samples they reach,
with the other echoes and the background held in the model; chi^2 is still
that of the whole waveform. Where any candidate was kept that way, one LM
refit of every echo from there ends the step, so the result is again a joint
least-squares fit; a waveform of few echoes refits all of them as before.

On a long record (at least LOCAL_MIN_SAMPLES samples, whatever its valid window: GEDI, LVIS) a drop candidate's
refit is screened: after SCREEN_ITERATIONS LM steps, a candidate whose chi^2 is still far above the BIC's price
stays without the rest of its refit (most such refits end far above it; docs/benchmarks.md).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.bounds import echo_bounds
from fwcore.engine.filter import KEPT, mark_spurious
from fwcore.engine.model import (PARAMS_PER_ECHO, SQRT_2LN2, echo_positions_of, individual_model, table_reach,
                                 table_peak_offset)
from fwcore.engine.optimizers.local import levenberg_marquardt, squared_error
from fwcore.engine.smoothing import gaussian_weights, smoothed_sample, smoothed_value, weighted_sums
from fwcore._jit import searchsorted

# an echo's reach for a local refit: where it falls below 2**-LOCAL_REACH_BITS of its height (the held echoes
# stay in the model, so this only says which echoes move: those whose reach meets the candidate's)
LOCAL_REACH_BITS = 10.0
# a local refit where the moving echoes reach at most this share of the waveform's samples, on waveforms of at
# least LOCAL_MIN_SAMPLES valid samples (LVIS's 1024, GEDI's 700-1400): on short ones (Leica's 256, RIEGL's 80)
# a full refit costs little and their echoes stay those measured against the accuracy bars
LOCAL_MAX_SHARE = 0.5
LOCAL_MIN_SAMPLES = 512
# On a waveform of at least LOCAL_MIN_SAMPLES samples (GEDI's 700-1400, LVIS's 1024, whatever their signal window), a
# drop candidate's refit first runs SCREEN_ITERATIONS LM steps; a candidate still SCREEN_MARGIN x the BIC's price of
# an echo above the price then is kept without more (GEDI savanna, LVIS clip: such a refit came under the price in
# 3 and 9 % of cases, after 6-30 more Jacobians); the others refit to convergence as before.
SCREEN_ITERATIONS = 5
SCREEN_MARGIN = 2.5



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
def echo_reach(x, k, shape):
    """The times between which echo k of individual x is above 2**-LOCAL_REACH_BITS of its height (a tabulated
    echo: its table's support)."""
    base = 1 + PARAMS_PER_ECHO * k
    u, s = x[base + 1], x[base + 2]
    if shape.tabulated:
        before, after = table_reach(shape, s)
        return u - before, u + after
    reach = s * SQRT_2LN2 * LOCAL_REACH_BITS ** (1.0 / (x[base + 3] * x[base + 3]))
    return u - reach, u + reach


@njit(**JIT)
def local_refit(p, shape, x, n_echoes, start, stop, times, target, weights, lower, upper):
    """LM refit, in place, of the echoes of x whose reach meets [start, stop] (times), over the samples their
    reaches cover, with the background and the other echoes held in the model. Returns the Jacobians
    evaluated, or -1 (x untouched) where the waveform has p.local_refit_echoes echoes or fewer or fewer than
    LOCAL_MIN_SAMPLES valid samples, or the moving ones reach more than LOCAL_MAX_SHARE of its samples: a full
    refit is then as cheap."""
    if n_echoes <= p.local_refit_echoes or times.size < LOCAL_MIN_SAMPLES:
        return -1
    near = np.zeros(n_echoes, dtype=np.bool_)
    lo_t, hi_t = start, stop
    for j in range(n_echoes):
        a, b = echo_reach(x, j, shape)
        if b >= start and a <= stop:
            near[j] = True
            lo_t, hi_t = min(lo_t, a), max(hi_t, b)
    n_near = int(np.sum(near))
    lo, hi = searchsorted(times, lo_t), searchsorted(times, hi_t, right=True)
    if n_near == 0 or n_near == n_echoes or hi - lo > LOCAL_MAX_SHARE * times.size:
        return -1
    held = x.copy()  # the model's fixed part: the background and the echoes that do not move
    local = np.zeros(1 + PARAMS_PER_ECHO * n_near)  # the background 0 and held: it is in `held`
    local_lower, local_upper = local.copy(), local.copy()
    q = 0
    for j in range(n_echoes):
        if not near[j]:
            continue
        base, to = 1 + PARAMS_PER_ECHO * j, 1 + PARAMS_PER_ECHO * q
        held[base] = 0.0  # an echo of amplitude 0 adds nothing to individual_model
        local[to:to + PARAMS_PER_ECHO] = x[base:base + PARAMS_PER_ECHO]
        local_lower[to:to + PARAMS_PER_ECHO] = lower[base:base + PARAMS_PER_ECHO]
        local_upper[to:to + PARAMS_PER_ECHO] = upper[base:base + PARAMS_PER_ECHO]
        q += 1
    sub = times[lo:hi]
    fixed = np.empty(sub.size)
    individual_model(held, n_echoes, sub, shape, fixed)
    _, used, _ = levenberg_marquardt(local, n_near, sub, shape, target[lo:hi] - fixed, weights[lo:hi], local_lower,
                                     local_upper, p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance,
                                     p.lm_predicted_stop)
    q = 0
    for j in range(n_echoes):
        if near[j]:
            base, to = 1 + PARAMS_PER_ECHO * j, 1 + PARAMS_PER_ECHO * q
            x[base:base + PARAMS_PER_ECHO] = local[to:to + PARAMS_PER_ECHO]
            q += 1
    return used


@njit(**JIT)
def _refit(p, shape, x, n_echoes, start, stop, times, target, weights, lower, upper):
    """A candidate's refit: local (local_refit) where that is worth it, else of every echo. Returns
    (Jacobians, whether it was local)."""
    used = local_refit(p, shape, x, n_echoes, start, stop, times, target, weights, lower, upper)
    if used >= 0:
        return used, True
    _, used, _ = levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper, p.lm_iterations,
                                     p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
    return used, False


@njit(**JIT)
def _screened_refit(p, shape, x, n_echoes, start, stop, times, target, raw, weights, lower, upper, limit):
    """A drop candidate's refit on a long waveform (_refit's first, then SCREEN_ITERATIONS LM steps; the rest of
    the LM only where chi^2 on the raw samples is then within `limit`): (Jacobians, whether it was local, chi^2)."""
    used = local_refit(p, shape, x, n_echoes, start, stop, times, target, weights, lower, upper)
    if used >= 0:
        return used, True, squared_error(x, n_echoes, times, shape, raw, weights)
    _, used, done = levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper, SCREEN_ITERATIONS,
                                        p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
    chi2 = squared_error(x, n_echoes, times, shape, raw, weights)
    if done or chi2 > limit:
        return used, False, chi2
    _, more, _ = levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper,
                                     max(p.lm_iterations - SCREEN_ITERATIONS, 1), p.lm_tolerance,
                                     p.lm_chi2_tolerance, p.lm_predicted_stop)
    return used + more, False, squared_error(x, n_echoes, times, shape, raw, weights)


@njit(**JIT)
def _joint_polish(p, shape, x, n_echoes, times, target, weights, lower, upper):
    """One LM refit of every echo after local refits were kept: the fit is joint again. Returns Jacobians."""
    _, used, _ = levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper, p.lm_iterations,
                                     p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
    return used


@njit(**JIT)
def drop_unneeded_echoes(p, shape, best, lower, upper, n_echoes, times, target, raw, weights, first, last,
                         pulse_fwhm, noise, n_samples=0):
    """Drop flagged echoes, weakest first, while a refit without one raises chi^2 by no more than
    the BIC's price of an echo; on a waveform of n_samples >= LOCAL_MIN_SAMPLES samples a candidate far above it
    after a few LM steps stays (_screened_refit). Returns (best, lower, upper, n_echoes, dropped, Jacobians)."""
    penalty = (3 if p.alpha_fixed else PARAMS_PER_ECHO) * math.log(times.size)
    chi2 = np.nan  # computed once an echo is flagged: most fits have none
    dropped = 0
    n_jacobians = 0
    kept_local = False
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
            start, stop = echo_reach(best, k, shape)
            if n_samples >= LOCAL_MIN_SAMPLES:
                used, local, reduced_chi2 = _screened_refit(p, shape, reduced, n_echoes - 1, start, stop, times,
                                                            target, raw, weights, reduced_lower, reduced_upper,
                                                            chi2 + (1.0 + SCREEN_MARGIN) * penalty)
            else:
                used, local = _refit(p, shape, reduced, n_echoes - 1, start, stop, times, target, weights,
                                     reduced_lower, reduced_upper)
                reduced_chi2 = squared_error(reduced, n_echoes - 1, times, shape, raw, weights)
            n_jacobians += used
            if reduced_chi2 - chi2 <= penalty:
                best, lower, upper, chi2 = reduced, reduced_lower, reduced_upper, reduced_chi2
                n_echoes -= 1
                dropped += 1
                removed = True
                kept_local = kept_local or local
                break
        if not removed:
            break
    if kept_local:
        n_jacobians += _joint_polish(p, shape, best, n_echoes, times, target, weights, lower, upper)
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
    residual = np.zeros(0)  # made (zeros where invalid) once a residual rises above the score: most fits have none
    standard = np.zeros(0)
    # the noise of a Gaussian-smoothed white residual: sqrt(sum w^2) / sum w
    w = gaussian_weights(pulse_sigma)
    filtered_noise = math.sqrt(np.sum(w * w)) / np.sum(w)
    added = 0
    n_jacobians = 0
    kept_local = False
    while added < p.max_added_echoes and n_echoes < p.max_echoes:
        individual_model(best, n_echoes, times, shape, model)
        score = p.noise_threshold * filtered_noise
        top = -np.inf
        highest = 0.0  # the residual's largest sample (0 where invalid)
        spread = 0.0  # and its largest magnitude
        for j in range(times.size):
            r = raw[j] - model[j]
            top = max(top, r * weights[j])
            highest = max(highest, r)
            spread = max(spread, abs(r))
        if top <= score:
            break  # a smoothing (a weighted mean) of the standardized residual cannot rise above its largest sample
        if residual.size == 0:
            residual = np.zeros(n)
            standard = np.zeros(n)
        for j in range(times.size):
            i = int(times[j])
            residual[i] = raw[j] - model[j]
            standard[i] = residual[i] * weights[j]
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
        start, stop = echo_reach(trial, n_echoes, shape)
        used, local = _refit(p, shape, trial, n_echoes + 1, start, stop, times, target, weights, trial_lower,
                             trial_upper)
        n_jacobians += used
        trial_chi2 = squared_error(trial, n_echoes + 1, times, shape, raw, weights)
        if np.isnan(chi2):
            chi2 = squared_error(best, n_echoes, times, shape, raw, weights)
        if chi2 - trial_chi2 <= penalty:
            break
        best, lower, upper, chi2 = trial, trial_lower, trial_upper, trial_chi2
        n_echoes += 1
        added += 1
        kept_local = kept_local or local
    if kept_local:
        n_jacobians += _joint_polish(p, shape, best, n_echoes, times, target, weights, lower, upper)
    return best, lower, upper, n_echoes, added, n_jacobians
