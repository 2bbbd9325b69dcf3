"""The instrument's response: measured on real files against facts read off them, the echo shape built from
it against a naive reference, and what it changes in the engine (an afterpulse is not an echo)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch, decompose_waveform
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.peak import main_lobe
from fwcore.instrument.pulse import SystemPulse, nominal_pulse
from fwcore.instrument.response import (SystemResponse, gaussian_response, load_response, named_response,
                                        pulses_response, response_from_samples)
from fwcore.instrument.shape import echo_shape
from fwcore.io import PointRange, read_pulses
from fwcore.engine.model import table_peak_offset, table_reach, table_value, tabulated_area, tabulated_model
from fwcore.engine.optimizers.local import model_and_jacobian
from fwcore.engine.preprocess import initial_echoes
from fwcore.pulses import pulse_waveforms
from tests.fwcore import naive

DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
LEICA = DATA / "leica_als" / "leica_a.las"
RIEGL = DATA / "pulsewaves" / "riegl_example3.pls"
NEON_IMPULSE = DATA / "neon_harvard" / "system_impulse.csv"


@pytest.fixture(scope="module")
def leica_response() -> SystemResponse:
    pulses = read_pulses(LEICA)
    return pulses_response(pulses, np.flatnonzero(np.diff(pulses.return_offsets) == 1), "single returns")


@pytest.fixture(scope="module")
def riegl_response() -> SystemResponse:
    pulses = read_pulses(PointRange(str(RIEGL), 0, 5000))
    return pulses_response(pulses, np.arange(len(pulses)), "isolated echoes")


def test_leica_response_rises_slowly_falls_fast_with_a_tail_and_an_undershoot(leica_response):
    r = leica_response
    assert r.n_pulses > 200  # the narrower half of the strong single returns
    assert r.fwhm_ps == pytest.approx(10300, abs=700)
    rise = -np.interp(0.1, r.response[:np.argmax(r.response)], r.times[:np.argmax(r.response)])
    assert 7000 <= rise <= 10000  # 10% to the peak over about 8 ns
    assert r.at(4000) == pytest.approx(0.52, abs=0.08)  # half the peak 4 ns behind it
    np.testing.assert_allclose(r.at([6000, 8000, 10000]), [0.37, 0.25, 0.13], atol=0.05)  # the tail
    undershoot = r.at(np.arange(18000, 28001, 1000))
    assert (undershoot < 0).all() and undershoot.mean() == pytest.approx(-0.02, abs=0.01)


def test_riegl_response_has_its_afterpulse_10_ns_behind_at_4_percent(riegl_response):
    r = riegl_response
    assert r.fwhm_ps == pytest.approx(4100, abs=300)
    delay, height = r.afterpulse()
    assert 9500 <= delay <= 11500
    assert 0.025 <= height <= 0.05


def test_neon_impulse_response_from_its_csv():
    r = load_response(NEON_IMPULSE)
    # read off the file: background 195 DN, peak 2018 DN at sample 30; half height crossed near 23.0 and 38.2
    assert r.fwhm_ps == pytest.approx(15100, abs=250)
    assert r.source == "system_impulse.csv"
    assert r.at(0.0) == pytest.approx(1.0, abs=0.01)
    assert r.at(-8000) < r.at(8000)  # it rises faster than it falls: asymmetric


def test_response_round_trips_and_rides_in_the_pulse(tmp_path, riegl_response):
    path = tmp_path / "riegl.json"
    riegl_response.save(path)
    again = load_response(path)
    np.testing.assert_allclose(again.response, riegl_response.response, atol=1e-6)
    pulse = nominal_pulse(again.fwhm_ps, response=again)
    assert SystemPulse.from_dict(json.loads(json.dumps(pulse.to_dict()))) == pulse


def test_bad_response_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="missing.csv: cannot read"):
        load_response(tmp_path / "missing.csv")
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(ValueError, match="bad.json: not a system response"):
        load_response(bad)
    flat = tmp_path / "flat.csv"
    flat.write_text("system_impulse\n5\n5\n5\n5\n5\n5\n")
    with pytest.raises(ValueError, match="flat.csv"):
        load_response(flat)


@pytest.mark.parametrize("s", [1.75, 2.4, 3.9])
def test_tabulated_echo_matches_the_naive_reference(riegl_response, s):
    shape = echo_shape(riegl_response, 1000.0)
    t = np.linspace(10.0, 50.0, 401)
    expected = naive.response_echo(riegl_response.times, riegl_response.response, 1000.0, 80.0, 21.3, s, t)
    got = tabulated_model(t, 0.0, 80.0, 21.3, s, shape)
    np.testing.assert_allclose(got, expected, atol=80.0 * 1e-2)  # rows interpolated in width: within 1% of the peak
    # the area is the echo's integral
    assert tabulated_area(shape, s) == pytest.approx(np.trapezoid(got / 80.0, t), rel=2e-3)


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


def test_a_return_a_target_widened_starts_as_wide_as_it_is():
    # a target widens both sides: the start takes the whole half-height width, so the rising edge is not
    # left over as an echo of its own
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(80.0)
    y = tabulated_model(t, 3.0, 150.0, 30.3, 1.5 * shape.s_min, shape)
    y = np.round(y + np.random.default_rng(4).normal(0, 0.5, t.size))
    est = initial_echoes(y, 0.4, shape.s_min, shape=shape)
    assert est.n_echoes == 1
    assert est.sigma[0] == pytest.approx(1.5 * shape.s_min, rel=0.1)


def test_a_neighbour_widens_one_side_and_the_start_takes_the_other():
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0)
    t = np.arange(80.0)
    y = tabulated_model(t, 3.0, [150.0, 90.0], [30.3, 35.8], [shape.s_min, shape.s_min], shape)
    y = np.round(y + np.random.default_rng(5).normal(0, 0.5, t.size))
    est = initial_echoes(y, 0.4, shape.s_min, shape=shape)
    assert est.n_echoes >= 2
    first = int(np.argmax(est.amplitude))
    assert est.sigma[first] < 1.2 * shape.s_min  # its whole half-height width would take in the neighbour
    assert np.sort(est.position[np.argsort(est.amplitude)[-2:]]) == pytest.approx([30.3, 35.8], abs=0.5)


@pytest.mark.parametrize("method", ["gold", "richardson-lucy"])
def test_deconvolution_finds_two_overlapping_echoes(method):
    leica = named_response("leica")
    shape = echo_shape(leica, 2000.0)
    t = np.arange(120.0)
    y = tabulated_model(t, 12.0, [150.0, 90.0], [40.0, 46.5], [shape.s_min, shape.s_min], shape)
    y = np.round(y + np.random.default_rng(1).normal(0, 0.5, t.size))
    config = DecompositionConfig(model="system", optimizer=method, deconvolution_iterations=500)
    d = decompose_waveform(y, 2000.0, 0, config, pulse=nominal_pulse(leica.fwhm_ps, response=leica))
    strong = np.sort(d.position[np.argsort(d.amplitude)[-2:]])
    np.testing.assert_allclose(strong, [40.0, 46.5], atol=0.6)


def test_a_gaussian_response_gives_the_gaussian_model():
    response = gaussian_response(4000.0)
    assert response.fwhm_ps == pytest.approx(4000.0, rel=1e-3)
    t = np.arange(60.0)
    y = 10 + 100 * np.exp(-0.5 * ((t - 30.2) / (4.0 / 2.3548)) ** 2)
    config = DecompositionConfig(model="system", fit_target="raw")
    d = decompose_waveform(y, 1000.0, 0, config, pulse=nominal_pulse(4000.0))
    assert d.amplitude.size == 1
    assert d.position[0] == pytest.approx(30.2, abs=0.01) and d.amplitude[0] == pytest.approx(100.0, rel=1e-3)
    assert d.fwhm[0] == pytest.approx(4.0, rel=5e-3) and np.isnan(d.alpha[0])


def test_a_run_measures_the_response_on_the_files_own_returns():
    system = file_system_pulse(LEICA, 1125, DecompositionConfig(model="system"))
    assert system.response is not None and system.response.source.startswith("single returns")
    assert system.fwhm_ps == pytest.approx(system.response.fwhm_ps)
    assert system.shape_tolerance < 0.05  # the measured shape leaves less unexplained than the Gaussian's 0.05
    generalized = DecompositionConfig(model="generalized")
    assert file_system_pulse(LEICA, 1125, generalized).response is None  # not measured where no echo takes it


def test_shipped_responses_are_the_measured_ones(leica_response, riegl_response):
    for name, measured in (("leica", leica_response), ("riegl", riegl_response)):
        shipped = named_response(name)
        assert shipped.fwhm_ps == pytest.approx(measured.fwhm_ps, rel=0.03)
        grid = np.arange(-8000, 20001, 1000)
        np.testing.assert_allclose(shipped.at(grid), measured.at(grid), atol=0.03)


def test_response_from_samples_puts_the_peak_at_zero():
    t = np.arange(40.0)
    r = response_from_samples(5 + 100 * np.exp(-0.5 * ((t - 17.3) / 2.0) ** 2), 1000.0, "test")
    assert r.times[np.argmax(r.response)] == pytest.approx(0.0, abs=300)
    assert r.fwhm_ps == pytest.approx(2.0 * 2.3548 * 1000, rel=0.02)


def test_fwl_info_json_of_one_file_in_a_list_is_a_response_file(tmp_path, riegl_response):
    path = tmp_path / "described.json"
    path.write_text(json.dumps([{"file": "riegl_example3.pls", "system_response": riegl_response.to_dict()}]))
    assert load_response(path).fwhm_ps == pytest.approx(riegl_response.fwhm_ps, rel=1e-4)
    path.write_text(json.dumps([{"system_response": riegl_response.to_dict()}] * 2))
    with pytest.raises(ValueError, match="described.json: not a system response"):
        load_response(path)


@pytest.mark.parametrize("method", ["gold", "richardson-lucy"])
def test_deconvolution_of_noise_alone_finds_no_echo(method):
    y = 12.0 + np.random.default_rng(5).normal(0.0, 0.5, 100).round()
    d = decompose_waveform(y, 1000.0, 0, DecompositionConfig(optimizer=method), pulse=nominal_pulse(4000.0))
    assert d.amplitude.size == 0 and d.message == "no_echoes"


def test_a_too_wide_echo_is_flagged_under_the_system_model():
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0, 4.0)
    t = np.arange(120.0)
    y = tabulated_model(t, 3.0, 80.0, 50.0, 3.6 * shape.s_min, shape)  # 3.6 x the response's FWHM
    config = DecompositionConfig(model="system", fit_target="raw")
    d = decompose_waveform(np.round(y + np.random.default_rng(2).normal(0, 0.3, t.size)), 1000.0, 0, config,
                           pulse=nominal_pulse(riegl.fwhm_ps, response=riegl))
    widest = int(np.argmax(d.fwhm))
    assert d.fwhm[widest] * 1000.0 > 3.0 * riegl.fwhm_ps and d.reject_reason[widest] == "too_wide"


@pytest.mark.parametrize("factor", [1.01, 1.37, 2.2, 3.9])  # between rows: both rows weigh
def test_a_tabulated_echo_is_zero_outside_its_reach_and_not_just_inside(leica_response, factor):
    shape = echo_shape(leica_response, 2000.0, 4.0)
    s = shape.s_min * factor
    before, after = table_reach(shape, s)
    t = np.arange(-before - 3.0, after + 3.0, 1.0 / 128.0)
    values = np.array([table_value(shape, 1.0, 0.0, s, x) for x in t])
    assert not values[(t < -before) | (t > after)].any()
    inside = (t > -before + 2 * shape.step) & (t < after - 2 * shape.step)
    assert values[inside][:8].any() and values[inside][-8:].any()


def test_an_echo_sits_at_its_response_lobes_centroid(leica_response):
    shape = echo_shape(leica_response, 2000.0)
    t = np.arange(-20.0, 30.0, 1.0 / 64.0)
    echo = tabulated_model(t, 0.0, 1.0, 0.0, shape.s_min, shape)
    lobe = main_lobe(echo, int(np.argmax(echo)), 0.05)
    inside = slice(lobe[0], lobe[1] + 1)
    assert np.sum(t[inside] * echo[inside]) / np.sum(echo[inside]) == pytest.approx(0.0, abs=0.02)
    # and the shape says where the echo peaks
    assert t[np.argmax(echo)] == pytest.approx(table_peak_offset(shape, shape.s_min), abs=2 * shape.step)


@pytest.mark.parametrize("stall_generations, generations", [(20, 20), (0, 200)])
def test_mde_stops_on_a_riegl_baseline_no_echo_explains(riegl_response, stall_generations, generations):
    # pulse 875: a strong return, then a baseline that wanders 2-5 DN for 60 ns; LM does not settle and its fit
    # fails the noise model, so lm-mde searches, but no echo explains a baseline: MDE's best moves by less than
    # the noise's share of the fitness, and the stall rule ends the search after one period with LM's fit
    pulses = read_pulses(PointRange(str(RIEGL), 875, 876))
    config = DecompositionConfig(model="system", stall_generations=stall_generations)
    pulse = nominal_pulse(riegl_response.fwhm_ps, response=riegl_response)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, pulse, threads=1)
    assert result.nit[0] == generations
    assert result.fit_error_raw[0] == pytest.approx(57.31, abs=0.01)
