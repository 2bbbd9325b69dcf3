"""The population optimizers: MDE (the default), plain DE, a real-coded GA and PSO, on one machinery.

An individual is [b, (A, u, s, alpha) per echo], with s the equal-FWHM Gaussian
sigma (see fwcore.model). Its fitness is the method's Eq. 9 fit error,
sum_i |f(x_i) - y_i| over the valid samples. Modelled on SciPy's
differential evolution: a registry of mutation steps, a per-run random stream,
box bounds, greedy selection; all of it numba, one waveform per thread.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE, _bits_of_f32, fast_exp2, fast_log2
from fwcore.rng import randint, uniform

PARAMS_PER_ECHO = 4
_SQRT_2LN2 = math.sqrt(2.0 * math.log(2.0))
_F32 = np.float32
_ZERO32 = _F32(0.0)
_LOGISTIC_MU = 4.0

# Optimizer codes shared by the kernels (the Python side maps enums onto these).
OPT_NONE, OPT_DE, OPT_MDE, OPT_GA, OPT_PSO, OPT_LM, OPT_LBFGS, OPT_MDE_LM, OPT_GA_ITERATIVE = range(9)
POPULATION_METHODS = (OPT_DE, OPT_MDE, OPT_GA, OPT_PSO, OPT_MDE_LM)

# GA: blend (BLX-alpha) crossover, Gaussian mutation of this fraction of a parameter's range.
_BLX_ALPHA = 0.5
_GA_MUTATION_SCALE = 0.1
# PSO: Clerc's constriction values for inertia and the cognitive and social terms; speed limit.
_PSO_INERTIA = 0.7298
_PSO_COGNITIVE = 1.49618
_PSO_SOCIAL = 1.49618
_PSO_MAX_SPEED = 0.2


# ---------------------------------------------------------------- objective

@njit(**JIT_INLINE)
def _echo_reach(amplitude, h, p, eps):
    """How far from its centre (in samples) an echo stays above eps: h * log2(A/eps)**(1/p),
    with log2(A/eps) bounded above by its float exponent + 1 (cheap, and only widens the window)."""
    ratio = _F32(amplitude / eps)
    if ratio <= _F32(1.0):
        return -1.0
    levels = _F32((_bits_of_f32(ratio) >> np.int32(23)) - np.int32(126))
    if p == 2.0:
        return h * math.sqrt(levels)
    return h * fast_exp2(fast_log2(levels) / _F32(p))


LANES = 8  # float32 lanes of AVX2: echo windows and buffers are whole blocks of LANES samples


def padded_length(n: int) -> int:
    """Buffer length for an n-sample waveform: whole SIMD blocks, so no scalar remainder loop runs."""
    return (n + LANES - 1) // LANES * LANES


@njit(**JIT)
def fill_model(x, n_echoes, tpos, gaussian, eps, model):
    """Write the model of individual x into `model` (float32, padded to whole blocks),
    evaluating each echo only over the aligned blocks where it exceeds eps."""
    n = model.size
    b = _F32(x[0])
    for i in range(n):
        model[i] = b
    for k in range(n_echoes):
        base = 1 + PARAMS_PER_ECHO * k
        amplitude = x[base]
        if amplitude <= 0.0:
            continue
        u = x[base + 1]
        h = x[base + 2] * _SQRT_2LN2
        p = x[base + 3] * x[base + 3]
        reach = _echo_reach(amplitude, h, p, eps)
        if reach < 0.0:
            continue
        lo = max(0, int(math.floor(u - reach))) // LANES * LANES
        hi = min(n, (int(math.ceil(u + reach)) + LANES) // LANES * LANES)
        a32 = _F32(amplitude)
        u32 = _F32(u)
        inv_h = _F32(1.0 / h)
        # unsigned indices: signed ones make numba emit wraparound checks that block SIMD
        if gaussian:
            for j in range(hi - lo):
                i = np.uint64(lo + j)
                z = (tpos[i] - u32) * inv_h
                model[i] += a32 * fast_exp2(-(z * z))
        else:
            p32 = _F32(p)
            for j in range(hi - lo):
                i = np.uint64(lo + j)
                z = abs(tpos[i] - u32) * inv_h
                model[i] += a32 * fast_exp2(-fast_exp2(p32 * fast_log2(z)))


@njit(**JIT)
def fit_error(x, n_echoes, tpos, target, weight, gaussian, eps, model):
    """Eq. 9: sum of |model - target| over valid samples (weight 1, else 0). `model` is scratch."""
    fill_model(x, n_echoes, tpos, gaussian, eps, model)
    acc = _ZERO32
    for i in range(model.size):
        acc += weight[i] * abs(model[i] - target[i])
    return np.float64(acc)


# ---------------------------------------------------------------- evolution steps

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
def evolve(pop, fitness, lower, upper, generations, cr, method, immediate,
           chaos_seeds, chaos_iterations, scale_min, scale_max, de_scale,
           state, n_echoes, tpos, target, weight, gaussian, eps):
    """Run DE or MDE for `generations`; pop and fitness are updated in place. Returns model evaluations.

    Generational update (default): a generation's trials all mutate the same
    population. immediate=True writes each winner back at once (asynchronous DE).
    """
    np_, d = pop.shape
    model = np.empty(tpos.size, dtype=np.float32)
    mutant = np.empty(d)
    candidate = np.empty(d)
    trial = np.empty(d)
    partners = np.empty(4, dtype=np.int64)
    n_candidates = chaos_seeds * chaos_iterations
    f1s = np.empty(n_candidates)
    f2s = np.empty(n_candidates)
    seeds = np.empty(chaos_seeds)
    diff1 = np.empty(d)
    diff2 = np.empty(d)
    best_x = np.empty(d)
    next_pop = pop.copy()
    next_fit = fitness.copy()
    nfev = 0
    for _ in range(generations):
        best = 0
        for i in range(1, np_):
            if fitness[i] < fitness[best]:
                best = i
        for i in range(np_):
            if method == OPT_MDE:
                _distinct_partners(state, np_, i, 4, partners)
                _draw_chaotic_factors(state, chaos_seeds, chaos_iterations, scale_min, scale_max, seeds, f1s)
                _draw_chaotic_factors(state, chaos_seeds, chaos_iterations, scale_min, scale_max, seeds, f2s)
                r1, r2, r3, r4 = partners[0], partners[1], partners[2], partners[3]
                for j in range(d):
                    best_x[j] = pop[best, j]
                    diff1[j] = pop[r1, j] - pop[r2, j]
                    diff2[j] = pop[r3, j] - pop[r4, j]
                best_candidate = np.inf
                for c in range(n_candidates):
                    _mde_candidate(best_x, diff1, diff2, f1s[c], f2s[c], lower, upper, candidate)
                    err = fit_error(candidate, n_echoes, tpos, target, weight, gaussian, eps, model)
                    nfev += 1
                    if err < best_candidate:
                        best_candidate = err
                        mutant[:] = candidate
            else:
                _distinct_partners(state, np_, i, 3, partners)
                mutate_de(pop[partners[0]], pop[partners[1]], pop[partners[2]], de_scale, lower, upper, mutant)
            binomial_crossover(pop[i], mutant, cr, state, trial)
            err = fit_error(trial, n_echoes, tpos, target, weight, gaussian, eps, model)
            nfev += 1
            if err <= fitness[i]:
                next_pop[i] = trial
                next_fit[i] = err
                if immediate:
                    pop[i] = trial
                    fitness[i] = err
                    if err < fitness[best]:
                        best = i
            else:
                next_pop[i] = pop[i]
                next_fit[i] = fitness[i]
        if not immediate:
            pop[:] = next_pop
            fitness[:] = next_fit
    return nfev


@njit(**JIT)
def _normal(state):
    """A standard normal draw (Box-Muller on the waveform's own stream)."""
    u1 = max(uniform(state), 1e-300)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * uniform(state))


@njit(**JIT)
def _tournament(state, fitness):
    a = randint(state, fitness.size)
    b = randint(state, fitness.size)
    return a if fitness[a] <= fitness[b] else b


@njit(**JIT)
def evolve_ga(pop, fitness, lower, upper, generations, crossover_rate, mutation_rate, state,
              n_echoes, tpos, target, weight, gaussian, eps):
    """Real-coded GA: binary tournaments, BLX-0.5 blend crossover (rate crossover_rate),
    Gaussian mutation of each parameter with probability mutation_rate, one elite. Returns evaluations."""
    np_, d = pop.shape
    model = np.empty(tpos.size, dtype=np.float32)
    next_pop = np.empty_like(pop)
    next_fit = np.empty_like(fitness)
    nfev = 0
    for _ in range(generations):
        elite = np.argmin(fitness)
        next_pop[0] = pop[elite]
        next_fit[0] = fitness[elite]
        for i in range(1, np_):
            p1 = pop[_tournament(state, fitness)]
            p2 = pop[_tournament(state, fitness)]
            child = next_pop[i]
            blend = uniform(state) < crossover_rate
            for j in range(d):
                v = p1[j]
                if blend:
                    v = p1[j] + (uniform(state) * (1.0 + 2.0 * _BLX_ALPHA) - _BLX_ALPHA) * (p2[j] - p1[j])
                if uniform(state) < mutation_rate:
                    v += _GA_MUTATION_SCALE * (upper[j] - lower[j]) * _normal(state)
                child[j] = min(max(v, lower[j]), upper[j])
            next_fit[i] = fit_error(child, n_echoes, tpos, target, weight, gaussian, eps, model)
            nfev += 1
        pop[:] = next_pop
        fitness[:] = next_fit
    return nfev


@njit(**JIT)
def swarm(pop, fitness, lower, upper, generations, state, n_echoes, tpos, target, weight, gaussian, eps):
    """Global-best PSO: v <- w v + c1 r1 (personal best - x) + c2 r2 (global best - x), speed limited
    to a fraction of each range, positions kept in the box. On return pop and fitness hold the
    personal bests. Returns evaluations."""
    np_, d = pop.shape
    model = np.empty(tpos.size, dtype=np.float32)
    x = pop.copy()
    velocity = np.empty_like(pop)
    for i in range(np_):
        for j in range(d):
            velocity[i, j] = (2.0 * uniform(state) - 1.0) * 0.1 * (upper[j] - lower[j])
    best = np.argmin(fitness)
    nfev = 0
    for _ in range(generations):
        for i in range(np_):
            for j in range(d):
                limit = _PSO_MAX_SPEED * (upper[j] - lower[j])
                v = (_PSO_INERTIA * velocity[i, j]
                     + _PSO_COGNITIVE * uniform(state) * (pop[i, j] - x[i, j])
                     + _PSO_SOCIAL * uniform(state) * (pop[best, j] - x[i, j]))
                v = min(max(v, -limit), limit)
                velocity[i, j] = v
                x[i, j] = min(max(x[i, j] + v, lower[j]), upper[j])
            err = fit_error(x[i], n_echoes, tpos, target, weight, gaussian, eps, model)
            nfev += 1
            if err <= fitness[i]:
                fitness[i] = err
                pop[i] = x[i]
                if err < fitness[best]:
                    best = i
    return nfev


# ---------------------------------------------------------------- Python API

def chaotic_scale_factors(seeds, k: int, a: float, b: float) -> np.ndarray:
    """The k x t chaotic scale factors from t seeds in [a, b]; row s holds the k iterates of seed s."""
    seeds = np.ascontiguousarray(seeds, dtype=np.float64)
    if not (a < b) or np.any((seeds < a) | (seeds > b)):
        raise ValueError(f"seeds must lie in [a, b] = [{a}, {b}]")
    out = np.empty(seeds.size * k)
    chaotic_factors_from_seeds(seeds, int(k), float(a), float(b), out)
    return out.reshape(seeds.size, k)
