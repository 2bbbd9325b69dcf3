"""MDE (the default's global search) and plain DE: mutation, crossover and selection on one machinery.

Modelled on SciPy's differential evolution: mutation steps as small kernels,
a per-waveform random stream, box bounds, greedy selection, and its stopping
rule on the spread of the population's fitness (std <= atol + tol |mean|).
MDE's scale factors come from the logistic map (chaotic_scale_factors): k x t
candidate mutants per target, the best of which is crossed over.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE
from fwcore.engine.optimizers.objective import fit_error
from fwcore.rng import randint, uniform

# Plain DE's fixed scale factor F (the method's Eq. 4), and the half size of the box around the initial estimate
# that seeds a population, as a fraction of each parameter's bound range: constants, as no one changed them.
DE_SCALE_FACTOR = 0.5
INIT_SPREAD = 0.25
_LOGISTIC_MU = 4.0

@njit(**JIT)
def chaotic_factors_from_seeds(seeds, k, a, b, out):
    """Logistic-map scale factors: each seed in [a, b] is mapped to [0, 1], iterated k times
    with z <- 4 z (1 - z), and every iterate mapped back to [a, b]; out[s * k + j] is iterate j+1 of seed s."""
    width = b - a
    for s in range(seeds.size):
        z = (seeds[s] - a) / width
        for j in range(k):
            z = _LOGISTIC_MU * z * (1.0 - z)
            out[s * k + j] = a + z * width


@njit(**JIT)
def _draw_chaotic_factors(state, t, k, a, b, seeds, out):
    for s in range(t):
        seeds[s] = a + (b - a) * uniform(state)
    chaotic_factors_from_seeds(seeds, k, a, b, out)


@njit(**JIT_INLINE)
def _repair(value, base, lo, hi):
    """Out of bounds: halfway between the bound and the mutation's base vector (keeps diversity, unlike clipping).
    Written as selects, not branches, so the loops over parameters vectorize."""
    value = 0.5 * (lo + base) if value < lo else value
    return 0.5 * (hi + base) if value > hi else value


@njit(**JIT_INLINE)
def _mde_candidate(best, diff1, diff2, f1, f2, lower, upper, out):
    """V = X_best + F1 diff1 + F2 diff2, repaired: evolve computes the differences once for all k x t candidates."""
    for j in range(out.size):
        out[j] = _repair(best[j] + f1 * diff1[j] + f2 * diff2[j], best[j], lower[j], upper[j])


@njit(**JIT)
def mutate_mde(best, x1, x2, x3, x4, f1, f2, lower, upper, out):
    """MDE mutation: V = X_best + F1 (X_r1 - X_r2) + F2 (X_r3 - X_r4), repaired into the bounds."""
    _mde_candidate(best, x1 - x2, x3 - x4, f1, f2, lower, upper, out)


@njit(**JIT)
def mutate_de(x1, x2, x3, f, lower, upper, out):
    """DE/rand/1 (the method's Eq. 4): V = X_r1 + F (X_r2 - X_r3), repaired into the bounds."""
    for j in range(out.size):
        v = x1[j] + f * (x2[j] - x3[j])
        out[j] = _repair(v, x1[j], lower[j], upper[j])


@njit(**JIT)
def binomial_crossover(target, mutant, cr, state, out):
    """U_j = V_j with probability CR (and always at one random j), else X_j."""
    d = out.size
    jrand = randint(state, d)
    for j in range(d):
        if uniform(state) < cr or j == jrand:
            out[j] = mutant[j]
        else:
            out[j] = target[j]


@njit(**JIT)
def _distinct_partners(state, np_, i, count, out):
    """`count` distinct population indices, all different from i."""
    for c in range(count):
        while True:
            r = randint(state, np_)
            if r == i:
                continue
            dup = False
            for q in range(c):
                if out[q] == r:
                    dup = True
            if not dup:
                break
        out[c] = r


@njit(**JIT)
def init_population(x0, lower, upper, spread, state, pop):
    """Row 0 is the initial estimate; the others are uniform in a box of half size spread * (hi - lo) around it."""
    np_, d = pop.shape
    for j in range(d):
        pop[0, j] = x0[j]
    for i in range(1, np_):
        for j in range(d):
            half = spread * (upper[j] - lower[j])
            v = x0[j] + (2.0 * uniform(state) - 1.0) * half
            pop[i, j] = min(max(v, lower[j]), upper[j])


@njit(**JIT)
def converged(fitness, tol, atol):
    """SciPy's stopping rule: the population's fitness spread is small, std <= atol + tol |mean|."""
    if tol <= 0.0 and atol <= 0.0:
        return False
    return np.std(fitness) <= atol + tol * abs(np.mean(fitness))


@njit(**JIT)
def evolve(pop, fitness, lower, upper, p, chaotic, fitness_atol, state, n_echoes, tpos, target, weight, shape, eps):
    """Run MDE (chaotic=True) or DE with p's settings (fwcore.engine.config.KernelParams) until converged
    (p.tol, and fitness_atol in place of p.atol: the caller adds the noise's share), or stalled (with
    p.tol > 0, the best fitness fell by no more than fitness_atol in p.stall_generations generations),
    or for p.generations; pop and fitness are updated in place. Returns (model evaluations, generations
    run, converged or stalled).

    Generational update (default): a generation's trials all mutate the same
    population. p.immediate writes each winner back at once (asynchronous DE).
    """
    np_, d = pop.shape
    model = np.empty(tpos.size, dtype=np.float32)
    mutant = np.empty(d)
    candidate = np.empty(d)
    trial = np.empty(d)
    partners = np.empty(4, dtype=np.int64)
    n_candidates = p.chaos_seeds * p.chaos_iterations
    f1s = np.empty(n_candidates)
    f2s = np.empty(n_candidates)
    seeds = np.empty(p.chaos_seeds)
    diff1 = np.empty(d)
    diff2 = np.empty(d)
    best_x = np.empty(d)
    next_pop = pop.copy()
    next_fit = fitness.copy()
    nfev = 0
    nit = 0
    done = converged(fitness, p.tol, fitness_atol)
    stall_check = p.tol > 0.0 and p.stall_generations > 0
    reference = np.min(fitness)  # the best fitness p.stall_generations generations ago
    while nit < p.generations and not done:
        best = 0
        for i in range(1, np_):
            if fitness[i] < fitness[best]:
                best = i
        for i in range(np_):
            if chaotic:
                _distinct_partners(state, np_, i, 4, partners)
                _draw_chaotic_factors(state, p.chaos_seeds, p.chaos_iterations, p.scale_min, p.scale_max, seeds, f1s)
                _draw_chaotic_factors(state, p.chaos_seeds, p.chaos_iterations, p.scale_min, p.scale_max, seeds, f2s)
                r1, r2, r3, r4 = partners[0], partners[1], partners[2], partners[3]
                for j in range(d):
                    best_x[j] = pop[best, j]
                    diff1[j] = pop[r1, j] - pop[r2, j]
                    diff2[j] = pop[r3, j] - pop[r4, j]
                best_candidate = np.inf
                for c in range(n_candidates):
                    _mde_candidate(best_x, diff1, diff2, f1s[c], f2s[c], lower, upper, candidate)
                    err = fit_error(candidate, n_echoes, tpos, target, weight, p.alpha_fixed, shape, eps, model)
                    nfev += 1
                    if err < best_candidate:
                        best_candidate = err
                        mutant[:] = candidate
            else:
                _distinct_partners(state, np_, i, 3, partners)
                mutate_de(pop[partners[0]], pop[partners[1]], pop[partners[2]], DE_SCALE_FACTOR, lower, upper, mutant)
            binomial_crossover(pop[i], mutant, p.crossover_rate, state, trial)
            err = fit_error(trial, n_echoes, tpos, target, weight, p.alpha_fixed, shape, eps, model)
            nfev += 1
            if err <= fitness[i]:
                next_pop[i] = trial
                next_fit[i] = err
                if p.immediate:
                    pop[i] = trial
                    fitness[i] = err
                    if err < fitness[best]:
                        best = i
            else:
                next_pop[i] = pop[i]
                next_fit[i] = fitness[i]
        if not p.immediate:
            pop[:] = next_pop
            fitness[:] = next_fit
        nit += 1
        done = converged(fitness, p.tol, fitness_atol)
        if stall_check and not done and nit % p.stall_generations == 0:
            current = np.min(fitness)
            done = reference - current <= fitness_atol
            reference = current
    return nfev, nit, done



# ---------------------------------------------------------------- Python API

def chaotic_scale_factors(seeds, k: int, a: float, b: float) -> np.ndarray:
    """The k x t chaotic scale factors from t seeds in [a, b]; row s holds the k iterates of seed s."""
    seeds = np.ascontiguousarray(seeds, dtype=np.float64)
    if not (a < b) or np.any((seeds < a) | (seeds > b)):
        raise ValueError(f"seeds must lie in [a, b] = [{a}, {b}]")
    out = np.empty(seeds.size * k)
    chaotic_factors_from_seeds(seeds, int(k), float(a), float(b), out)
    return out.reshape(seeds.size, k)
