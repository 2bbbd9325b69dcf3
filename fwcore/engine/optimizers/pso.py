"""Global-best particle swarm optimisation, one of the methods MDE is compared with."""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.optimizers.objective import fit_error
from fwcore.rng import uniform

# Clerc's constriction values for inertia and the cognitive and social terms; speed limit
_PSO_INERTIA = 0.7298
_PSO_COGNITIVE = 1.49618
_PSO_SOCIAL = 1.49618
_PSO_MAX_SPEED = 0.2


@njit(**JIT)
def swarm(pop, fitness, lower, upper, p, state, n_echoes, tpos, target, weight, shape, eps):
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
    for _ in range(p.generations):
        for i in range(np_):
            for j in range(d):
                limit = _PSO_MAX_SPEED * (upper[j] - lower[j])
                v = (_PSO_INERTIA * velocity[i, j]
                     + _PSO_COGNITIVE * uniform(state) * (pop[i, j] - x[i, j])
                     + _PSO_SOCIAL * uniform(state) * (pop[best, j] - x[i, j]))
                v = min(max(v, -limit), limit)
                velocity[i, j] = v
                x[i, j] = min(max(x[i, j] + v, lower[j]), upper[j])
            err = fit_error(x[i], n_echoes, tpos, target, weight, p.alpha_fixed, shape, eps, model)
            nfev += 1
            if err <= fitness[i]:
                fitness[i] = err
                pop[i] = x[i]
                if err < fitness[best]:
                    best = i
    return nfev
