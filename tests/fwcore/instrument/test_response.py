"""The instrument's response as data: NEON's recorded impulse response read against facts read off it, the shipped
ones against those measured on the bundled files, saved and loaded, a Gaussian's, and named errors for bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_waveform
from fwcore.instrument.pulse import SystemPulse, nominal_pulse
from fwcore.instrument.response import gaussian_response, load_response, named_response, response_from_samples

DATA = Path(__file__).resolve().parents[3] / "examples" / "data"
NEON_IMPULSE = DATA / "neon_harvard" / "system_impulse.csv"


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
