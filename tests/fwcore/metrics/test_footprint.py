"""A large footprint from small echoes: weights, the vertical axis, the pulse, and GEDI's metrics of it."""

import math

import numpy as np

from fwcore.metrics.footprint import FootprintSensor, footprint_metrics, footprint_waveform


def test_one_echo_is_the_pulse_at_its_elevation_weighted_by_the_footprint():
    s = FootprintSensor()
    w0, top0 = footprint_waveform(np.zeros(1), np.zeros(1), np.array([100.0]), np.array([2.0]), s)
    w1, top1 = footprint_waveform(np.array([s.sigma_m]), np.zeros(1), np.array([100.0]), np.array([2.0]), s)
    np.testing.assert_allclose(w0.sum(), 2.0, rtol=1e-9)  # the pulse keeps the energy
    np.testing.assert_allclose(w1.sum(), 2.0 * math.exp(-0.5), rtol=1e-9)  # one sigma off the centre
    peak = top0 - np.argmax(w0) * s.sample_m
    assert abs(peak - 100.0) <= s.sample_m / 2
    # the pulse's width: its FWHM 15.6 ns of range
    half = w0 >= w0.max() / 2
    assert abs(half.sum() * s.sample_m - 15.6 * 0.149896229) < 2 * s.sample_m


def test_ground_and_rh98_of_a_canopy_over_flat_ground():
    """A disc of echoes: ground at 50 m, a canopy layer at 70 m holding the same energy; GEDI's lowest mode is
    the ground and RH98 is near the canopy's 20 m (the pulse's spread above it)."""
    rng = np.random.default_rng(0)
    n = 4000
    dx, dy = rng.uniform(-15, 15, n), rng.uniform(-15, 15, n)
    z = np.where(np.arange(n) % 2 == 0, 50.0, 70.0)
    samples, top = footprint_waveform(dx, dy, z, np.ones(n))
    m = footprint_metrics(samples, top)
    assert m["reason"] == ""
    assert abs(m["ground_z"] - 50.0) < 0.15
    assert 20.0 < m["rh"][98] < 22.5 and abs(m["rh"][50] - 10.0) < 10.0
    # equal energies, rhov/rhog 1.5: Pgap = 1 - 1 / (1 + 1.5)
    assert abs(m["pgap"] - 0.6) < 0.05
    assert footprint_metrics(np.zeros(0), math.nan)["reason"]
