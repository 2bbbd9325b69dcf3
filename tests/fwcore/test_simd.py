"""fwcore._simd's block sums against the scalar loops they replace: the same bits, not merely close."""

import numpy as np
import pytest
from numba import njit

from fwcore._simd import CHOLESKY_LANES, block_sums, cholesky_lanes, weighted_block_sums


@njit
def _sums(weighted_rows, jac, weights, residual, lo, hi, r, c):
    """The intrinsics as the engine calls them (residual None: a pair block)."""
    if weighted_rows:
        return weighted_block_sums(jac, weights, residual, lo, hi, r, c)
    return block_sums(jac, weights, residual, lo, hi, r, c)


@njit
def _lanes(factor, c, r, pivot):
    cholesky_lanes(factor, c, r, pivot)


def _scalar_sums(jac, weights, residual, lo, hi, r, c, weighted_rows):
    """The engine's former loops, one float at a time in sample order (Python floats are IEEE doubles)."""
    outer, with_residual, with_weight = [0.0] * 16, [0.0] * 4, [0.0] * 4
    for i in range(lo, hi):
        w = float(weights[i])
        for a in range(4):
            ja = float(jac[i, r + a])
            for b in range(4):
                product = ja * float(jac[i, c + b])
                outer[4 * a + b] += product if weighted_rows else product * w * w
            if residual is not None:
                base = ja if weighted_rows else ja * w
                with_residual[a] += base * float(residual[i])
                with_weight[a] += base * w
    return outer + with_residual + with_weight


def _jacobian(rng, m, d):
    # magnitudes over twelve decades, so that any change in the order of operations shows in the last bits
    return rng.standard_normal((m, d)) * 10.0 ** rng.uniform(-6, 6, (m, d))


@pytest.mark.parametrize("weighted_rows", [False, True])
def test_block_sums_are_the_scalar_loops_bits(weighted_rows):
    rng = np.random.default_rng(7)
    m, n_echoes = 97, 6
    jac = _jacobian(rng, m, 1 + 4 * n_echoes)
    weights = rng.uniform(0.05, 4.0, m)
    residual = rng.standard_normal(m) * 100.0
    windows = [(0, m), (0, 0), (5, 6), (13, 90), (96, 97)] + [tuple(sorted(rng.integers(0, m + 1, 2))) for _ in range(40)]
    for lo, hi in windows:
        k, q = rng.integers(0, n_echoes, 2)
        r, c = 1 + 4 * int(k), 1 + 4 * int(q)
        expected = _scalar_sums(jac, weights, None, lo, hi, r, c, weighted_rows)
        assert np.array(_sums(weighted_rows, jac, weights, None, lo, hi, r, c)).tobytes() == np.array(expected).tobytes()
        expected = _scalar_sums(jac, weights, residual, lo, hi, r, r, weighted_rows)
        assert np.array(_sums(weighted_rows, jac, weights, residual, lo, hi, r, r)).tobytes() == np.array(expected).tobytes()


def test_a_pair_block_is_its_outer_products_summed():
    # values exact in binary: the sums are exact too, whatever their order
    jac = np.zeros((3, 9))
    jac[:, 1:5] = [[1, 2, 3, 4], [0.5, 0, 1, 2], [2, 2, 2, 2]]
    jac[:, 5:9] = [[1, 0, 0, 1], [4, 4, 4, 4], [0.25, 0.5, 1, 2]]
    weights = np.array([1.0, 2.0, 0.5])
    sums = np.array(_sums(False, jac, weights, None, 0, 3, 1, 5))
    expected = sum(np.outer(jac[i, 1:5], jac[i, 5:9]) * weights[i] ** 2 for i in range(3))
    np.testing.assert_array_equal(sums[:16].reshape(4, 4), expected)
    np.testing.assert_array_equal(sums[16:], 0.0)  # no residual: no gradient sums
    np.testing.assert_array_equal(np.array(_sums(True, jac, weights, None, 1, 2, 1, 5))[:16].reshape(4, 4),
                                  np.outer(jac[1, 1:5], jac[1, 5:9]))


def test_an_empty_window_sums_to_zero():
    jac = np.ones((4, 5))
    assert _sums(False, jac, np.ones(4), np.ones(4), 2, 2, 1, 1) == (0.0,) * 24


def test_a_strided_jacobian_is_refused():
    jac = np.ones((4, 10))[:, ::2]
    with pytest.raises(Exception, match="C-contiguous"):
        _sums(False, jac, np.ones(4), None, 0, 4, 0, 0)


def test_cholesky_lanes_are_the_scalar_column_update():
    rng = np.random.default_rng(11)
    d = 29
    for c, r in [(0, 1), (3, 4), (10, 11), (12, 20), (20, 21)]:
        factor = rng.standard_normal((d, d)) * 10.0 ** rng.uniform(-4, 4, (d, d))
        pivot = float(rng.uniform(0.5, 3.0))
        expected = factor.copy()
        for k in range(r, r + CHOLESKY_LANES):
            acc = float(expected[c, k])
            for q in range(c):
                acc -= float(expected[q, k]) * float(expected[q, c])
            expected[c, k] = acc / pivot
        _lanes(factor, c, r, pivot)
        assert factor.tobytes() == expected.tobytes()  # only row c's eight entries change, to the scalar bits
