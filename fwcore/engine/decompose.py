"""Decompose waveforms: the orchestration of the engine's steps, and its Python API.

    initial estimate -> bounds -> optimizer -> model-order selection -> raw polish -> filter -> metrics

`decompose_batch(batch, config, pulse)` is the entry point: many waveforms of
any lengths, under the method's settings (`config`) and their file's system
pulse (fwcore.instrument.pulse.SystemPulse), in chunks on a pool of threads (the
kernels release the GIL), each waveform with its own random stream, so a
waveform's result does not depend on its batch or the thread count.
`decompose_waveform` is the same for one waveform. Each step is a kernel of its own module
(fwcore.engine.estimate over .smoothing, .bounds, .optimizers, .selection, .filter); this module only wires them.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from fwcore._jit import JIT, bind_libm_cores
from fwcore.engine.bounds import parameter_bounds
from fwcore.engine.config import LOCAL_LM, LOCAL_NONE, MSG_CONVERGED, OPT_NONE, DecompositionConfig, Model, Optimizer
from fwcore.engine.filter import mark_spurious
from fwcore.instrument.pulse import SystemPulse
from fwcore.instrument.shape import echo_shape
from fwcore.engine.model import (PARAMS_PER_ECHO, SQRT_2LN2, EchoShape, analytic_shape, echo_energy, echo_positions_of,
                                 fwhm, individual_model, tabulated_areas)
from fwcore.engine.optimizers import find_own_echoes, run_optimizer
from fwcore.engine.optimizers.local import levenberg_marquardt, squared_error
from fwcore.engine.estimate import initial_estimate
from fwcore.engine.records import (ECHO_RESULT, STATUS_NO_VALID_SAMPLES, STATUS_NON_FINITE, WAVEFORM_RESULT,
                            BatchDecomposition, Decomposition, WaveformBatch)
from fwcore.engine.noise_model import add_shot_noise, noise_variance
from fwcore.engine.selection import LOCAL_MIN_SAMPLES, add_missing_echoes, drop_unneeded_echoes
from fwcore.engine.strong_echo import strong_echo_fit

_LN2 = math.log(2.0)
_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2
# On a long record (LOCAL_MIN_SAMPLES samples or more: GEDI, LVIS) the generalized Gaussian's LM fits evaluate an echo
# only where it is above TAIL_FLOOR x the noise sigma (and 1e-3 of its amplitude): its 1e-12 reach, 58 half widths
# at alpha 1, covered 61 % of a GEDI savanna window's samples per echo, 37 % so (docs/benchmarks.md). A tail below
# 1e-3 sigma moves chi^2 by less than 1e-6 a sample. Leica's, RIEGL's and NEON's short records keep the 1e-12 reach.
TAIL_FLOOR = 1e-3


@njit(**JIT)
def _valid_arrays(samples, smoothed, valid, fit_denoised):
    """Times, fit target and raw values of the valid samples."""
    m = 0
    for i in range(samples.size):
        m += valid[i]
    times = np.empty(m)
    fit_target = np.empty(m)
    raw = np.empty(m)
    j = 0
    for i in range(samples.size):
        if valid[i]:
            times[j] = i
            fit_target[j] = smoothed[i] if fit_denoised else samples[i]
            raw[j] = samples[i]
            j += 1
    return times, fit_target, raw


@njit(**JIT)
def _measure(best, n_echoes, samples, smoothed, valid, times, shape, out):
    """The reported metrics, exact (float64, libm), against the denoised (Eq. 9) and raw samples; `times` are the
    valid samples' (_valid_arrays'): the model at them only, nothing else is read (GEDI's and LVIS's noise)."""
    n = samples.size
    m = times.size
    mean = 0.0
    for i in range(n):
        if valid[i]:
            mean += samples[i]
    mean /= m
    model = np.empty(m)
    individual_model(best, n_echoes, times, shape, model)
    err_denoised = 0.0
    err_raw = 0.0
    ss_res = 0.0
    ss_tot = 0.0
    j = 0
    for i in range(n):
        if valid[i]:
            err_denoised += abs(model[j] - smoothed[i])
            r = model[j] - samples[i]
            j += 1
            err_raw += abs(r)
            ss_res += r * r
            ss_tot += (samples[i] - mean) ** 2
    out.fit_error = err_denoised
    out.fit_error_raw = err_raw
    out.rmse = math.sqrt(ss_res / m)
    out.r2 = 1.0 - ss_res / ss_tot if ss_tot > 0.0 else 0.0


@njit(**JIT)
def _write_echoes(best, n_echoes, first, last, pulse_fwhm, noise, p, shape, echoes):
    """The echoes sorted by position, in Chauve's parameters (an echo of the tabulated response: its
    equal-FWHM sigma, alpha NaN), each with the filter's reason."""
    order = np.argsort(echo_positions_of(best, n_echoes))
    widths = np.empty(n_echoes)
    for j in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * order[j]
        a, u, s, alpha = best[base], best[base + 1], best[base + 2], best[base + 3]
        h = s * SQRT_2LN2
        echoes[j].amplitude = a
        echoes[j].position = u
        if shape.tabulated:
            echoes[j].sigma = s
            echoes[j].alpha = np.nan
        else:
            echoes[j].sigma = math.sqrt(h ** (alpha * alpha) / (2.0 * _LN2))
            echoes[j].alpha = alpha
        widths[j] = 2.0 * h
    reasons = np.zeros(n_echoes, dtype=np.int8)
    mark_spurious(echoes.amplitude[:n_echoes].copy(), echoes.position[:n_echoes].copy(), widths, first, last,
                  pulse_fwhm, noise, p, reasons)
    for j in range(n_echoes):
        echoes[j].reason = reasons[j]


@njit(**JIT)
def _with_tail_floor(shape, tail_floor):
    """The shape with its generalized Gaussian's tails cut at `tail_floor` counts (fwcore.engine.model.EchoShape)."""
    return EchoShape(shape.tabulated, shape.rows, shape.slopes, shape.areas, shape.support, shape.peak_offsets,
                     shape.half_widths, shape.step, shape.origin, shape.s_min, shape.s_step, tail_floor)


@njit(**JIT)
def _valid_span(valid):
    """The first and last valid sample."""
    first = 0
    while not valid[first]:
        first += 1
    last = valid.size - 1
    while not valid[last]:
        last -= 1
    return first, last


@njit(**JIT)
def _parameter_scale(smoothed, valid, background):
    """The scale below which a parameter's change is nothing: 1e-6 of the highest |denoised - background|."""
    peak = 0.0
    for i in range(smoothed.size):
        if valid[i]:
            peak = max(peak, abs(smoothed[i] - background))
    return max(1e-6 * peak, 1e-12)


@njit(**JIT)
def _raw_polish(best, n_echoes, times, shape, raw, weights, lower, local_upper, p):
    """The smoothing bends steep rises (NEON): where the fit to the denoised target fails the noise model on the
    raw samples, LM refits it to them from where it is, with the same echoes; returns the evaluations used."""
    chi2 = squared_error(best, n_echoes, times, shape, raw, weights)
    if not chi2 / max(times.size - best.size, 1) > p.raw_polish_gate:  # NaN too: no polish, as before
        return 0
    _, used, _ = levenberg_marquardt(best, n_echoes, times, shape, raw, weights, lower, local_upper,
                                     p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance,
                                     p.lm_predicted_stop)
    return used


@njit(**JIT)
def _select_echoes(p, shape, best, lower, upper, n_echoes, samples, valid, times, fit_target, raw, signal, variance,
                   weights, first, last, pulse_sigma, pulse_fwhm, noise):
    """Model-order selection after the optimizer (fwcore.engine.selection), under the noise model with its
    Poisson-like term where p.signal_dependent_noise. Returns (best, lower, upper, n_echoes, weights, dropped,
    added, Jacobians)."""
    nfev = 0
    if p.local == LOCAL_NONE:  # a population's best is not at the least-squares optimum the refits compare with
        _, used, _ = levenberg_marquardt(best, n_echoes, times, shape, fit_target, weights, lower, upper,
                                         p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance, p.lm_predicted_stop)
        nfev += used
    if p.signal_dependent_noise:
        add_shot_noise(best, n_echoes, times, shape, raw, signal, variance)
        weights = 1.0 / np.sqrt(variance)
    best, lower, upper, n_echoes, dropped, used = drop_unneeded_echoes(
        p, shape, best, lower, upper, n_echoes, times, fit_target, raw, weights, first, last, pulse_fwhm, noise,
        samples.size)
    nfev += used
    best, lower, upper, n_echoes, added, used = add_missing_echoes(
        p, shape, best, lower, upper, n_echoes, samples, valid, times, fit_target, raw, weights, first, last,
        pulse_sigma, noise)
    return best, lower, upper, n_echoes, weights, dropped, added, nfev + used


@njit(**JIT)
def _decompose_one(samples, valid, smoothing_sigma, pulse_sigma, noise_floor, seed, p, shape, out, echoes):
    """One waveform end to end into its result record `out` and echo records `echoes`."""
    n = samples.size
    first, last = _valid_span(valid)
    pulse_fwhm = pulse_sigma * _FWHM_PER_SIGMA

    smoothed = np.empty(n)
    amp0 = np.zeros(p.max_echoes)
    pos0 = np.zeros(p.max_echoes)
    sig0 = np.zeros(p.max_echoes)
    noise, background, n_echoes = initial_estimate(samples, valid, smoothing_sigma, pulse_sigma, p, shape, smoothed,
                                                   amp0, pos0, sig0, noise_floor)
    if n >= LOCAL_MIN_SAMPLES and not shape.tabulated:
        shape = _with_tail_floor(shape, TAIL_FLOOR * noise)
    n_initial = n_echoes
    times, fit_target, raw = _valid_arrays(samples, smoothed, valid, p.fit_denoised)
    variance = np.empty(times.size)
    noise_variance(smoothed, valid, background, noise, p.shape_tolerance, variance)
    weights = 1.0 / np.sqrt(variance)
    signal = np.empty(times.size)  # the smoothed height above background, where shot noise arises
    for j in range(times.size):
        signal[j] = max(smoothed[int(times[j])] - background, 0.0)

    scale = _parameter_scale(smoothed, valid, background)
    d = 1 + PARAMS_PER_ECHO * n_echoes
    x0 = np.empty(d)
    lower = np.empty(d)
    upper = np.empty(d)
    local_upper = np.empty(d)
    parameter_bounds(background, noise, amp0[:n_echoes], pos0[:n_echoes], sig0[:n_echoes], smoothed, first, last,
                     p.alpha_fixed, p.alpha_min, p.alpha_max, shape, scale, x0, lower, upper, local_upper)

    # LM's methods with the selection (the default's lm-mde, fast's lm) may fit a strong echo alone
    alone, alone_lower, alone_upper, nfev, strong = strong_echo_fit(
        p.strong_echo_fit and p.select_echoes and p.local == LOCAL_LM and (p.search_where_local_fails or not p.search),
        p, shape, x0, lower, local_upper, n_echoes, times, fit_target, raw, weights, first, last, pulse_fwhm, noise)
    if strong:  # nothing for the optimizer to do
        best, nit, message = alone, 0 if p.search else nfev, MSG_CONVERGED
    elif p.own_echoes:  # the patent's GA and deconvolution choose their echoes themselves
        best, n_echoes, n_initial, nfev, nit, message = find_own_echoes(
            p, shape, samples, valid, smoothed, background, noise, first, last, times, fit_target, raw, weights,
            pulse_sigma, seed)
    else:
        eps = 0.02 * max(noise, scale)  # truncation adds < 2% of the noise per sample to the fitness
        fit_samples = smoothed if p.fit_denoised else samples
        spent = nfev
        best, nfev, nit, message = run_optimizer(p, shape, x0, lower, upper, local_upper, n_echoes, fit_samples, valid,
                                                 times, fit_target, raw, signal, variance, noise, eps, seed)
        nfev += spent  # the strong echo's fit that did not stand

    dropped = 0
    added = 0
    if strong:  # the candidates beside it set aside unfitted; the selection may still add what the residual holds
        lower, local_upper, dropped, n_echoes = alone_lower, alone_upper, n_echoes - 1, 1
    if p.select_echoes and p.method != OPT_NONE and not p.own_echoes:
        best, lower, local_upper, n_echoes, weights, dropped_here, added, used = _select_echoes(
            p, shape, best, lower, local_upper, n_echoes, samples, valid, times, fit_target, raw, signal, variance,
            weights, first, last, pulse_sigma, pulse_fwhm, noise)
        dropped += dropped_here
        nfev += used

    if p.raw_polish and p.fit_denoised and n_echoes > 0 and p.method != OPT_NONE and not p.own_echoes:
        nfev += _raw_polish(best, n_echoes, times, shape, raw, weights, lower, local_upper, p)
    out.background = best[0]
    out.noise_sigma = noise
    out.nfev = nfev
    out.nit = nit
    out.message = message
    out.n_echoes_initial = n_initial
    out.n_echoes_dropped = dropped
    out.n_echoes_added = added
    out.n_echoes = n_echoes
    _measure(best, n_echoes, samples, smoothed, valid, times, shape, out)
    _write_echoes(best, n_echoes, first, last, pulse_fwhm, noise, p, shape, echoes)


@njit(**JIT)
def _decompose_range(samples, valid, offsets, status, smoothing_sigma, pulse_sigma, noise_floor, seeds, p, shape,
                     out, echoes, first, stop):
    """Waveforms first..stop-1 of the batch (those of status 0), each into its own records."""
    for w in range(first, stop):
        if status[w] != 0:
            continue
        lo, hi = offsets[w], offsets[w + 1]
        _decompose_one(samples[lo:hi], valid[lo:hi], smoothing_sigma[w], pulse_sigma[w], noise_floor[w], seeds[w], p,
                       shape, out[w], echoes[w])


# ---------------------------------------------------------------- Python API

def pulse_sigma_samples(pulse: SystemPulse, sample_spacing_ps: np.ndarray) -> np.ndarray:
    """The system pulse's Gaussian sigma in samples of each waveform."""
    return pulse.fwhm_ps / _FWHM_PER_SIGMA / np.asarray(sample_spacing_ps, dtype=float)


def smoothing_sigma_samples(config: DecompositionConfig, pulse: SystemPulse,
                            sample_spacing_ps: np.ndarray) -> np.ndarray:
    """The denoising filter's sigma in samples: explicit, or tied to the system pulse."""
    spacing = np.asarray(sample_spacing_ps, dtype=float)
    if config.smoothing_sigma_ps is not None:
        return np.full(spacing.shape, config.smoothing_sigma_ps) / spacing
    return config.smoothing_factor * pulse_sigma_samples(pulse, spacing)


@njit(**JIT)
def _check_samples(samples, valid, offsets, status, kernel_samples):
    """Each waveform's status (waveform_status) and the samples the kernels read (0 where invalid or not finite),
    in one pass: on 62-sample RIEGL pulses NumPy's masks and cumulative sums cost 0.3-0.5 us a pulse."""
    for i in range(samples.size):
        kernel_samples[i] = samples[i] if valid[i] and np.isfinite(samples[i]) else 0.0
    for w in range(status.size):
        any_valid = False
        finite = True
        for i in range(offsets[w], offsets[w + 1]):
            if valid[i]:
                any_valid = True
                finite = finite and np.isfinite(samples[i])
        status[w] = STATUS_NO_VALID_SAMPLES if not any_valid else (0 if finite else STATUS_NON_FINITE)


def checked_samples(batch: WaveformBatch) -> tuple[np.ndarray, np.ndarray]:
    """(per waveform, why it cannot be decomposed: STATUS_REASONS codes, 0: it can; the batch's samples as the
    kernels read them: 0 where invalid or not finite, so that they never reach the kernels' sums)."""
    status = np.empty(len(batch), dtype=np.int8)
    kernel_samples = np.empty(batch.samples.shape, dtype=np.result_type(batch.samples, 0.0))
    _check_samples(batch.samples, batch.valid, batch.offsets, status, kernel_samples)
    return status, kernel_samples


def waveform_status(batch: WaveformBatch) -> np.ndarray:
    """Per waveform, why it cannot be decomposed (STATUS_REASONS codes; 0: it can)."""
    return checked_samples(batch)[0]


_CHUNK = 256  # waveforms per task at most, and 8 tasks per thread at least: slow ones (MDE) even out


def _in_threads(kernel_args: tuple, n: int, threads: int) -> None:
    """_decompose_range over waveforms 0..n-1 in chunks on `threads` threads. The kernel releases the GIL;
    a thread pool rather than numba's prange, whose parallel compile took 35 s of the engine's 120."""
    if threads <= 1 or n <= 1:
        _decompose_range(*kernel_args, 0, n)
        return
    chunk = max(1, min(_CHUNK, n // (8 * threads)))
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda first: _decompose_range(*kernel_args, first, min(first + chunk, n)),
                      range(0, n, chunk)))


def decompose_batch(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse,
                    threads: int | None = None) -> BatchDecomposition:
    """Decompose every waveform of the batch with the method's settings `config` and the system pulse of the
    waveforms' file `pulse`, on `threads` threads (default: numba's thread count, all cores).

    A waveform with non-finite valid samples, or with no valid sample, is not
    decomposed: its status says why and it has no echoes. Under the system model the echoes have the
    shape of pulse.echo_response() at each waveform's sample spacing (one table per spacing).
    """
    bind_libm_cores()  # before the kernels below are linked: libm's cores, not its wrappers (the same bits)
    n = len(batch)
    status, samples = checked_samples(batch)
    out = np.zeros(n, dtype=WAVEFORM_RESULT)
    out["status"] = status
    echoes = np.zeros((n, config.max_echoes), dtype=ECHO_RESULT)
    shapes = echo_shapes(config, pulse, batch.sample_spacing_ps)
    noise_floor = np.zeros(n) if batch.noise_floor is None else np.nan_to_num(batch.noise_floor.astype(np.float64))
    params = config.kernel_params(pulse.echo_model(config.model), pulse.shape_tolerance)
    for shape, spacings in _shape_groups(shapes):
        # the kernel skips waveforms whose status is not 0: those of other shapes wait their turn
        group = status if len(spacings) == len(shapes) else np.where(np.isin(batch.sample_spacing_ps, spacings),
                                                                      status, -1)
        kernel_args = (samples, batch.valid, batch.offsets, group.astype(np.int8),
                       smoothing_sigma_samples(config, pulse, batch.sample_spacing_ps),
                       pulse_sigma_samples(pulse, batch.sample_spacing_ps), noise_floor, batch.seeds, params,
                       shape, out, echoes)
        _in_threads(kernel_args, n, threads or numba.config.NUMBA_NUM_THREADS)
    counts = out["n_echoes"]
    echo_offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=echo_offsets[1:])
    flat = echoes[np.arange(config.max_echoes)[None, :] < counts[:, None]]
    sigma, alpha = flat["sigma"], flat["alpha"]
    if uses_response(config, pulse):
        width = sigma * _FWHM_PER_SIGMA  # a tabulated echo's sigma is that of the Gaussian of equal FWHM
        echo_spacing = batch.sample_spacing_ps[np.repeat(np.arange(n), counts)]
        energy = np.empty(sigma.size)
        for spacing, shape in shapes.items():
            at = echo_spacing == spacing
            energy[at] = flat["amplitude"][at] * tabulated_areas(shape, sigma[at])
    else:
        width = fwhm(sigma, alpha)
        energy = echo_energy(flat["amplitude"], sigma, alpha)
    return BatchDecomposition(
        out, echo_offsets=echo_offsets, amplitude=flat["amplitude"], position=flat["position"], sigma=sigma,
        alpha=alpha, fwhm=width, energy=energy, reject=flat["reason"],
        shapes=shapes if uses_response(config, pulse) else None, sample_spacing_ps=batch.sample_spacing_ps)


def uses_response(config: DecompositionConfig, pulse: SystemPulse) -> bool:
    """Whether echoes take the system response's shape: the system model (the file's, under auto), except in
    the patent's GA, whose method is defined on Gaussians."""
    return pulse.echo_model(config.model) is Model.SYSTEM and config.optimizer is not Optimizer.GA_ITERATIVE


# spacings equal to this many significant digits share one echo table: LVIS's differ from shot to shot in the
# seventh (its Z0..Z1023 and incidence give each its own, 1 ns within 1e-6), and a table a shot cost 0.3 s each
SHAPE_SPACING_DIGITS = 6


def echo_shapes(config: DecompositionConfig, pulse: SystemPulse,
                sample_spacing_ps: np.ndarray) -> dict[float, EchoShape]:
    """The kernels' echo shape for each distinct sample spacing of a batch: one object for all spacings (the
    analytic shape), or a table for each spacing to SHAPE_SPACING_DIGITS digits, shared by the spacings it rounds."""
    spacings = [float(s) for s in np.unique(sample_spacing_ps)] or [1000.0]
    if not uses_response(config, pulse):
        shape = analytic_shape()
        return {s: shape for s in spacings}
    response = pulse.echo_response()
    tables: dict[float, EchoShape] = {}
    for s in spacings:
        key = float(f"{s:.{SHAPE_SPACING_DIGITS}g}")
        if key not in tables:  # rows one FWHM wider than the filter's limit, so that a too-wide echo can show as one
            tables[key] = echo_shape(response, key, config.max_width_factor + 1.0)
    return {s: tables[float(f"{s:.{SHAPE_SPACING_DIGITS}g}")] for s in spacings}


def _shape_groups(shapes: dict[float, EchoShape]) -> list[tuple[EchoShape, list[float]]]:
    """The distinct shapes of echo_shapes, each with the spacings it serves (one kernel pass per shape)."""
    groups: dict[int, tuple[EchoShape, list[float]]] = {}
    for spacing, shape in shapes.items():
        groups.setdefault(id(shape), (shape, []))[1].append(spacing)
    return list(groups.values())


def decompose_waveform(samples, sample_spacing_ps: float = 1000.0, seed: int = 0,
                       config: DecompositionConfig = DecompositionConfig(), valid=None, *,
                       pulse: SystemPulse) -> Decomposition:
    """Decompose one waveform (the batch engine with a batch of one: identical results)."""
    batch = WaveformBatch.from_waveforms([np.asarray(samples, dtype=float)], sample_spacing_ps, [seed],
                                         None if valid is None else [valid])
    return decompose_batch(batch, config, pulse).waveform(0)
