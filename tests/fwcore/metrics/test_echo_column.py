"""A small footprint's column metrics from its echoes: hand-computed columns, and the ground against a simulated
flight's truth and L2B's fitted ground on the same pulses."""

from statistics import NormalDist

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
import math

from numba import njit

from fwcore.metrics.echo_column import (ERFC_TWO_BELOW, ERFC_ZERO_ABOVE, FWHM_PER_SIGMA, NO_ECHO, NOT_DECOMPOSED,
                                        _erfc, echo_column_metrics, pulse_column_metrics)
from fwcore.metrics.pulses import batch_metrics
from fwcore.metrics.waveform import NO_AXIS
from fwcore.pulses import echo_positions, pulse_waveforms
from fwcore.studies.simulate import SceneConfig, SensorConfig, simulate_flight

DROP = 0.15  # m a sample: 1 ns


def _columns(z, energy, fwhm, kept=None, decomposed=True, drop=DROP, cos_zenith=1.0):
    z = np.asarray(z, float)
    return echo_column_metrics(np.array([0, z.size]), np.ones(z.size, bool) if kept is None else np.asarray(kept),
                               np.arange(z.size, dtype=float), z, np.asarray(fwhm, float), np.asarray(energy, float),
                               np.array([decomposed]), np.array([drop]), np.array([cos_zenith]))


@njit
def _both(x):
    ours, libm = np.empty(x.size), np.empty(x.size)
    for i in range(x.size):
        ours[i], libm[i] = _erfc(x[i]), math.erfc(x[i])
    return ours, libm


def test_the_erfc_tails_are_libms_own_values_bit_for_bit():
    # the shortcut must not move a metric: erfc compiled as the kernels compile it, flat beyond the thresholds
    x = np.r_[np.linspace(-60.0, 60.0, 2_000_001), -np.inf, np.inf, np.nan, ERFC_TWO_BELOW, ERFC_ZERO_ABOVE,
              np.nextafter(ERFC_TWO_BELOW, 0.0), np.nextafter(ERFC_ZERO_ABOVE, 0.0)]
    ours, libm = _both(x)
    assert np.array_equal(ours, libm, equal_nan=True)
    assert (libm[x <= ERFC_TWO_BELOW] == 2.0).all() and (libm[x >= ERFC_ZERO_ABOVE] == 0.0).all()
    near = _both(np.array([-5.8, 27.0]))[1]  # the thresholds sit in the tails, not beyond them
    assert near[0] < 2.0 and near[1] > 0.0


def test_a_canopy_and_a_ground_echo_by_hand():
    # canopy 20 m over the ground, energy 30; the ground's 40; both 4 samples wide (sd 0.255 m)
    m = _columns([20.0, 0.0], [30.0, 40.0], [4.0, 4.0])
    sd = 4.0 / FWHM_PER_SIGMA * DROP
    assert m.reason == [""]
    assert m.ground_z[0] == 0.0 and m.rg[0] == 40.0 and m.rv[0] == 30.0
    pgap = 1.0 - 30.0 / (30.0 + 1.5 * 40.0)  # L2B's rhov/rhog 1.5
    assert m.pgap[0] == pytest.approx(pgap) and m.cover[0] == pytest.approx(1.0 - pgap)
    assert m.pai[0] == pytest.approx(-np.log(pgap) / 0.5)
    # half the energy (35 of 70) lies under the height where the ground's Gaussian holds 35 of its 40
    assert m.rh[0, 50] == pytest.approx(NormalDist().inv_cdf(35 / 40) * sd, abs=0.015)
    assert m.rh[0, 0] == pytest.approx(-3 * sd, abs=0.011) and m.rh[0, 100] == pytest.approx(20 + 3 * sd, abs=0.011)
    # 98 %: 1.4 of the canopy's 30 above it
    assert m.rh[0, 98] == pytest.approx(20 + NormalDist().inv_cdf(1 - 1.4 / 30) * sd, abs=0.015)
    # the profile: at 0 m all the canopy is above, at 20 m half of it, at 25 m none
    pai_z = m.pai_z[0]
    assert pai_z[0] == pytest.approx(-np.log(pgap) / 0.5)
    assert pai_z[4] == pytest.approx(-np.log(1 - 15 / 90) / 0.5, rel=1e-6)
    assert pai_z[5] == pytest.approx(0.0, abs=1e-9)
    assert m.pavd_z[0, 4] == pytest.approx(-(pai_z[5] - pai_z[3]) / 10.0)


def test_a_single_echo_is_bare_ground_without_a_fit():
    m = _columns([12.5], [80.0], [4.0], cos_zenith=0.9)
    assert m.ground_z[0] == 12.5 and m.rv[0] == 0.0 and m.rg[0] == 80.0
    assert m.cover[0] == 0.0 and m.pai[0] == 0.0 and np.all(m.pai_z[0] == 0.0)
    assert m.rh[0, 50] == pytest.approx(0.0, abs=0.011)  # symmetric about the ground
    assert m.rh[0, 100] == pytest.approx(-m.rh[0, 0], abs=0.011)


def test_the_ground_is_the_last_kept_echo_and_each_null_says_why():
    kept = _columns([20.0, 5.0, -30.0], [30.0, 40.0, 10.0], [4.0] * 3, kept=[True, True, False])
    assert kept.ground_z[0] == 5.0 and kept.rv[0] == 30.0  # the filtered echo under the ground counts for nothing
    assert _columns([20.0], [30.0], [4.0], kept=[False]).reason == [NO_ECHO]
    assert _columns([20.0], [30.0], [4.0], decomposed=False).reason == [NOT_DECOMPOSED]
    nothing = _columns([20.0], [30.0], [4.0], drop=np.nan)
    assert nothing.reason == [NO_AXIS] and np.isnan(nothing.ground_z[0]) and np.isnan(nothing.rh[0]).all()


@pytest.fixture(scope="module")
def simulated():
    """300 pulses of the simulated flight (ground, trees, roofs), decomposed by the engine."""
    sensor = SensorConfig()
    flight = simulate_flight(300, sensor, SceneConfig(), seed=5)
    pulse = nominal_pulse(sensor.pulse_fwhm_ps)
    result = decompose_batch(pulse_waveforms(flight.pulses, 0), DecompositionConfig(), pulse, threads=1)
    xyz = echo_positions(flight.pulses, result, pulse.range_offset_ps)
    truth = flight.truth
    row = {int(p): i for i, p in enumerate(flight.pulses.pulse_id)}
    ground = np.full(len(flight.pulses), np.nan)
    for pulse_id, surface, z in zip(truth["pulse_id"], truth["surface"], truth["z"]):
        if surface == "ground":
            ground[row[int(pulse_id)]] = z
    return (pulse_column_metrics(flight.pulses, result, xyz), batch_metrics(flight.pulses, result, pulse),
            ground)


def test_the_echo_ground_is_the_true_ground_and_l2bs_to_tolerance(simulated):
    echoes, full, truth = simulated
    seen = np.isfinite(truth)  # the pulses whose beam reached the ground (not a roof's)
    assert seen.sum() > 200
    error = np.abs(echoes.ground_z[seen] - truth[seen])
    assert np.median(error) < 0.01 and np.percentile(error, 95) < 0.03
    # L2B's fitted ground on the same pulses: the same to 2 cm on most, never closer to the truth in the median
    agree = np.abs(echoes.ground_z[seen] - full.ground_z[seen])
    assert np.median(agree) < 0.02 and np.mean(agree < 0.05) > 0.85
    assert np.median(error) <= np.median(np.abs(full.ground_z[seen] - truth[seen]))


def test_the_echo_cover_follows_l2bs_cover(simulated):
    echoes, full, _ = simulated
    both = np.isfinite(echoes.cover) & np.isfinite(full.cover)
    assert both.sum() > 250
    assert abs(np.mean(echoes.cover[both]) - np.mean(full.cover[both])) < 0.03
    assert np.corrcoef(echoes.cover[both], full.cover[both])[0, 1] > 0.9
