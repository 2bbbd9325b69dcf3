"""Particle swarm: the kernel against the NumPy reference on the same random stream."""

import numpy as np

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.optimizers.pso import swarm
from fwcore.engine.model import analytic_shape
from fwcore.rng import SplitMix64
from tests.fwcore import naive
from tests.fwcore.engine.optimizers.test_evolution import _problem


def test_pso_matches_the_numpy_reference():
    pop, fitness, lower, upper, tpos, target, weight, objective = _problem(3)
    expected_pop, expected_fit, expected_nfev = naive.pso_swarm(pop, fitness, lower, upper, 4, SplitMix64(77),
                                                                objective)
    assert expected_fit.min() < fitness.min()  # the reference moves: a comparison of two copies of the start fails
    state = np.array([77], dtype=np.uint64)
    p = DecompositionConfig(generations=4, model="generalized").kernel_params(Model.GENERALIZED, 0.0)
    nfev = swarm(pop, fitness, lower, upper, p, state, 3, tpos, target, weight, analytic_shape(), 1e-3)
    assert nfev == expected_nfev == 4 * 8
    np.testing.assert_allclose(pop, expected_pop, rtol=1e-12)
    np.testing.assert_allclose(fitness, expected_fit, rtol=1e-12)
