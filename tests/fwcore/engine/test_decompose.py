from __future__ import annotations

import dataclasses
import math
import pickle

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import checked_samples, decompose_batch, decompose_waveform, echo_shapes
from fwcore.engine.model import fwhm, tabulated_model, waveform_model
from fwcore.engine.records import (STATUS_NO_VALID_SAMPLES, STATUS_NON_FINITE, WAVEFORM_FIELDS, Decomposition,
                                  WaveformBatch)
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape

SPACING = 1000.0
PULSE_SIGMA = 3.0  # samples
CONFIG = DecompositionConfig()
PULSE = nominal_pulse(PULSE_SIGMA * 2 * math.sqrt(2 * math.log(2)) * SPACING)
SQ2 = math.sqrt(2)


def synthetic(amplitude, position, sigma, alpha, noise, n=160, background=30.0, seed=0):
    t = np.arange(n, dtype=float)
    clean = waveform_model(t, background, amplitude, position, sigma, alpha)
    return clean + np.random.default_rng(seed).normal(0, noise, n)


def matched(result, position):
    """The fitted echo nearest each true position."""
    return [int(np.argmin(np.abs(result.position - p))) for p in position]


@pytest.mark.parametrize("n_echoes", [1, 2, 3, 4, 5, 6])
def test_separated_echoes_are_recovered(n_echoes):
    rng = np.random.default_rng(n_echoes)
    position = 15.0 + 22.0 * np.arange(n_echoes) + rng.uniform(-2, 2, n_echoes)
    amplitude = rng.uniform(60, 200, n_echoes)
    y = synthetic(amplitude, position, [PULSE_SIGMA] * n_echoes, [SQ2] * n_echoes, noise=1.5, seed=n_echoes)
    r = decompose_waveform(y, SPACING, seed=1, config=CONFIG, pulse=PULSE)
    idx = matched(r, position)
    np.testing.assert_allclose(r.position[idx], position, atol=0.35)
    # spurious flank echoes of the progressive estimate take a share of the signal: 12%
    np.testing.assert_allclose(r.amplitude[idx], amplitude, rtol=0.12)
    np.testing.assert_allclose(r.fwhm[idx], fwhm(PULSE_SIGMA, SQ2), rtol=0.1)
    assert r.kept[idx].all()
    assert r.kept.sum() == n_echoes  # nothing spurious survives the filter
    assert r.r2 > 0.99


def test_two_echoes_one_and_a_half_sigma_apart_are_both_fitted():
    # the second echo shows only as a shoulder; the selection adds it where the residual holds it
    # (no shape tolerance: these echoes are the model exactly)
    position = [60.0, 60.0 + 1.5 * PULSE_SIGMA]
    y = synthetic([150.0, 100.0], position, [PULSE_SIGMA] * 2, [SQ2] * 2, noise=1.0, seed=3)
    r = decompose_waveform(y, SPACING, seed=2, config=CONFIG.replace(model="gaussian"), pulse=PULSE)
    strong = r.amplitude > 30
    assert strong.sum() == 2
    np.testing.assert_allclose(np.sort(r.position[strong]), position, atol=0.6)
    np.testing.assert_allclose(r.amplitude[strong][np.argsort(r.position[strong])], [150, 100], rtol=0.15)
    # closer than the pulse FWHM: the filter keeps the stronger one and says why not the other
    assert "too_close" in r.reject_reason


def test_weak_echo_at_four_noise_sigma_is_found():
    noise = 2.0
    position = [40.0, 110.0]
    y = synthetic([150.0, 4 * noise], position, [PULSE_SIGMA] * 2, [SQ2] * 2, noise=noise, seed=4)
    r = decompose_waveform(y, SPACING, seed=3, config=CONFIG.replace(min_amplitude_ratio=0.0, min_snr=3.0), pulse=PULSE)
    weak = matched(r, [110.0])[0]
    assert abs(r.position[weak] - 110.0) < 1.0
    assert r.amplitude[weak] == pytest.approx(8.0, rel=0.35)


@pytest.mark.parametrize("alpha", [1.2, 1.5, 1.8, 2.2])
def test_shape_factor_alpha_is_recovered(alpha):
    from fwcore.engine.model import sigma_from_half_width
    h = 4.0  # half width at half maximum, samples
    sigma = float(sigma_from_half_width(h, alpha))
    y = synthetic([200.0], [70.0], [sigma], [alpha], noise=1.0, seed=int(alpha * 10))
    # alpha = 1.2 tails leave residuals the progressive estimate takes for extra echoes, which then
    # share the signal and bend the shape: the selection drops the echoes the data does not need.
    # The shape is fitted to the raw samples: the denoising filter rounds flat tops (2.2 looks like 1.94).
    r = decompose_waveform(y, SPACING, seed=4, config=CONFIG.replace(fit_target="raw"), pulse=PULSE)
    assert r.kept.sum() == 1
    k = matched(r, [70.0])[0]
    assert r.alpha[k] == pytest.approx(alpha, abs=0.25)
    assert r.fwhm[k] == pytest.approx(2 * h, rel=0.06)
    assert r.position[k] == pytest.approx(70.0, abs=0.2)


def test_reported_metrics_are_those_of_the_reported_echoes():
    y = synthetic([120.0, 80.0], [50.0, 90.0], [3.0, 4.0], [1.6, 1.3], noise=2.0, seed=5)
    r = decompose_waveform(y, SPACING, seed=5, config=CONFIG, pulse=PULSE)
    model = r.model(np.arange(y.size))
    assert r.fit_error_raw == pytest.approx(np.abs(model - y).sum(), rel=1e-9)
    assert r.rmse == pytest.approx(np.sqrt(np.mean((model - y) ** 2)), rel=1e-9)
    assert r.r2 == pytest.approx(1 - np.sum((model - y) ** 2) / np.sum((y - y.mean()) ** 2), rel=1e-9)


def _batch(waveforms, seeds):
    return WaveformBatch.from_waveforms(waveforms, SPACING, seeds)


def test_results_do_not_depend_on_batch_composition_or_threads():
    waves = [synthetic([100.0, 70.0], [40.0 + 5 * i, 90.0], [3.0, 3.5], [1.5, 1.3], 1.5, seed=i) for i in range(4)]
    seeds = [11, 12, 13, 14]
    config = CONFIG.replace(generations=20)
    full = decompose_batch(_batch(waves, seeds), config, PULSE, threads=2)
    alone = decompose_batch(_batch([waves[2]], [seeds[2]]), config, PULSE, threads=1)
    shuffled = decompose_batch(_batch([waves[3], waves[2], waves[0]], [14, 13, 11]), config, PULSE, threads=1)
    for other, i in ((alone, 0), (shuffled, 1)):
        a, b = full.waveform(2), other.waveform(i)
        np.testing.assert_array_equal(a.amplitude, b.amplitude)
        np.testing.assert_array_equal(a.position, b.position)
        assert a.fit_error == b.fit_error
    again = decompose_batch(_batch(waves, seeds), config, PULSE, threads=1)
    np.testing.assert_array_equal(full.amplitude, again.amplitude)


def test_bad_waveforms_get_a_status_and_the_rest_are_decomposed():
    good = synthetic([100.0], [50.0], [3.0], [SQ2], 1.0)
    nan = good.copy()
    nan[10] = np.nan
    batch = WaveformBatch.from_waveforms([good, nan, np.zeros(5)], SPACING, [1, 2, 3],
                                         valid=[np.ones(160, bool), np.ones(160, bool), np.zeros(5, bool)])
    r = decompose_batch(batch, CONFIG.replace(generations=5), PULSE)
    assert [r.waveform(i).status for i in range(3)] == ["", "non_finite_samples", "no_valid_samples"]
    assert r.waveform(0).amplitude.size >= 1
    assert r.waveform(1).amplitude.size == 0 and r.waveform(2).amplitude.size == 0


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_checked_samples_are_numpys_masks_and_cumulative_sums_to_the_bit(dtype):
    rng = np.random.default_rng(58)
    waveforms = [rng.normal(100.0, 5.0, size).astype(dtype) for size in (7, 0, 5, 9, 3, 6)]
    waveforms[0][2], waveforms[3][4], waveforms[5][1] = np.nan, np.inf, -np.inf
    valid = [rng.random(w.size) < 0.7 for w in waveforms]
    valid[2][:] = False  # no valid sample; waveform 1 has no sample at all
    valid[0][2] = valid[3][4] = True  # NaN, inf where valid: not finite
    valid[4][0] = valid[5][0] = True
    valid[5][1] = False  # -inf where invalid: still decomposable
    batch = WaveformBatch.from_waveforms(waveforms, SPACING, range(6), valid)
    batch = dataclasses.replace(batch, samples=batch.samples.astype(dtype))
    # the computation it replaces (decompose_batch before issue 58's ninth pass)
    running = np.concatenate(([0], np.cumsum(batch.valid & ~np.isfinite(batch.samples), dtype=np.int64)))
    non_finite = running[batch.offsets[1:]] - running[batch.offsets[:-1]]
    running = np.concatenate(([0], np.cumsum(batch.valid, dtype=np.int64)))
    n_valid = running[batch.offsets[1:]] - running[batch.offsets[:-1]]
    expected = np.zeros(len(batch), dtype=np.int8)
    expected[non_finite > 0] = STATUS_NON_FINITE
    expected[n_valid == 0] = STATUS_NO_VALID_SAMPLES
    cleaned = np.where(batch.valid, batch.samples, 0.0)
    cleaned[~np.isfinite(cleaned)] = 0.0
    status, samples = checked_samples(batch)
    assert status.dtype == np.int8 and status.tolist() == expected.tolist()
    assert status.tolist() == [STATUS_NON_FINITE, STATUS_NO_VALID_SAMPLES, STATUS_NO_VALID_SAMPLES,
                               STATUS_NON_FINITE, 0, 0]
    assert samples.dtype == cleaned.dtype and samples.tobytes() == cleaned.tobytes()


def test_both_result_classes_have_every_field_of_the_result_record():
    # the record's dtype is the one list of per-waveform fields: the batch's attributes and a waveform's follow it
    batch = WaveformBatch.from_waveforms([synthetic([100.0], [50.0], [3.0], [SQ2], 1.0), np.zeros(5)], SPACING, [1, 2],
                                         valid=[np.ones(160, bool), np.zeros(5, bool)])
    r = decompose_batch(batch, CONFIG.replace(generations=5), PULSE)
    assert [f.name for f in dataclasses.fields(Decomposition)][:len(WAVEFORM_FIELDS)] == list(WAVEFORM_FIELDS)
    assert all(getattr(r, name).shape == (2,) for name in WAVEFORM_FIELDS)
    assert r.status.dtype == r.message.dtype == np.int8 and not hasattr(r, "n_echoes")  # n_echoes: echo_offsets
    one = r.waveform(1)
    assert (one.status, one.message, one.nfev) == ("no_valid_samples", "no_echoes", 0)
    assert type(r.waveform(0).nfev) is int and type(r.waveform(0).rmse) is float
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(r)).nfev, r.nfev)


def test_flat_waveform_has_no_echo_and_a_background():
    y = np.random.default_rng(9).normal(50.0, 1.0, 100)
    r = decompose_waveform(y, SPACING, config=CONFIG.replace(noise_threshold=6.0), pulse=PULSE)
    assert r.amplitude.size == 0
    assert r.background == pytest.approx(50.0, abs=2.0)


def test_gaps_keep_every_valid_sample_at_its_time():
    y = synthetic([100.0], [70.0], [3.0], [SQ2], 1.0)
    valid = np.ones(y.size, bool)
    valid[20:40] = False
    y[20:40] = 0.0  # NEON-style zero gap
    r = decompose_waveform(y, SPACING, seed=1, config=CONFIG, valid=valid, pulse=PULSE)
    k = matched(r, [70.0])[0]
    assert r.position[k] == pytest.approx(70.0, abs=0.25)
    assert r.background == pytest.approx(30.0, abs=2.0)


def test_gaussian_model_fixes_alpha():
    y = synthetic([100.0], [70.0], [3.0], [1.8], 1.0)
    r = decompose_waveform(y, SPACING, config=CONFIG.replace(model="gaussian"), pulse=PULSE)
    np.testing.assert_array_equal(r.alpha, SQ2)


def test_an_afterpulse_is_not_an_echo_under_the_system_model():
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(80.0)
    rng = np.random.default_rng(3)
    y = tabulated_model(t, 3.0, 180.0, 25.4, shape.s_min, shape) + rng.normal(0, 0.6, t.size)
    system = DecompositionConfig(model="system")
    d = decompose_waveform(np.round(y), 1000.0, 0, system, pulse=nominal_pulse(riegl.fwhm_ps, response=riegl))
    assert d.amplitude.size == 1
    assert d.position[0] == pytest.approx(25.4, abs=0.05)
    # the generalized Gaussian cannot take the afterpulse: it needs a second echo behind the first
    g = decompose_waveform(np.round(y), 1000.0, 0, DecompositionConfig(), pulse=nominal_pulse(riegl.fwhm_ps))
    assert g.amplitude.size >= 2 and g.position.max() > 27.0


def test_spacings_equal_to_six_digits_share_one_echo_table_and_give_the_same_echoes():
    # LVIS: every shot's spacing is its own, 1 ns within 1e-6; a table a shot cost 0.3 s each
    riegl = named_response("riegl")
    pulse = nominal_pulse(riegl.fwhm_ps, response=riegl)
    system = DecompositionConfig(model="system")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(120.0)
    rng = np.random.default_rng(5)
    waves = [tabulated_model(t, 3.0, np.array([150.0, 60.0]), np.array([30.0 + k, 70.0 - k]),
                             np.full(2, shape.s_min), shape) + rng.normal(0, 0.6, t.size) for k in range(8)]
    spacing = 1000.0 * (1.0 + 1e-7 * (np.arange(8) - 4))
    tables = echo_shapes(system, pulse, spacing)
    assert len(tables) == 8 and len({id(s) for s in tables.values()}) == 1
    seeds = np.arange(8)
    varied = decompose_batch(WaveformBatch.from_waveforms(waves, spacing, seeds), system, pulse, threads=1)
    exact = decompose_batch(WaveformBatch.from_waveforms(waves, np.full(8, 1000.0), seeds), system, pulse, threads=1)
    assert np.array_equal(varied.echo_offsets, exact.echo_offsets)
    assert np.abs(varied.position - exact.position).max() < 1e-3  # samples
    assert np.abs(varied.amplitude - exact.amplitude).max() < 1e-2 * exact.amplitude.max()
    for i in range(8):  # and each waveform's model is its own spacing's
        assert varied.waveform(i).model(t) == pytest.approx(exact.waveform(i).model(t), rel=1e-4, abs=1e-3)


def test_a_long_records_echoes_are_those_of_its_window_decomposed_alone():
    # on a long record (GEDI, LVIS) the generalized Gaussian's tails are cut at 1e-3 of the noise (TAIL_FLOOR): the
    # fit of its signal window as a short record (exact tails) lands on the same echoes, not to the bit
    position = np.array([300.0, 318.0, 345.0])
    y = synthetic(np.array([90.0, 60.0, 150.0]), position, [PULSE_SIGMA] * 3, [1.2, 1.5, 1.3], noise=1.5, n=1024,
                  seed=3)
    valid = np.zeros(y.size, bool)
    valid[250:400] = True
    long = decompose_waveform(y, SPACING, seed=1, config=CONFIG, pulse=PULSE, valid=valid)
    short = decompose_waveform(y[250:400], SPACING, seed=1, config=CONFIG, pulse=PULSE)
    assert long.kept.sum() == short.kept.sum() == 3
    np.testing.assert_allclose(long.position[long.kept], short.position[short.kept] + 250.0, atol=0.01)
    np.testing.assert_allclose(long.amplitude[long.kept], short.amplitude[short.kept], rtol=1e-3)
    assert not np.array_equal(long.position[long.kept], short.position[short.kept] + 250.0)
    np.testing.assert_allclose(long.position[long.kept], position, atol=0.3)
