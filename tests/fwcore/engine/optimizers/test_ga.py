"""The real-coded GA: one generation of the kernel against the NumPy reference on the same random stream."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.optimizers.ga import evolve_ga
from fwcore.engine.model import analytic_shape
from fwcore.rng import SplitMix64
from tests.fwcore import naive
from tests.fwcore.engine.optimizers.test_evolution import _problem


@pytest.mark.parametrize("crossover_rate, mutation_rate", [(0.9, 0.1), (0.5, 0.6)])
def test_one_ga_generation_matches_the_numpy_reference(crossover_rate, mutation_rate):
    pop, fitness, lower, upper, tpos, target, weight, objective = _problem(2)
    expected_pop, expected_fit = naive.ga_generation(pop, fitness, lower, upper, crossover_rate, mutation_rate,
                                                     SplitMix64(31), objective)
    assert not np.allclose(expected_pop[1:], pop[1:])  # the children differ from the parents
    state = np.array([31], dtype=np.uint64)
    p = DecompositionConfig(generations=1, crossover_rate=crossover_rate, ga_mutation_rate=mutation_rate,
                            model="generalized").kernel_params(Model.GENERALIZED, 0.0)
    nfev = evolve_ga(pop, fitness, lower, upper, p, state, 3, tpos, target, weight, analytic_shape(), 1e-3)
    assert nfev == 7  # every child but the elite
    np.testing.assert_allclose(pop, expected_pop, rtol=1e-12)
    np.testing.assert_allclose(fitness, expected_fit, rtol=1e-12)
