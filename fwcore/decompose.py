"""Decompose waveforms: denoise, estimate, optimise, filter, measure.

`decompose_batch` is the engine's entry point: many waveforms of any lengths
in one numba-parallel call, one waveform per thread, each with its own random
stream, so a waveform's result does not depend on its batch or the thread
count. `decompose_waveform` is the same for one waveform.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numba
import numpy as np
from numba import njit, prange

from fwcore._jit import JIT, PARALLEL_JIT
from fwcore.config import DecompositionConfig, FitTarget, Model, Optimizer
from fwcore.filter import REJECT_REASONS, TOO_CLOSE, TOO_NARROW, TOO_WIDE, mark_spurious
from fwcore.model import echo_energy, fwhm, waveform_model
from fwcore.lm import lbfgs, levenberg_marquardt, squared_error
from fwcore.optimize import (LANES, OPT_DE, OPT_GA, OPT_GA_ITERATIVE, OPT_LBFGS, OPT_LM, OPT_MDE, OPT_MDE_LM,
                             OPT_NONE, OPT_PSO, PARAMS_PER_ECHO, POPULATION_METHODS, evolve, evolve_ga,
                             fit_error, init_population, swarm)
from fwcore.patent import ga_iterative
from fwcore.preprocess import _noise_sigma, _progressive_echoes, _smooth, _valid_min

_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
_LN2 = math.log(2.0)
_FWHM_PER_SIGMA = 2.0 * _SQRT_2LN2
_GAUSSIAN_ALPHA = math.sqrt(2.0)

STATUS_OK, STATUS_NO_VALID_SAMPLES, STATUS_NON_FINITE = 0, 1, 2
STATUS_REASONS = ("", "no_valid_samples", "non_finite_samples")
_OPTIMIZER_CODES = {Optimizer.NONE: OPT_NONE, Optimizer.DE: OPT_DE, Optimizer.MDE: OPT_MDE, Optimizer.GA: OPT_GA,
                    Optimizer.PSO: OPT_PSO, Optimizer.LM: OPT_LM, Optimizer.LBFGS: OPT_LBFGS,
                    Optimizer.MDE_LM: OPT_MDE_LM, Optimizer.GA_ITERATIVE: OPT_GA_ITERATIVE}


# ---------------------------------------------------------------- kernels

@njit(**JIT)
def _parameter_bounds(background, noise, amplitude, position, sigma, signal, first, last,
                      gaussian, alpha_min, alpha_max, scale, x0, lower, upper, local_upper):
    """The initial individual and box bounds around it, all physical (A >= 0, s > 0, u inside).

    The population optimizers search amplitudes up to 1.5 x the estimate; the local ones
    (local_upper) up to 1.5 x the signal's height at the echo: the progressive estimate gives a
    flank echo only what the stronger one left, and a gradient can grow it to its true height,
    where a population spread over that range would mostly split single echoes in two."""
    spread_b = max(3.0 * noise, scale)
    x0[0] = background
    lower[0] = background - spread_b
    upper[0] = background + spread_b
    for k in range(amplitude.size):
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s = amplitude[k], position[k], sigma[k]
        shift = max(1.5 * s, 2.0)
        x0[base], lower[base], upper[base] = a, 0.0, 1.5 * a + 3.0 * noise
        x0[base + 1] = u
        lower[base + 1] = max(first, u - shift)
        upper[base + 1] = min(last, u + shift)
        x0[base + 2], lower[base + 2], upper[base + 2] = s, max(0.25 * s, 0.3), 3.0 * s
        x0[base + 3] = _GAUSSIAN_ALPHA
        lower[base + 3] = _GAUSSIAN_ALPHA if gaussian else alpha_min
        upper[base + 3] = _GAUSSIAN_ALPHA if gaussian else alpha_max
    local_upper[:] = upper
    for k in range(amplitude.size):
        base = 1 + PARAMS_PER_ECHO * k
        height = signal[min(max(int(round(position[k])), 0), signal.size - 1)] - background
        local_upper[base] = 1.5 * max(amplitude[k], height) + 3.0 * noise


@njit(**JIT)
def _exact_model(x, n_echoes, n):
    """The model in float64 with libm, for the reported metrics (never the fast approximations)."""
    model = np.full(n, x[0])
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        a, u, s, alpha = x[base], x[base + 1], x[base + 2], x[base + 3]
        if a <= 0.0:
            continue
        h = s * _SQRT_2LN2
        p = alpha * alpha
        for i in range(n):
            model[i] += a * math.exp(-_LN2 * (abs(i - u) / h) ** p)
    return model


@njit(**JIT)
def _spurious_reasons(x, n_echoes, first, last, pulse_fwhm, noise, min_snr, min_amplitude_ratio,
                      min_separation_factor, min_width_factor, max_width_factor):
    """The filter's reason for each echo of individual x, in the individual's order."""
    position = np.array([x[1 + PARAMS_PER_ECHO * k + 1] for k in range(n_echoes)])
    order = np.argsort(position)
    amplitude = np.empty(n_echoes)
    width = np.empty(n_echoes)
    for j in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * order[j]
        amplitude[j] = x[base]
        width[j] = 2.0 * x[base + 2] * _SQRT_2LN2
    sorted_reasons = np.zeros(n_echoes, dtype=np.int8)
    mark_spurious(amplitude, position[order], width, first, last, pulse_fwhm, noise, min_snr,
                  min_amplitude_ratio, min_separation_factor, min_width_factor, max_width_factor, sorted_reasons)
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
def _valid_samples(samples, smoothed, valid, fit_denoised, wanted):
    """Times, fit target and raw values of the valid samples (empty unless wanted)."""
    n = samples.size if wanted else 0
    m = 0
    for i in range(n):
        m += valid[i]
    times = np.empty(m)
    fit_target = np.empty(m)
    raw = np.empty(m)
    j = 0
    for i in range(n):
        if valid[i]:
            times[j] = i
            fit_target[j] = smoothed[i] if fit_denoised else samples[i]
            raw[j] = samples[i]
            j += 1
    return times, fit_target, raw


@njit(**JIT)
def _prune_echoes(best, lower, upper, n_echoes, times, target, raw, gaussian, lm_iterations,
                  first, last, pulse_fwhm, noise, min_snr, min_amplitude_ratio, min_separation_factor,
                  min_width_factor, max_width_factor):
    """Drop spurious echoes the data does not need: the progressive estimate peels heavy tails and
    flanks off as extra echoes, which then share one echo's signal and bend its shape.

    An echo flagged too close, too narrow or too wide (weakest first) is removed and
    the rest refitted by LM, as is the model with it; the smaller model is taken when
    the Bayesian information criterion on the raw samples does not rise:
    (SSR without - SSR with) / sigma^2 <= parameters per echo x ln(m), sigma^2 the
    optimizer's mean squared residual. Returns the new individual, echo count and the
    Jacobians evaluated.
    """
    m = times.size
    per_echo = 3 if gaussian else PARAMS_PER_ECHO
    penalty = per_echo * math.log(m)  # the BIC's price of one echo
    variance = max(squared_error(best, n_echoes, times, raw) / m, 1e-12)
    n_jacobians = 0
    while n_echoes > 0:
        reasons = _spurious_reasons(best, n_echoes, first, last, pulse_fwhm, noise, min_snr,
                                    min_amplitude_ratio, min_separation_factor, min_width_factor,
                                    max_width_factor)
        # too close, too narrow or too wide: the shapes that take a share of another echo's signal
        amplitude = np.array([best[1 + PARAMS_PER_ECHO * k] if reasons[k] in (TOO_CLOSE, TOO_NARROW, TOO_WIDE)
                              else np.inf for k in range(n_echoes)])
        if not np.isfinite(amplitude.min()):
            break
        full = best.copy()  # the model with every echo, refitted the same way for a fair comparison
        _, used = levenberg_marquardt(full, n_echoes, times, target, lower, upper, lm_iterations, 1e-8)
        n_jacobians += used
        full_ssr = squared_error(full, n_echoes, times, raw)
        removed = False
        for k in np.argsort(amplitude):
            if not np.isfinite(amplitude[k]):
                break
            reduced = _without_echo(best, k)
            _, used = levenberg_marquardt(reduced, n_echoes - 1, times, target, _without_echo(lower, k),
                                          _without_echo(upper, k), lm_iterations, 1e-8)
            n_jacobians += used
            gain = squared_error(reduced, n_echoes - 1, times, raw) - full_ssr
            if gain <= penalty * variance:
                best, lower, upper = reduced, _without_echo(lower, k), _without_echo(upper, k)
                n_echoes -= 1
                removed = True
                break
        if not removed:
            break
    return best, n_echoes, n_jacobians


@njit(**JIT)
def _decompose_one(samples, valid, smoothing_sigma, pulse_sigma, pulse_fwhm, seed, method, gaussian,
                   fit_denoised, population, generations, cr, immediate, chaos_seeds, chaos_iterations,
                   scale_min, scale_max, de_scale, init_spread, noise_threshold, min_noise_sigma, max_echoes,
                   alpha_min, alpha_max, min_snr, min_amplitude_ratio, min_separation_factor,
                   min_width_factor, max_width_factor, prune, lm_iterations, ga_mutation_rate,
                   ga_iterative_r2, ga_iterative_generations,
                   out_scalars, out_echoes, out_reasons):
    """One waveform end to end. out_scalars: background, noise, fit_error, fit_error_raw, rmse, r2,
    nfev, n_initial, n_echoes. out_echoes[k]: A, u, sigma (Chauve, samples), alpha, sorted by u."""
    n = samples.size
    first = 0
    while not valid[first]:
        first += 1
    last = n - 1
    while not valid[last]:
        last -= 1
    smoothed = np.empty(n)
    _smooth(samples, valid, smoothing_sigma, smoothed)
    noise = max(_noise_sigma(samples, smoothed, valid), min_noise_sigma)
    background = _valid_min(smoothed, valid)
    amp0 = np.zeros(max_echoes)
    pos0 = np.zeros(max_echoes)
    sig0 = np.zeros(max_echoes)
    n_echoes = _progressive_echoes(smoothed, valid, background, noise_threshold * noise, max_echoes,
                                   pulse_sigma, amp0, pos0, sig0)
    n_initial = n_echoes
    d = 1 + PARAMS_PER_ECHO * n_echoes
    x0 = np.empty(d)
    lower = np.empty(d)
    upper = np.empty(d)
    local_upper = np.empty(d)
    peak = 0.0
    for i in range(n):
        if valid[i]:
            peak = max(peak, abs(smoothed[i] - background))
    scale = max(1e-6 * peak, 1e-12)
    _parameter_bounds(background, noise, amp0[:n_echoes], pos0[:n_echoes], sig0[:n_echoes], smoothed,
                      first, last, gaussian, alpha_min, alpha_max, scale, x0, lower, upper, local_upper)

    best = x0.copy()
    nfev = 0
    # the valid samples as arrays, for the methods that work on them (not the population kernels)
    local = method in (OPT_LM, OPT_LBFGS, OPT_MDE_LM, OPT_GA_ITERATIVE) or (prune and method != OPT_NONE)
    times, fit_target, raw = _valid_samples(samples, smoothed, valid, fit_denoised, local)
    if method == OPT_GA_ITERATIVE:
        best, n_echoes, n_initial, nfev = ga_iterative(
            valid, smoothed, background, noise, noise_threshold, max_echoes, first, last, times, fit_target, raw,
            ga_iterative_r2, population, ga_iterative_generations, seed)
    elif method in POPULATION_METHODS and n_echoes > 0:
        state = np.empty(1, dtype=np.uint64)
        state[0] = seed
        n_pad = (n + LANES - 1) // LANES * LANES
        tpos = np.arange(n_pad).astype(np.float32)
        target = np.zeros(n_pad, dtype=np.float32)
        target[:n] = smoothed if fit_denoised else samples
        weight = np.zeros(n_pad, dtype=np.float32)
        weight[:n] = valid
        eps = 0.02 * max(noise, scale)  # truncation adds < 2% of the noise per sample to the fitness
        model = np.empty(n_pad, dtype=np.float32)
        pop = np.empty((population, d))
        init_population(x0, lower, upper, init_spread, state, pop)
        fitness = np.empty(population)
        for i in range(population):
            fitness[i] = fit_error(pop[i], n_echoes, tpos, target, weight, gaussian, eps, model)
        nfev = population
        if method == OPT_GA:
            nfev += evolve_ga(pop, fitness, lower, upper, generations, cr, ga_mutation_rate, state, n_echoes,
                              tpos, target, weight, gaussian, eps)
        elif method == OPT_PSO:
            nfev += swarm(pop, fitness, lower, upper, generations, state, n_echoes, tpos, target, weight,
                          gaussian, eps)
        else:
            evolution = OPT_MDE if method == OPT_MDE_LM else method
            nfev += evolve(pop, fitness, lower, upper, generations, cr, evolution, immediate, chaos_seeds,
                           chaos_iterations, scale_min, scale_max, de_scale, state, n_echoes, tpos, target,
                           weight, gaussian, eps)
        best = pop[np.argmin(fitness)].copy()
    if (method == OPT_LM or method == OPT_MDE_LM) and n_echoes > 0:
        _, used = levenberg_marquardt(best, n_echoes, times, fit_target, lower, local_upper, lm_iterations,
                                      1e-8)
        nfev += used
    elif method == OPT_LBFGS and n_echoes > 0:
        _, used = lbfgs(best, n_echoes, times, fit_target, lower, local_upper, 4 * lm_iterations, 10, 1e-9)
        nfev += used

    if method != OPT_NONE and method != OPT_GA_ITERATIVE and prune and n_echoes > 0:
        best, n_echoes, n_jacobians = _prune_echoes(
            best, lower, local_upper, n_echoes, times, fit_target, raw, gaussian, lm_iterations,
            first, last, pulse_fwhm, noise, min_snr, min_amplitude_ratio, min_separation_factor,
            min_width_factor, max_width_factor)
        nfev += n_jacobians

    # metrics, exact, against the denoised (Eq. 9) and the raw samples
    model = _exact_model(best, n_echoes, n)
    m = 0
    err_denoised = 0.0
    err_raw = 0.0
    ss_res = 0.0
    mean = 0.0
    for i in range(n):
        if valid[i]:
            m += 1
            mean += samples[i]
    mean /= m
    ss_tot = 0.0
    for i in range(n):
        if valid[i]:
            err_denoised += abs(model[i] - smoothed[i])
            r = model[i] - samples[i]
            err_raw += abs(r)
            ss_res += r * r
            ss_tot += (samples[i] - mean) ** 2
    out_scalars[0] = best[0]
    out_scalars[1] = noise
    out_scalars[2] = err_denoised
    out_scalars[3] = err_raw
    out_scalars[4] = math.sqrt(ss_res / m)
    out_scalars[5] = 1.0 - ss_res / ss_tot if ss_tot > 0.0 else 0.0
    out_scalars[6] = nfev
    out_scalars[7] = n_initial
    out_scalars[8] = n_echoes

    # echoes sorted by position, in Chauve's parameters
    order = np.argsort(np.array([best[1 + PARAMS_PER_ECHO * k + 1] for k in range(n_echoes)]))
    widths = np.empty(n_echoes)
    for j in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * order[j]
        a, u, s, alpha = best[base], best[base + 1], best[base + 2], best[base + 3]
        h = s * _SQRT_2LN2
        out_echoes[j, 0] = a
        out_echoes[j, 1] = u
        out_echoes[j, 2] = math.sqrt(h ** (alpha * alpha) / (2.0 * _LN2))
        out_echoes[j, 3] = alpha
        widths[j] = 2.0 * h
    mark_spurious(out_echoes[:n_echoes, 0].copy(), out_echoes[:n_echoes, 1].copy(), widths, first, last,
                  pulse_fwhm, noise, min_snr, min_amplitude_ratio, min_separation_factor, min_width_factor,
                  max_width_factor, out_reasons[:n_echoes])


@njit(**PARALLEL_JIT)
def _decompose_many(samples, valid, offsets, status, smoothing_sigma, pulse_sigma, seeds, method, gaussian,
                    fit_denoised, population, generations, cr, immediate, chaos_seeds, chaos_iterations,
                    scale_min, scale_max, de_scale, init_spread, noise_threshold, min_noise_sigma, max_echoes,
                    alpha_min, alpha_max, min_snr, min_amplitude_ratio, min_separation_factor,
                    min_width_factor, max_width_factor, prune, lm_iterations, ga_mutation_rate, ga_iterative_r2,
                    ga_iterative_generations, out_scalars, out_echoes,
                    out_reasons):
    for w in prange(offsets.size - 1):
        if status[w] != 0:
            continue
        lo, hi = offsets[w], offsets[w + 1]
        _decompose_one(samples[lo:hi], valid[lo:hi], smoothing_sigma[w], pulse_sigma[w],
                       pulse_sigma[w] * _FWHM_PER_SIGMA, seeds[w], method, gaussian, fit_denoised,
                       population, generations, cr, immediate, chaos_seeds, chaos_iterations,
                       scale_min, scale_max, de_scale, init_spread, noise_threshold, min_noise_sigma,
                       max_echoes, alpha_min, alpha_max, min_snr, min_amplitude_ratio, min_separation_factor,
                       min_width_factor, max_width_factor, prune, lm_iterations, ga_mutation_rate,
                       ga_iterative_r2, ga_iterative_generations, out_scalars[w], out_echoes[w], out_reasons[w])


# ---------------------------------------------------------------- records

@dataclasses.dataclass(frozen=True)
class WaveformBatch:
    """Many waveforms as flat arrays: waveform i is samples[offsets[i]:offsets[i+1]]."""

    samples: np.ndarray  # float64, digitizer units
    valid: np.ndarray  # bool: False for padding and gaps
    offsets: np.ndarray  # int64, n + 1
    sample_spacing_ps: np.ndarray  # float64, n
    seeds: np.ndarray  # uint64, n: from fwcore.rng.pulse_seed

    def __len__(self) -> int:
        return self.offsets.size - 1

    @classmethod
    def from_waveforms(cls, waveforms: Sequence[np.ndarray], sample_spacing_ps, seeds,
                       valid: Sequence[np.ndarray] | None = None) -> "WaveformBatch":
        n = len(waveforms)
        lengths = np.array([len(w) for w in waveforms], dtype=np.int64)
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(lengths, out=offsets[1:])
        samples = (np.concatenate([np.asarray(w, dtype=np.float64) for w in waveforms])
                   if n else np.zeros(0))
        mask = (np.concatenate([np.asarray(v, dtype=bool) for v in valid]) if valid is not None and n
                else np.ones(samples.size, dtype=bool))
        if mask.shape != samples.shape:
            raise ValueError("valid masks must match the waveforms' lengths")
        spacing = np.broadcast_to(np.asarray(sample_spacing_ps, dtype=np.float64), (n,)).copy()
        seeds = np.asarray(seeds, dtype=np.uint64).reshape(n)
        return cls(samples, mask, offsets, spacing, seeds)


@dataclasses.dataclass(frozen=True)
class Decomposition:
    """One waveform's result. Times and widths in samples (time 0 = first sample)."""

    status: str  # "" when decomposed, else why not
    background: float
    noise_sigma: float
    fit_error: float  # Eq. 9 against the denoised samples
    fit_error_raw: float  # the same sum against the raw samples
    rmse: float  # against the raw samples
    r2: float
    nfev: int
    n_echoes_initial: int
    amplitude: np.ndarray
    position: np.ndarray
    sigma: np.ndarray  # Chauve's sigma, samples**(alpha**2 / 2)
    alpha: np.ndarray
    fwhm: np.ndarray
    energy: np.ndarray  # area under each echo, digitizer units x samples
    reject_reason: tuple[str, ...]  # "" for kept echoes

    @property
    def kept(self) -> np.ndarray:
        return np.array([r == "" for r in self.reject_reason], dtype=bool)

    def model(self, t) -> np.ndarray:
        return waveform_model(t, self.background, self.amplitude, self.position, self.sigma, self.alpha)


@dataclasses.dataclass(frozen=True)
class BatchDecomposition:
    """A batch's results, columnar: per waveform (n) and per echo (flat, echo_offsets)."""

    status: np.ndarray  # int8 codes into STATUS_REASONS
    background: np.ndarray
    noise_sigma: np.ndarray
    fit_error: np.ndarray
    fit_error_raw: np.ndarray
    rmse: np.ndarray
    r2: np.ndarray
    nfev: np.ndarray
    n_echoes_initial: np.ndarray
    echo_offsets: np.ndarray  # n + 1
    amplitude: np.ndarray
    position: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    fwhm: np.ndarray
    energy: np.ndarray
    reject: np.ndarray  # int8 codes into fwcore.filter.REJECT_REASONS

    def __len__(self) -> int:
        return self.status.size

    @property
    def echo_waveform(self) -> np.ndarray:
        """For each echo, the index of its waveform in the batch."""
        return np.repeat(np.arange(len(self)), np.diff(self.echo_offsets))

    def waveform(self, i: int) -> Decomposition:
        lo, hi = self.echo_offsets[i], self.echo_offsets[i + 1]
        return Decomposition(
            status=STATUS_REASONS[self.status[i]], background=float(self.background[i]),
            noise_sigma=float(self.noise_sigma[i]), fit_error=float(self.fit_error[i]),
            fit_error_raw=float(self.fit_error_raw[i]), rmse=float(self.rmse[i]), r2=float(self.r2[i]),
            nfev=int(self.nfev[i]), n_echoes_initial=int(self.n_echoes_initial[i]),
            amplitude=self.amplitude[lo:hi], position=self.position[lo:hi], sigma=self.sigma[lo:hi],
            alpha=self.alpha[lo:hi], fwhm=self.fwhm[lo:hi], energy=self.energy[lo:hi],
            reject_reason=tuple(REJECT_REASONS[r] for r in self.reject[lo:hi]))


# ---------------------------------------------------------------- Python API

def pulse_sigma_samples(config: DecompositionConfig, sample_spacing_ps: np.ndarray) -> np.ndarray:
    """The system pulse's Gaussian sigma in samples of each waveform."""
    return config.pulse_fwhm_ps() / _FWHM_PER_SIGMA / np.asarray(sample_spacing_ps, dtype=float)


def smoothing_sigma_samples(config: DecompositionConfig, sample_spacing_ps: np.ndarray) -> np.ndarray:
    """The denoising filter's sigma in samples: explicit, or tied to the system pulse."""
    spacing = np.asarray(sample_spacing_ps, dtype=float)
    if config.smoothing_sigma_ps is not None:
        return np.full(spacing.shape, config.smoothing_sigma_ps) / spacing
    return config.smoothing_factor * pulse_sigma_samples(config, spacing)


def decompose_batch(batch: WaveformBatch, config: DecompositionConfig = DecompositionConfig(),
                    threads: int | None = None, immediate: bool = False) -> BatchDecomposition:
    """Decompose every waveform of the batch in one parallel call.

    A waveform with non-finite valid samples, or with no valid sample, is not
    decomposed: its status says why and it has no echoes.
    """
    n = len(batch)
    status = np.zeros(n, dtype=np.int8)
    for w in range(n):
        lo, hi = batch.offsets[w], batch.offsets[w + 1]
        chunk, mask = batch.samples[lo:hi], batch.valid[lo:hi]
        if not mask.any():
            status[w] = STATUS_NO_VALID_SAMPLES
        elif not np.isfinite(chunk[mask]).all():
            status[w] = STATUS_NON_FINITE
    k = config.max_echoes
    scalars = np.zeros((n, 9))
    echoes = np.zeros((n, k, 4))
    reasons = np.zeros((n, k), dtype=np.int8)
    samples = np.where(batch.valid, batch.samples, 0.0)  # invalid samples never reach the kernel's sums
    samples[~np.isfinite(samples)] = 0.0
    previous_threads = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        _decompose_many(
            samples, batch.valid, batch.offsets, status,
            smoothing_sigma_samples(config, batch.sample_spacing_ps),
            pulse_sigma_samples(config, batch.sample_spacing_ps), batch.seeds,
            _OPTIMIZER_CODES[config.optimizer], config.model is Model.GAUSSIAN,
            config.fit_target is FitTarget.DENOISED, config.population, config.generations,
            config.crossover_rate, immediate, config.chaos_seeds, config.chaos_iterations,
            config.scale_min, config.scale_max, config.de_scale_factor, config.init_spread,
            config.noise_threshold, config.min_noise_sigma, k, config.alpha_min, config.alpha_max,
            config.min_snr, config.min_amplitude_ratio, config.min_separation_factor,
            config.min_width_factor, config.max_width_factor, config.prune_echoes, config.lm_iterations,
            config.ga_mutation_rate, config.ga_iterative_r2, config.ga_iterative_generations, scalars, echoes, reasons)
    finally:
        numba.set_num_threads(previous_threads)
    counts = scalars[:, 8].astype(np.int64)
    echo_offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=echo_offsets[1:])
    has = np.arange(k)[None, :] < counts[:, None]
    flat = echoes[has]
    amplitude, position, sigma, alpha = flat[:, 0], flat[:, 1], flat[:, 2], flat[:, 3]
    return BatchDecomposition(
        status=status, background=scalars[:, 0], noise_sigma=scalars[:, 1], fit_error=scalars[:, 2],
        fit_error_raw=scalars[:, 3], rmse=scalars[:, 4], r2=scalars[:, 5],
        nfev=scalars[:, 6].astype(np.int64), n_echoes_initial=scalars[:, 7].astype(np.int64),
        echo_offsets=echo_offsets, amplitude=amplitude, position=position, sigma=sigma, alpha=alpha,
        fwhm=fwhm(sigma, alpha), energy=echo_energy(amplitude, sigma, alpha), reject=reasons[has])


def decompose_waveform(samples, sample_spacing_ps: float = 1000.0, seed: int = 0,
                       config: DecompositionConfig = DecompositionConfig(), valid=None) -> Decomposition:
    """Decompose one waveform (the batch engine with a batch of one: identical results)."""
    batch = WaveformBatch.from_waveforms([np.asarray(samples, dtype=float)], sample_spacing_ps, [seed],
                                         None if valid is None else [valid])
    return decompose_batch(batch, config).waveform(0)
