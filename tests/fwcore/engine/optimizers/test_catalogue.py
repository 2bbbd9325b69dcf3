"""Every optimizer of the catalogue, through the engine's one interface, on known echoes."""

import math

import numpy as np
import pytest

from fwcore.engine.config import MSG_CONVERGED, MSG_MAX_ITERATIONS, DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch, decompose_waveform
from fwcore.engine.records import WaveformBatch
from tests.fwcore.engine.test_decompose import CONFIG, PULSE, PULSE_SIGMA, SPACING, SQ2, synthetic

# the comparison's population and generations for the population methods
PAPER = dict(population=100, generations=100)


def _two_echoes(seed):
    rng = np.random.default_rng(seed)
    position = np.array([50.0, 80.0]) + rng.uniform(-2, 2, 2)
    amplitude = rng.uniform(80, 160, 2)
    return synthetic(amplitude, position, [PULSE_SIGMA] * 2, [SQ2] * 2, noise=1.5, seed=seed), position, amplitude


# the real-coded GA converges least at 100 x 100 (as in the method's comparison): wider tolerances
@pytest.mark.parametrize("optimizer, tolerance", [("lm", 0.03), ("lbfgs", 0.03), ("ga", 0.08), ("pso", 0.03),
                                                  ("de", 0.03), ("mde", 0.03), ("mde-lm", 0.03)])
def test_separated_echoes_are_recovered_by_every_optimizer(optimizer, tolerance):
    y, position, amplitude = _two_echoes(7)
    r = decompose_waveform(y, SPACING, seed=1, config=CONFIG.replace(optimizer=optimizer, **PAPER), pulse=PULSE)
    # flank echoes of the progressive estimate may take a share of an echo: the fitted model's
    # peaks and heights at the true echoes are what must be right
    for p, a in zip(position, amplitude):
        t = np.linspace(p - 3, p + 3, 601)
        assert t[np.argmax(r.model(t))] == pytest.approx(p, abs=0.3)
        assert r.model([p])[0] - r.background == pytest.approx(a, rel=tolerance)
    assert r.r2 > 0.99
    assert r.kept.sum() == 2


@pytest.mark.parametrize("optimizer", ["ga", "pso"])
def test_population_methods_improve_on_the_initial_estimate_on_average(optimizer):
    waves = [_two_echoes(seed)[0] for seed in range(8)]
    batch = WaveformBatch.from_waveforms(waves, SPACING, np.arange(8))
    before = decompose_batch(batch, CONFIG.replace(optimizer="none"), PULSE)
    after = decompose_batch(batch, CONFIG.replace(optimizer=optimizer, **PAPER), PULSE)
    assert after.fit_error.mean() < 0.8 * before.fit_error.mean()


def test_mde_lm_polish_lowers_the_fit_error_of_mde():
    y, _, _ = _two_echoes(3)
    mde = decompose_waveform(y, SPACING, seed=1, config=CONFIG.replace(optimizer="mde"), pulse=PULSE)
    polished = decompose_waveform(y, SPACING, seed=1, config=CONFIG.replace(optimizer="mde-lm"), pulse=PULSE)
    assert polished.rmse <= mde.rmse


def test_unknown_optimizer_names_the_choices():
    with pytest.raises(ValueError, match="optimizer must be one of none, lm, lbfgs"):
        DecompositionConfig(optimizer="simplex")


def test_every_optimizer_is_deterministic():
    y, _, _ = _two_echoes(5)
    for optimizer in ("ga", "pso", "ga-iterative", "lm"):
        config = CONFIG.replace(optimizer=optimizer, generations=20, ga_iterative_generations=50)
        a = decompose_waveform(y, SPACING, seed=9, config=config, pulse=PULSE)
        b = decompose_waveform(y, SPACING, seed=9, config=config, pulse=PULSE)
        np.testing.assert_array_equal(a.amplitude, b.amplitude)
        assert math.isfinite(a.fit_error)


def _batch(n=8):
    return WaveformBatch.from_waveforms([_two_echoes(seed)[0] for seed in range(n)], SPACING, np.arange(n))


def test_lm_mde_is_lm_where_the_lm_fit_passes_the_noise_model():
    # white noise of the model's own kind: every LM fit is as good as the noise allows
    batch = _batch()
    lm = decompose_batch(batch, CONFIG.replace(optimizer="lm"), PULSE)
    gated = decompose_batch(batch, CONFIG.replace(optimizer="lm-mde"), PULSE)
    assert (gated.nit == 0).all()  # no MDE generation ran
    np.testing.assert_array_equal(gated.position, lm.position)
    np.testing.assert_array_equal(gated.amplitude, lm.amplitude)


def test_lm_mde_searches_where_lm_does_not_settle_and_never_keeps_a_worse_fit():
    batch = _batch()
    # one LM step settles none of these fits; constant noise on the raw samples: chi^2 is m rmse^2 / sigma^2
    config = CONFIG.replace(select_echoes=False, lm_iterations=1, fit_target="raw", raw_polish=False,
                            signal_dependent_noise=False)
    lm = decompose_batch(batch, config.replace(optimizer="lm"), PULSE)
    searched = decompose_batch(batch, config.replace(optimizer="lm-mde", mde_gate=0.0), PULSE)
    assert (lm.message == MSG_MAX_ITERATIONS).all()
    assert (searched.nit > 0).all()
    # MDE's polished fit replaces LM's only when chi^2 falls by more than ln m
    assert (searched.rmse <= lm.rmse + 1e-9).all()


def test_lm_mde_leaves_a_fit_lm_settled_to_lm_even_at_gate_zero():
    # a converged LM fit that fails the noise model is the model's misfit, which MDE would end in too
    batch = _batch()
    config = CONFIG.replace(select_echoes=False)
    lm = decompose_batch(batch, config.replace(optimizer="lm"), PULSE)
    gated = decompose_batch(batch, config.replace(optimizer="lm-mde", mde_gate=0.0), PULSE)
    assert (lm.message == MSG_CONVERGED).all()
    assert (gated.nit == 0).all()
    np.testing.assert_array_equal(gated.position, lm.position)


def test_mde_gate_must_not_be_negative():
    with pytest.raises(ValueError, match="mde_gate"):
        DecompositionConfig(mde_gate=-1.0)


@pytest.mark.parametrize("optimizer, weighted", [("lm", True), ("lbfgs", False)])
def test_the_local_fit_weighs_the_samples_by_the_noise_where_the_catalogue_says(optimizer, weighted):
    from fwcore.engine.model import analytic_shape
    from fwcore.engine.optimizers import run_optimizer
    from tests.fwcore.naive import model_of_individual

    times = np.arange(60.0)
    truth = np.array([10.0, 100.0, 25.0, 3.0, SQ2, 60.0, 35.0, 3.0, SQ2])
    target = model_of_individual(truth, times) + np.random.default_rng(3).normal(0.0, 2.0, times.size)
    start = truth + np.array([1.0, -20.0, 1.0, 0.5, 0.0, 10.0, -1.0, -0.5, 0.0])
    lower = truth - np.array([50.0, 100.0, 5.0, 2.0, 0.0, 100.0, 5.0, 2.0, 0.0])
    upper = truth + np.array([50.0, 100.0, 5.0, 2.0, 0.0, 100.0, 5.0, 2.0, 0.0])
    p = CONFIG.replace(optimizer=optimizer, model="gaussian").kernel_params(Model.GAUSSIAN, 0.0)
    assert p.noise_weighted == weighted

    def fit(variance):
        best, *_ = run_optimizer(p, analytic_shape(), start, lower, upper, upper, 2, target, np.ones(60, bool), times,
                                 target, target, np.zeros(60), variance, 2.0, 0.01, 1)
        return best

    uneven = np.where(times < 30, 1.0, 100.0)  # the second echo's samples 10x noisier
    assert np.array_equal(fit(np.ones(60)), fit(uneven)) != weighted
