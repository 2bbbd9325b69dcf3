"""The kernels' float32 objective: the fast model against the float64 reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.optimizers.objective import fill_model, padded_length
from fwcore.engine.model import analytic_shape
from tests.fwcore.naive import model_of_individual


@pytest.mark.parametrize("gaussian", [True, False])
def test_fast_float32_model_matches_float64_reference(gaussian):
    rng = np.random.default_rng(3)
    n = 150
    n_pad = padded_length(n)
    x = [210.0]
    for _ in range(5):
        x += [rng.uniform(5, 400), rng.uniform(5, 145), rng.uniform(1.0, 8.0),
              math.sqrt(2) if gaussian else rng.uniform(1.1, 2.4)]
    x = np.array(x)
    model = np.empty(n_pad, np.float32)
    eps = 1e-4
    fill_model(x, 5, np.arange(n_pad, dtype=np.float32), gaussian, analytic_shape(), eps, model)
    reference = model_of_individual(x, np.arange(n))
    # float32 with approximate exp2/log2 (1e-4 each): within 2e-4 of the echoes' height plus the
    # truncation eps per echo
    np.testing.assert_allclose(model[:n], reference, atol=2e-4 * (reference - x[0]).max() + 5 * eps)
