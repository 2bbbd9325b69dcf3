"""The optimizer kernels behind the catalogue (fwcore.engine.config.OPTIMIZERS), like SciPy's strategy table.

Every method starts from the same initial estimate and bounds and hands back the
same things: the best individual, model evaluations, iterations and a message.
`run_optimizer` is the one place the kernels branch on what the catalogue says
of the method (its search, its local fit, whether that weighs the samples by the
noise); the methods that choose their own echoes (the patent's GA,
deconvolution) run in `find_own_echoes`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.config import (LOCAL_LBFGS, LOCAL_NONE, MSG_CONVERGED, MSG_MAX_GENERATIONS, MSG_MAX_ITERATIONS,
                           MSG_NO_ECHOES, MSG_NOT_OPTIMIZED, OPT_DE, OPT_GA, OPT_GOLD, OPT_MDE, OPT_PSO)
from fwcore.engine.optimizers.deconvolution import deconvolution_echoes, fit_amplitudes
from fwcore.engine.optimizers.evolution import INIT_SPREAD, evolve, init_population
from fwcore.engine.optimizers.ga import evolve_ga
from fwcore.engine.optimizers.ga_iterative import ga_iterative
from fwcore.engine.optimizers.local import lbfgs, levenberg_marquardt, squared_error
from fwcore.engine.optimizers.objective import LANES, fit_error
from fwcore.engine.optimizers.pso import swarm
from fwcore.engine.noise_model import add_shot_noise

@njit(**JIT)
def _population_search(p, shape, method, start, lower, upper, n_echoes, fit_samples, valid, noise, eps, seed):
    """A population method (p.method's kind) on Eq. 9 over `fit_samples`, its population seeded
    around `start`; it converges (tol > 0) when its fitness spread is within the noise's too.
    Returns (best individual, model evaluations, generations, converged)."""
    n = fit_samples.size
    atol = p.atol
    if p.tol > 0.0:
        atol += p.noise_tol * noise * math.sqrt(np.sum(valid) * (1.0 - 2.0 / math.pi))
    state = np.empty(1, dtype=np.uint64)
    state[0] = seed
    n_pad = (n + LANES - 1) // LANES * LANES
    tpos = np.arange(n_pad).astype(np.float32)
    target = np.zeros(n_pad, dtype=np.float32)
    target[:n] = fit_samples
    weight = np.zeros(n_pad, dtype=np.float32)
    weight[:n] = valid
    model = np.empty(n_pad, dtype=np.float32)
    pop = np.empty((p.population, start.size))
    init_population(start, lower, upper, INIT_SPREAD, state, pop)
    fitness = np.empty(p.population)
    for i in range(p.population):
        fitness[i] = fit_error(pop[i], n_echoes, tpos, target, weight, p.alpha_fixed, shape, eps, model)
    nfev = p.population
    done = True
    if method == OPT_GA:
        nfev += evolve_ga(pop, fitness, lower, upper, p, state, n_echoes, tpos, target, weight, shape, eps)
        nit = p.generations
    elif method == OPT_PSO:
        nfev += swarm(pop, fitness, lower, upper, p, state, n_echoes, tpos, target, weight, shape, eps)
        nit = p.generations
    else:
        used, nit, done = evolve(pop, fitness, lower, upper, p, method != OPT_DE, atol, state, n_echoes, tpos, target,
                                 weight, shape, eps)
        nfev += used
    return pop[np.argmin(fitness)].copy(), nfev, nit, done


@njit(**JIT)
def reduced_chi2(x, n_echoes, times, shape, raw, signal, variance):
    """chi^2 per degree of freedom of x on the raw samples under the noise model, with the
    Poisson-like term fitted to x's residual (noise_model.add_shot_noise) added to `variance`."""
    shot = variance.copy()
    add_shot_noise(x, n_echoes, times, shape, raw, signal, shot)
    chi2 = squared_error(x, n_echoes, times, shape, raw, 1.0 / np.sqrt(shot))
    return chi2 / max(times.size - x.size, 1)


@njit(**JIT)
def find_own_echoes(p, shape, samples, valid, smoothed, background, noise, first, last, times, fit_target, raw,
                    weights, pulse_sigma, seed):
    """The methods that choose their own echoes (p.own_echoes): the patent's GA, which adds echoes until R^2
    is reached, and deconvolution, whose echoes are the recovered profile's lobes. Returns (best, echoes,
    echoes first estimated, model evaluations, iterations, message)."""
    if not p.deconvolution:
        best, n_echoes, n_initial, nfev = ga_iterative(
            valid, smoothed, background, noise, p.noise_threshold, p.max_echoes, first, last, times, fit_target,
            raw, p.ga_iterative_r2, p.population, p.ga_iterative_generations, seed)
        return best, n_echoes, n_initial, nfev, 0, MSG_CONVERGED
    best, n_echoes = deconvolution_echoes(samples, valid, background, noise, p.noise_threshold, p.max_echoes,
                                          first, last, shape, pulse_sigma, p.method == OPT_GOLD,
                                          p.deconvolution_iterations)
    nfev = p.deconvolution_iterations + fit_amplitudes(best, n_echoes, times, shape, raw, weights, p.lm_iterations,
                                                       p.lm_tolerance)
    message = MSG_CONVERGED if n_echoes else MSG_NO_ECHOES
    return best, n_echoes, n_echoes, nfev, p.deconvolution_iterations, message


@njit(**JIT)
def _local_fit(p, x, n_echoes, times, shape, target, weights, lower, upper):
    """The optimizer's local fit (p.local) of x in place; L-BFGS gets 4x LM's iterations, which its cheaper
    steps afford. Returns (model evaluations, converged)."""
    if p.local == LOCAL_LBFGS:
        _, used, done = lbfgs(x, n_echoes, times, shape, target, weights, lower, upper, 4 * p.lm_iterations, 10,
                              1e-9)
    else:
        _, used, done = levenberg_marquardt(x, n_echoes, times, shape, target, weights, lower, upper,
                                            p.lm_iterations, p.lm_tolerance, p.lm_chi2_tolerance,
                                            p.lm_predicted_stop)
    return used, done


@njit(**JIT)
def _search_where_local_fails(p, shape, best, lower, upper, local_upper, n_echoes, fit_samples, valid, times,
                              fit_target, raw, signal, variance, weights, noise, eps, seed):
    """lm-mde: the local fit first; MDE only where it did not converge and its fit fails the gate, polished
    by the local fit and kept when it lowers chi^2 by more than one parameter's BIC price, ln m.
    Returns (best, model evaluations, MDE's generations, message)."""
    nfev, done = _local_fit(p, best, n_echoes, times, shape, fit_target, weights, lower, local_upper)
    message = MSG_CONVERGED if done else MSG_MAX_ITERATIONS
    # a fit LM settled is where MDE would end too (its misfit is the model's): MDE only where LM could not
    if done or reduced_chi2(best, n_echoes, times, shape, raw, signal, variance) <= p.mde_gate:
        return best, nfev, 0, message
    searched, used, nit, done = _population_search(p, shape, OPT_MDE, best, lower, upper, n_echoes, fit_samples,
                                                   valid, noise, eps, seed)
    nfev += used
    used, polished = _local_fit(p, searched, n_echoes, times, shape, fit_target, weights, lower, local_upper)
    nfev += used
    chi2 = squared_error(best, n_echoes, times, shape, raw, weights)
    if squared_error(searched, n_echoes, times, shape, raw, weights) < chi2 - math.log(times.size):
        best = searched
        message = MSG_CONVERGED if done and polished else (MSG_MAX_GENERATIONS if not done else MSG_MAX_ITERATIONS)
    return best, nfev, nit, message


@njit(**JIT)
def run_optimizer(p, shape, x0, lower, upper, local_upper, n_echoes, fit_samples, valid, times, fit_target, raw, signal,
                  variance, noise, eps, seed):
    """Optimise individual x0 of n_echoes echoes as the catalogue says (p's OptimizerSpec fields).

    Population searches (p.search) fit Eq. 9 over `fit_samples` (the whole waveform, invalid samples
    weighted 0) within [lower, upper]; local fits (p.local) least squares over the valid samples (times,
    fit_target; weights 1 / sqrt(variance) where p.noise_weighted, else 1) within [lower, local_upper],
    after the search if there is one. p.search_where_local_fails (lm-mde): _search_where_local_fails.
    Returns (best, model evaluations, iterations, message); iterations are the search's generations, or
    the local fit's evaluations when it runs alone."""
    best = x0.copy()
    if n_echoes == 0:
        return best, 0, 0, MSG_NO_ECHOES
    if not p.search and p.local == LOCAL_NONE:
        return best, 0, 0, MSG_NOT_OPTIMIZED
    weights = 1.0 / np.sqrt(variance)
    if p.search_where_local_fails:
        return _search_where_local_fails(p, shape, best, lower, upper, local_upper, n_echoes, fit_samples, valid,
                                         times, fit_target, raw, signal, variance, weights, noise, eps, seed)
    nfev = 0
    nit = 0
    message = MSG_CONVERGED
    if p.search:
        best, used, nit, done = _population_search(p, shape, p.method, x0, lower, upper, n_echoes, fit_samples,
                                                   valid, noise, eps, seed)
        nfev += used
        if not done:
            message = MSG_MAX_GENERATIONS
    if p.local != LOCAL_NONE:
        # L-BFGS fits the plain sum of squares (OPTIMIZERS: its noise_weighted is False)
        used, done = _local_fit(p, best, n_echoes, times, shape, fit_target,
                                weights if p.noise_weighted else np.ones(times.size), lower, local_upper)
        nfev += used
        if not p.search:
            nit = used
        if not done and message == MSG_CONVERGED:
            message = MSG_MAX_ITERATIONS
    return best, nfev, nit, message
