"""Simulated flights: the truth renders to the stored samples, the file reads back as written (the flight written
chunk by chunk with its truth: tests/fwcore/studies/test_truth.py)."""

import dataclasses

import numpy as np
import pytest

from fwcore.io import read_pulses
from fwcore.io.geolocate import geolocate
from fwcore.io.writer import write_waveform_las
from fwcore.studies.simulate import MAX_ECHOES, SceneConfig, SensorConfig, render_truth, simulate_flight

NOISELESS = SensorConfig(noise_sigma=0.0, shot_noise=0.0)


def test_truth_renders_to_the_stored_samples_within_quantisation():
    flight = simulate_flight(300, NOISELESS, seed=3)
    rendered = render_truth(flight.truth, NOISELESS.samples_per_packet, NOISELESS.sample_spacing_ps,
                            NOISELESS.background)
    stored = flight.pulses.samples.reshape(300, -1)
    unsaturated = rendered < 255
    assert np.abs(stored - rendered)[unsaturated].max() <= 0.5 + 1e-9
    assert (stored[~unsaturated] == 255).all()


def test_the_scene_has_one_to_six_echoes_of_varied_shape():
    flight = simulate_flight(4000, seed=1)
    counts = np.unique(flight.truth["pulse_id"], return_counts=True)[1]
    assert counts.min() == 1 and counts.max() == MAX_ECHOES
    assert set(flight.truth["surface"]) == {"ground", "vegetation", "roof"}
    assert flight.truth["alpha"].min() < 1.3 and flight.truth["alpha"].max() > 2.1
    snr = flight.truth["amplitude"] / flight.truth["noise_sigma"]
    assert (snr < 6).sum() > 100  # weak echoes near the noise floor


@pytest.mark.parametrize("layout, bits", [("las13-wdp", 8), ("las14-internal", 16)])
def test_the_file_reads_back_with_the_truths_pulse_ids_and_geometry(tmp_path, layout, bits):
    sensor = SensorConfig(bits=bits, background=300.0 if bits == 16 else 12.0)
    flight = simulate_flight(200, sensor, SceneConfig(), seed=5, source_file="sim.las")
    path = write_waveform_las(tmp_path / "sim.las", flight.pulses, layout, bits=bits)
    pulses = read_pulses(path)
    assert sorted(pulses.pulse_id) == sorted(np.unique(flight.truth["pulse_id"]))
    np.testing.assert_array_equal(pulses.samples, flight.pulses.samples)
    assert (pulses.bits_per_sample == bits).all()
    # each true echo, geolocated the reader's way from the file's anchor and direction, is where the truth says
    index = {int(p): i for i, p in enumerate(pulses.pulse_id)}
    owner = np.array([index[int(p)] for p in flight.truth["pulse_id"]])
    xyz = geolocate(pulses.anchor[owner], pulses.anchor_location_ps[owner], pulses.direction[owner],
                    flight.truth["time_ps"])
    truth = np.stack([flight.truth[c] for c in "xyz"], axis=1)
    assert np.abs(xyz - truth).max() < 0.01  # 1 cm: LAS millimetre coordinates and float32 directions


def test_system_returns_are_threshold_crossings():
    sensor = SensorConfig()
    flight = simulate_flight(500, sensor, seed=2)
    p = flight.pulses
    threshold = sensor.background + sensor.detection_threshold * sensor.noise_sigma
    samples = p.samples.reshape(500, -1)
    owner = np.repeat(np.arange(500), np.diff(p.return_offsets))
    at = (p.return_location_ps / sensor.sample_spacing_ps).astype(int)
    crossing = samples[owner, at] > threshold
    strongest = at == samples[owner].argmax(axis=1)
    assert np.all(crossing | strongest)  # a pulse with no crossing keeps its strongest sample
    assert np.all(np.diff(p.return_offsets) >= 1)


def test_same_seed_same_flight_and_bad_settings_are_refused():
    a, b = simulate_flight(50, seed=9), simulate_flight(50, seed=9)
    np.testing.assert_array_equal(a.pulses.samples, b.pulses.samples)
    assert not np.array_equal(a.pulses.samples, simulate_flight(50, seed=10).pulses.samples)
    with pytest.raises(ValueError, match="bits must be 8 or 16"):
        SensorConfig(bits=12)
    with pytest.raises(ValueError, match="packet is too short"):
        simulate_flight(200, SensorConfig(samples_per_packet=40))


@pytest.mark.parametrize("name", ["riegl", "leica"])
def test_a_flight_of_a_measured_response_renders_its_echoes_in_that_shape(name):
    from fwcore.instrument.measure import pulses_response
    from fwcore.instrument.response import SHIPPED_SPACING_PS, named_response

    response = named_response(name)
    sensor = SensorConfig(pulse_fwhm_ps=response.fwhm_ps, sample_spacing_ps=SHIPPED_SPACING_PS[name],
                          noise_sigma=0.0, shot_noise=0.0, response=response)
    flight = simulate_flight(300, sensor, seed=3)
    rendered = render_truth(flight.truth, sensor.samples_per_packet, sensor.sample_spacing_ps, sensor.background,
                            response)
    stored = flight.pulses.samples.reshape(300, -1)
    unsaturated = rendered < 255
    assert np.abs(stored - rendered)[unsaturated].max() <= 0.5 + 1e-9
    assert np.isnan(flight.truth["alpha"]).all()
    # the simulated returns, measured as a run measures a file, give back the response, widened a little by
    # the targets (the narrowest returns of the scene are up to 15% wider than the response)
    noisy = simulate_flight(2000, dataclasses.replace(sensor, noise_sigma=0.6, shot_noise=0.02), seed=4)
    measured = pulses_response(noisy.pulses, np.arange(2000), "simulated")
    assert 0.98 * response.fwhm_ps <= measured.fwhm_ps <= 1.15 * response.fwhm_ps
    if name == "riegl":
        assert measured.afterpulse()[0] == pytest.approx(response.afterpulse()[0], abs=1000)


def test_a_riegl_export_like_sensor_scales_its_echoes_and_varies_each_pulses_afterpulse():
    from fwcore.instrument.response import named_response

    response = named_response("riegl")
    base = SensorConfig(pulse_fwhm_ps=response.fwhm_ps, samples_per_packet=62, bits=16, pre_trigger_ps=10000.0,
                        noise_sigma=0.0, shot_noise=0.0, response=response)
    scene = SceneConfig(canopy_cover=0.0, roof_fraction=0.0)
    plain = simulate_flight(200, base, scene, seed=5)
    scaled = simulate_flight(200, dataclasses.replace(base, amplitude_scale=20.0), scene, seed=5)
    np.testing.assert_allclose(scaled.truth["amplitude"], 20.0 * plain.truth["amplitude"])
    jittered = simulate_flight(200, dataclasses.replace(base, amplitude_scale=20.0, afterpulse_jitter=1.0), scene,
                               seed=5)
    # the truth (the echo) is the same; the samples differ behind each echo by up to the mean afterpulse's height
    np.testing.assert_array_equal(jittered.truth["amplitude"], scaled.truth["amplitude"])
    delay, height = response.afterpulse()
    diff = (jittered.pulses.samples - scaled.pulses.samples).reshape(200, -1)
    at = np.rint((scaled.truth["time_ps"] + delay) / 1000.0).astype(int)
    behind = np.abs(diff[np.arange(200), at]) / (height * scaled.truth["amplitude"])
    assert behind.max() <= 1.0 + 0.01 and behind.max() > 0.8 and np.median(behind) > 0.2
    # elsewhere (well before each echo) the samples agree to the quantisation
    assert np.abs(diff[:, :5]).max() <= 1.0


def test_grass_on_open_ground_puts_a_weak_surface_just_above_the_ground_on_its_share_of_pulses():
    scene = SceneConfig(canopy_cover=0.0, roof_fraction=0.0, ground_cover_fraction=0.7,
                        ground_cover_share=(0.03, 0.1), ground_cover_height_m=(0.15, 0.45))
    flight = simulate_flight(2000, SensorConfig(), scene, seed=3)
    truth = flight.truth
    ids, counts = np.unique(truth["pulse_id"], return_counts=True)
    assert counts.max() == 2 and abs((counts == 2).mean() - 0.7) < 0.03
    grass = truth["surface"] == "vegetation"
    ground = truth["surface"] == "ground"
    by_pulse = {pid: i for i, pid in enumerate(truth["pulse_id"][ground])}
    below = np.array([by_pulse[pid] for pid in truth["pulse_id"][grass]])
    share = truth["amplitude"][grass] / truth["amplitude"][ground][below]
    assert share.min() >= 0.03 and share.max() <= 0.1
    above_m = (truth["time_ps"][ground][below] - truth["time_ps"][grass]) * 299792458.0e-12 / 2.0
    cos20 = np.cos(np.radians(20.0))  # the scan's widest angle stretches the range between them
    assert above_m.min() >= 0.15 - 1e-9 and above_m.max() <= 0.45 / cos20 + 1e-9
    # without it the scene is the one it was: one surface a pulse
    plain = simulate_flight(2000, SensorConfig(), dataclasses.replace(scene, ground_cover_fraction=0.0), seed=3)
    assert np.unique(plain.truth["pulse_id"], return_counts=True)[1].max() == 1
