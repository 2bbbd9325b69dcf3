"""The local optimizers: the analytic Jacobian, LM and L-BFGS on known echoes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fwcore.engine.model import analytic_shape, tabulated_model
from fwcore.engine.optimizers.local import fit_lbfgs, fit_levenberg_marquardt, model_and_jacobian
from fwcore.instrument.shape import echo_shape
from tests.fwcore import naive
from tests.fwcore.naive import model_of_individual

T = np.arange(100.0)
TRUE = np.array([10.0, 100.0, 40.0, 3.0, 1.6, 50.0, 55.0, 4.0, 1.2])  # b, (A, u, s, alpha) x 2
START = np.array([12.0, 80.0, 42.0, 4.0, 1.414, 40.0, 53.0, 3.0, 1.414])
LOWER = np.array([0.0, 0.0, 30.0, 0.5, 1.0, 0.0, 45.0, 0.5, 1.0])
UPPER = np.array([30.0, 200.0, 50.0, 10.0, 2.6, 200.0, 65.0, 10.0, 2.6])


def test_jacobian_matches_central_differences():
    model = np.empty(T.size)
    jac = np.empty((T.size, START.size))
    windows = np.empty((2, 2), dtype=np.int64)
    model_and_jacobian(START, 2, T, analytic_shape(), model, jac, windows)
    np.testing.assert_allclose(model, model_of_individual(START, T), rtol=1e-12)
    for k, (lo, hi) in enumerate(windows):  # outside its window an echo's columns are zero
        columns = jac[:, 1 + 4 * k:5 + 4 * k]
        assert not columns[:lo].any() and not columns[hi:].any() and columns[lo:hi].any()
    numeric = np.empty_like(jac)
    for j in range(START.size):
        step = np.zeros(START.size)
        step[j] = 1e-6
        numeric[:, j] = (model_of_individual(START + step, T) - model_of_individual(START - step, T)) / 2e-6
    np.testing.assert_allclose(jac, numeric, atol=1e-6)


@pytest.mark.parametrize("fit", [fit_levenberg_marquardt, fit_lbfgs])
def test_noiseless_echoes_are_recovered_exactly(fit):
    x, ssr, _ = fit(START, 2, T, model_of_individual(TRUE, T), LOWER, UPPER)
    np.testing.assert_allclose(x, TRUE, atol=1e-3)
    assert ssr < 1e-6


def test_lm_converges_from_a_good_start_in_few_iterations():
    y = model_of_individual(TRUE, T) + np.random.default_rng(0).normal(0, 1.0, T.size)
    x, ssr, jacobians = fit_levenberg_marquardt(START, 2, T, y, LOWER, UPPER)
    assert jacobians <= 15
    np.testing.assert_allclose(x[[2, 6]], TRUE[[2, 6]], atol=0.1)  # positions
    np.testing.assert_allclose(x[[1, 5]], TRUE[[1, 5]], rtol=0.05)  # amplitudes
    assert ssr < 1.3 * T.size  # white noise of sigma 1 alone gives about T.size


def test_bounds_hold_and_fixed_parameters_do_not_move():
    lower, upper = LOWER.copy(), UPPER.copy()
    lower[[4, 8]] = upper[[4, 8]] = np.sqrt(2)  # the Gaussian model: alpha fixed
    upper[1] = 60.0  # the true amplitude 100 is out of reach
    for fit in (fit_levenberg_marquardt, fit_lbfgs):
        start = START.copy()
        start[[4, 8]] = np.sqrt(2)
        x, _, _ = fit(start, 2, T, model_of_individual(TRUE, T), lower, upper)
        assert np.all(x >= lower) and np.all(x <= upper)
        assert x[1] == 60.0 and x[4] == x[8] == np.sqrt(2)


def test_wrong_individual_size_is_refused():
    with pytest.raises(ValueError, match="2 echoes has 9 parameters"):
        fit_levenberg_marquardt(START[:5], 2, T, T, LOWER[:5], UPPER[:5])


def test_a_width_held_at_its_bound_fits_as_if_it_were_fixed():
    # the true first echo is 3 samples wide; its width may not fall below 3.5: the descent pushes it against
    # the bound, where LM must hold it and fit the rest as it would with the width fixed there
    lower = LOWER.copy()
    lower[3] = 3.5
    held, _, used = fit_levenberg_marquardt(START, 2, T, model_of_individual(TRUE, T), lower, UPPER)
    fixed_lower, fixed_upper = lower.copy(), UPPER.copy()
    fixed_upper[3] = fixed_lower[3] = 3.5
    start = START.copy()
    start[3] = 3.5
    fixed, _, _ = fit_levenberg_marquardt(start, 2, T, model_of_individual(TRUE, T), fixed_lower, fixed_upper)
    assert held[3] == 3.5
    np.testing.assert_allclose(held, fixed, rtol=1e-4)
    assert used < 50  # converged, not stopped by the iteration limit


def test_tabulated_jacobian_matches_central_differences(leica_response):
    shape = echo_shape(leica_response, 2000.0)
    x = np.array([13.0, 120.0, 40.3, 2.9, math.sqrt(2), 45.0, 47.6, 3.6, math.sqrt(2)])
    t = np.arange(0.0, 90.0)
    model, jac = np.empty(t.size), np.empty((t.size, x.size))
    model_and_jacobian(x, 2, t, shape, model, jac, np.empty((2, 2), dtype=np.int64))
    np.testing.assert_allclose(model, tabulated_model(t, 13.0, [120.0, 45.0], [40.3, 47.6], [2.9, 3.6], shape),
                               atol=1e-9)
    for j in (0, 1, 2, 3, 5, 6, 7):
        h = 1e-4 if j in (2, 6) else 1e-3
        up, down = x.copy(), x.copy()
        up[j] += h
        down[j] -= h
        numeric = (tabulated_model(t, up[0], up[[1, 5]], up[[2, 6]], up[[3, 7]], shape)
                   - tabulated_model(t, down[0], down[[1, 5]], down[[2, 6]], down[[3, 7]], shape)) / (2 * h)
        np.testing.assert_allclose(jac[:, j], numeric, atol=2e-2 * max(1.0, np.abs(numeric).max()))


def test_a_step_promising_less_than_the_chi2_tolerance_is_not_taken():
    from fwcore.engine.optimizers.local import levenberg_marquardt

    y = model_of_individual(TRUE, T) + np.random.default_rng(0).normal(0, 1.0, T.size)  # weights 1: chi^2 units
    fits = {}
    for predict in (False, True):
        x = START.copy()
        ssr, jacobians, converged = levenberg_marquardt(x, 2, T, analytic_shape(), y, np.ones(T.size), LOWER, UPPER,
                                                        50, 1e-12, 0.05, predict)
        fits[predict] = x, ssr, jacobians, converged
    (x_made, ssr_made, made, done_made), (x_promised, ssr_promised, promised, done_promised) = fits[False], fits[True]
    assert done_made and done_promised
    assert promised == made - 1  # the Jacobian at the last step, which made its gain under 0.05, is never computed
    assert 0.0 <= ssr_promised - ssr_made <= 0.05  # and that step would have gained under 0.05
    np.testing.assert_allclose(x_promised[[2, 6]], x_made[[2, 6]], atol=0.02)


# ---------------------------------------------------------------- against SciPy's optimizers (tests/fwcore/naive)

NOISY_T = np.arange(120.0)
NOISY_TRUTH = {  # b, (A, u, s, alpha) per echo: 1 to 3 echoes, the third overlapping the second
    1: [8.0, 120.0, 50.0, 3.0, 1.5],
    2: [8.0, 120.0, 40.0, 3.0, 1.6, 60.0, 52.0, 4.0, 1.2],
    3: [8.0, 120.0, 30.0, 2.5, 1.414, 80.0, 50.0, 3.5, 1.8, 40.0, 75.0, 3.0, 1.3],
}


def noisy_case(n: int, gaussian: bool = False):
    """A waveform of n known echoes with white noise of sigma 2, a start within 8% of the truth, and bounds
    around it (alpha held at sqrt 2 when `gaussian`)."""
    truth = np.array(NOISY_TRUTH[n])
    rng = np.random.default_rng(n + 10 * gaussian)
    if gaussian:
        truth[4::4] = np.sqrt(2)
    y = model_of_individual(truth, NOISY_T) + rng.normal(0, 2.0, NOISY_T.size)
    start = truth * (1 + rng.uniform(-0.08, 0.08, truth.size))
    lower = np.r_[0.0, np.tile([0.0, 0.0, 0.5, np.sqrt(2) if gaussian else 1.0], n)]
    upper = np.r_[30.0, np.tile([300.0, 120.0, 10.0, np.sqrt(2) if gaussian else 2.6], n)]
    start[4::4] = np.sqrt(2) if gaussian else start[4::4]
    return y, start, lower, upper


def standard_errors(x, cost, lower, upper):
    """Each parameter's standard error at the optimum x (sigma^2 (J^T J)^-1, sigma^2 = cost / (m - free)); 1
    for a held one."""
    free = lower < upper
    jac = naive.model_jacobian(x, NOISY_T)[:, free]
    errors = np.ones(x.size)
    errors[free] = np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)) * cost / (NOISY_T.size - free.sum()))
    return errors


def assert_same_optimum(x, cost, reference, reference_cost, lower, upper):
    """Our optimum is SciPy's: the cost within 1e-8 of it (LM stops once a step gains under 1e-8 of the
    sum, L-BFGS under 1e-9: what is left is below that), each parameter within 1e-3 of its standard error
    (a difference no fit's uncertainty could show; 3e-4 is the largest seen, L-BFGS on three echoes)."""
    assert abs(cost - reference_cost) <= 1e-8 * reference_cost
    assert np.all(np.abs(x - reference) <= 1e-3 * standard_errors(reference, reference_cost, lower, upper))
    assert np.all((lower <= x) & (x <= upper))


@pytest.mark.parametrize("n, gaussian", [(1, False), (2, False), (3, False), (2, True)])
def test_lm_reaches_scipys_least_squares_optimum(n, gaussian):
    y, start, lower, upper = noisy_case(n, gaussian)
    reference, reference_cost = naive.least_squares_fit(start, NOISY_T, y, lower, upper, method="lm")
    x, cost, _ = fit_levenberg_marquardt(start, n, NOISY_T, y, lower, upper)
    assert_same_optimum(x, cost, reference, reference_cost, lower, upper)
    assert np.abs(x[2::4] - NOISY_TRUTH[n][2::4]).max() < 0.5  # and the optimum is the truth's, positions


@pytest.mark.parametrize("n, gaussian", [(1, False), (2, False), (3, False), (2, True)])
def test_lbfgs_reaches_scipys_lbfgsb_optimum(n, gaussian):
    y, start, lower, upper = noisy_case(n, gaussian)
    reference, reference_cost = naive.lbfgs_fit(start, NOISY_T, y, lower, upper)
    x, cost, _ = fit_lbfgs(start, n, NOISY_T, y, lower, upper)
    assert_same_optimum(x, cost, reference, reference_cost, lower, upper)


@pytest.mark.parametrize("fit", [fit_levenberg_marquardt, fit_lbfgs])
def test_an_optimum_on_a_bound_is_scipys_bounded_one(fit):
    # the first echo's amplitude capped at 100 (truth 120): the optimum sits on the bound
    y, start, lower, upper = noisy_case(2)
    upper[1] = 100.0
    reference, reference_cost = naive.least_squares_fit(start, NOISY_T, y, lower, upper, method="trf")
    x, cost, _ = fit(start, 2, NOISY_T, y, lower, upper)
    assert x[1] == 100.0 and reference[1] == pytest.approx(100.0, abs=1e-9)
    assert_same_optimum(x, cost, reference, reference_cost, lower, upper)


def test_a_tail_floor_cuts_an_echo_where_it_falls_below_the_floor_and_no_sooner():
    from fwcore.engine.optimizers.local import tail_cut
    assert tail_cut(100.0, 0.0) == 40.0  # no floor: 1e-12 of the amplitude, as always
    assert tail_cut(100.0, 1e-3) == pytest.approx(math.log(1e5))
    assert tail_cut(0.5, 1e-3) == pytest.approx(math.log(1e3))  # a weak echo keeps 1e-3 of itself
    assert tail_cut(1e20, 1e-3) == 40.0
    shape = analytic_shape()._replace(tail_floor=0.01)
    t = np.arange(400.0)
    x = np.array([5.0, 80.0, 200.0, 6.0, 1.0])  # alpha 1: a heavy-tailed echo, 1e-12 of it 400 samples away
    exact, cut = np.empty(t.size), np.empty(t.size)
    jac_exact, jac_cut = np.empty((t.size, 5)), np.empty((t.size, 5))
    windows_exact, windows_cut = np.empty((1, 2), dtype=np.int64), np.empty((1, 2), dtype=np.int64)
    model_and_jacobian(x, 1, t, analytic_shape(), exact, jac_exact, windows_exact)
    model_and_jacobian(x, 1, t, shape, cut, jac_cut, windows_cut)
    assert np.abs(cut - exact).max() <= 0.01  # what is left out is below the floor
    assert np.array_equal(cut[cut != 5.0], exact[cut != 5.0])  # and where it is evaluated, exactly as before
    assert list(windows_exact[0]) == [0, 400] and np.diff(windows_cut[0])[0] < 200  # 1e-4 of it, 92 samples away


def _three_echoes(rng):
    """Three overlapping echoes of different shapes over 300 samples, with noise and per-sample weights:
    (times, individual, samples, weights)."""
    t = np.arange(300.0)
    x = np.array([4.0, 60.0, 90.0, 5.0, 1.3, 25.0, 104.0, 7.0, 1.0, 40.0, 200.0, 3.0, 1.9])
    return t, x, model_of_individual(x, t) + rng.normal(0.0, 1.5, t.size), rng.uniform(0.5, 1.0, t.size)


def test_a_trial_point_is_model_and_jacobian_to_the_bit_and_stops_once_its_sum_passes_the_bound():
    from fwcore.engine.optimizers.local import trial_model_and_jacobian

    t, x, y, w = _three_echoes(np.random.default_rng(3))
    for shape in (analytic_shape(), analytic_shape()._replace(tail_floor=0.01)):
        model, jac, windows = np.empty(t.size), np.empty((t.size, x.size)), np.empty((3, 2), dtype=np.int64)
        model_and_jacobian(x, 3, t, shape, model, jac, windows)
        expected = sum((w[i] * (model[i] - y[i])) ** 2 for i in range(t.size))  # in sample order, as LM sums
        trial_model, trial_jac = np.full(t.size, np.nan), np.full((t.size, x.size), np.nan)
        trial_windows, reach = np.empty((3, 2), dtype=np.int64), np.empty((3, 3))
        ssr = trial_model_and_jacobian(x, 3, t, shape, y, w, np.inf, trial_model, trial_jac, trial_windows, reach)
        assert ssr == expected
        assert np.array_equal(trial_model, model) and np.array_equal(trial_windows, windows)
        assert np.array_equal(trial_jac[:, 0], jac[:, 0])
        for k, (lo, hi) in enumerate(windows):  # an echo's columns inside its window; LM reads no others
            columns = slice(1 + 4 * k, 5 + 4 * k)
            assert np.array_equal(trial_jac[lo:hi, columns], jac[lo:hi, columns])
            assert np.isnan(trial_jac[:lo, columns]).all() and np.isnan(trial_jac[hi:, columns]).all()
        # a bound half way: the sum stops at the first sample that reaches it, the samples after it untouched
        partial = np.cumsum((w * (model - y)) ** 2)
        stop = int(np.searchsorted(partial, expected / 2))
        trial_model[:] = np.nan
        ssr = trial_model_and_jacobian(x, 3, t, shape, y, w, partial[stop], trial_model, trial_jac, trial_windows,
                                       reach)
        assert ssr >= partial[stop] and ssr < expected
        assert np.array_equal(trial_model[:stop + 1], model[:stop + 1]) and np.isnan(trial_model[stop + 1:]).all()


def test_a_long_records_weighted_point_is_the_weighted_jacobian_and_its_normal_equations_are_jt_w_j():
    from fwcore.engine.optimizers.local import TRIAL_BLOCK, _normal_equations, weighted_trial

    t, x, y, w = _three_echoes(np.random.default_rng(4))
    shape = analytic_shape()._replace(tail_floor=0.01)
    model, jac, windows = np.empty(t.size), np.zeros((t.size, x.size)), np.empty((3, 2), dtype=np.int64)
    model_and_jacobian(x, 3, t, shape, model, jac, windows)
    weighted_model, jw = np.full(t.size, np.nan), np.zeros((t.size, x.size))
    weighted_windows, reach, block = np.empty((3, 2), dtype=np.int64), np.empty((3, 6)), np.empty((5, TRIAL_BLOCK))
    ssr = weighted_trial(x, 3, t, shape, y, w, np.inf, weighted_model, jw, weighted_windows, reach, block)
    # z as |t - u| x (1 / h): the model to rounding, not to the bit
    assert ssr == pytest.approx(sum((w[i] * (model[i] - y[i])) ** 2 for i in range(t.size)), rel=1e-12)
    np.testing.assert_allclose(weighted_model, model, rtol=1e-14)
    assert np.array_equal(weighted_windows, windows)
    np.testing.assert_allclose(jw, w[:, None] * jac, rtol=1e-13, atol=1e-300)  # one division, not four: rounding
    residual = w * (model - y)
    jtj, grad, wjtj, wgrad = np.zeros((13, 13)), np.zeros(13), np.zeros((13, 13)), np.zeros(13)
    _normal_equations(jac, residual, w, windows, jtj, grad)
    _normal_equations(jw, residual, w, windows, wjtj, wgrad, True)
    np.testing.assert_allclose(wjtj, jtj, rtol=1e-12, atol=1e-12 * np.abs(jtj).max())
    np.testing.assert_allclose(wgrad, grad, rtol=1e-12, atol=1e-12 * np.abs(grad).max())
    # an early stop: after the first block of samples whose partial sum reaches the bound, the rest untouched
    partial = np.cumsum((w * (weighted_model - y)) ** 2)
    stop = int(np.searchsorted(partial, ssr / 2))
    block_end = min((stop // TRIAL_BLOCK + 1) * TRIAL_BLOCK, t.size)
    assert block_end < t.size  # the record is longer than a block: the stop leaves samples untouched
    weighted_model[:] = np.nan
    stopped = weighted_trial(x, 3, t, shape, y, w, partial[stop], weighted_model, jw, weighted_windows, reach, block)
    assert stopped == pytest.approx(partial[block_end - 1], rel=1e-14) and stopped < ssr
    assert not np.isnan(weighted_model[:block_end]).any() and np.isnan(weighted_model[block_end:]).all()


def test_lm_on_a_long_record_fits_as_the_exact_path_does():
    # the weighted path (a tail floor) and the exact one (none) reach the same echoes from the same start
    rng = np.random.default_rng(6)
    y = model_of_individual(TRUE, T) + rng.normal(0.0, 0.5, T.size)
    exact, _, _ = fit_levenberg_marquardt(START, 2, T, y, LOWER, UPPER)
    weighted, _, _ = fit_levenberg_marquardt(START, 2, T, y, LOWER, UPPER, shape=analytic_shape()._replace(
        tail_floor=1e-3))
    np.testing.assert_allclose(weighted, exact, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(weighted[1:], TRUE[1:], rtol=0.05)


def test_damped_solve_is_the_damped_systems_solution_over_the_free_parameters():
    from fwcore.engine.optimizers.local import _solve_damped

    rng = np.random.default_rng(4)
    for d in (5, 13, 29, 49):  # under, at and past the factor's vector lanes (eight rows)
        jac = rng.standard_normal((3 * d, d))
        jtj = jac.T @ jac
        grad = rng.standard_normal(d)
        free = rng.random(d) > 0.2
        lam = 0.3
        step, scratch = np.zeros(d), np.zeros((d, d))
        assert _solve_damped(jtj, grad, lam, free, step, scratch)
        system = jtj[np.ix_(free, free)] + lam * np.diag(np.diag(jtj)[free])
        np.testing.assert_allclose(step[free], np.linalg.solve(system, -grad[free]), rtol=1e-8, atol=1e-10)
        np.testing.assert_array_equal(step[~free], 0.0)


def test_damped_solve_refuses_an_indefinite_system():
    from fwcore.engine.optimizers.local import _solve_damped

    jtj = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    assert not _solve_damped(jtj, np.ones(2), 0.0, np.ones(2, np.bool_), np.zeros(2), np.zeros((2, 2)))


def test_a_long_records_squared_error_is_its_trial_point_s_sum():
    # both take the vectorizable exp and log over the same windows: the same sum to rounding
    from fwcore.engine.optimizers.local import TRIAL_BLOCK, squared_error, weighted_trial

    t, x, y, w = _three_echoes(np.random.default_rng(5))
    shape = analytic_shape()._replace(tail_floor=0.01)
    model, jw = np.empty(t.size), np.empty((t.size, x.size))
    windows, reach, block = np.empty((3, 2), dtype=np.int64), np.empty((3, 6)), np.empty((5, TRIAL_BLOCK))
    ssr = weighted_trial(x, 3, t, shape, y, w, np.inf, model, jw, windows, reach, block)
    assert squared_error(x, 3, t, shape, y, w) == pytest.approx(ssr, rel=1e-13)
