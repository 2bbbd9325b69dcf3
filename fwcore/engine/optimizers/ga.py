"""A real-coded genetic algorithm, one of the methods MDE is compared with.

Binary tournaments, BLX-0.5 blend crossover, Gaussian mutation, one elite; the
fitness is the method's Eq. 9 (fwcore.engine.optimizers.objective).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.optimizers.objective import fit_error
from fwcore.rng import randint, uniform

# blend (BLX-alpha) crossover, Gaussian mutation of this fraction of a parameter's range
_BLX_ALPHA = 0.5
_GA_MUTATION_SCALE = 0.1


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
def evolve_ga(pop, fitness, lower, upper, p, state, n_echoes, tpos, target, weight, shape, eps):
    """Real-coded GA for p.generations: binary tournaments, BLX-0.5 blend crossover (rate p.crossover_rate),
    Gaussian mutation of each parameter with probability p.ga_mutation_rate, one elite. Returns evaluations."""
    np_, d = pop.shape
    model = np.empty(tpos.size, dtype=np.float32)
    next_pop = np.empty_like(pop)
    next_fit = np.empty_like(fitness)
    nfev = 0
    for _ in range(p.generations):
        elite = np.argmin(fitness)
        next_pop[0] = pop[elite]
        next_fit[0] = fitness[elite]
        for i in range(1, np_):
            p1 = pop[_tournament(state, fitness)]
            p2 = pop[_tournament(state, fitness)]
            child = next_pop[i]
            blend = uniform(state) < p.crossover_rate
            for j in range(d):
                v = p1[j]
                if blend:
                    v = p1[j] + (uniform(state) * (1.0 + 2.0 * _BLX_ALPHA) - _BLX_ALPHA) * (p2[j] - p1[j])
                if uniform(state) < p.ga_mutation_rate:
                    v += _GA_MUTATION_SCALE * (upper[j] - lower[j]) * _normal(state)
                child[j] = min(max(v, lower[j]), upper[j])
            next_fit[i] = fit_error(child, n_echoes, tpos, target, weight, p.alpha_fixed, shape, eps, model)
            nfev += 1
        pop[:] = next_pop
        fitness[:] = next_fit
    return nfev
