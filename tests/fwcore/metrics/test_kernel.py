"""The numba kernel against its NumPy reference (pulse_metrics, a waveform at a time) on the shared GEDI beams and
on waveforms that provoke every reason for null metrics."""

import numpy as np
import pytest

from fwcore.metrics.algorithms import l2a_algorithm
from fwcore.metrics.waveform import MetricSettings, NO_AXIS, NO_GROUND, NO_NOISE, NO_SIGNAL, NOT_FINITE, \
    reference_metrics, waveform_metrics

FIELDS = ("toploc", "botloc", "ground_index", "ground_z", "mode_z", "rh", "rv", "rg", "pgap", "cover", "pai", "cover_z", "pai_z",
          "pavd_z")


def _both(*args, **kwargs):
    return waveform_metrics(*args, **kwargs), reference_metrics(*args, **kwargs)


@pytest.mark.parametrize("settings", [MetricSettings(), MetricSettings(smoothing_width_zcross=3.5,
                                                                       back_threshold_sd=4.0),
                                      l2a_algorithm(2), MetricSettings(select_mode=True, energy_thresh=400.0,
                                                                       max_modes=2)])
def test_the_kernel_is_its_reference_on_gedi(gedi_beams, settings):
    for b in gedi_beams:
        args = (b["samples"], b["offsets"], b["noise_mean"], b["noise_sd"], b["first_z"], b["metres_per_sample"],
                b["cos_zenith"], b["pulse"])
        kernel, reference = _both(*args, settings=settings)
        assert kernel.reason == reference.reason
        for name in FIELDS:
            assert np.allclose(getattr(kernel, name), getattr(reference, name), rtol=1e-6, atol=1e-6,
                               equal_nan=True), name


def test_every_reason_for_null_metrics():
    x = np.arange(200.0)
    pulse = 100 + 400 * np.exp(-0.5 * ((x - 120) / 4) ** 2)
    waves = [pulse, np.full(200, 100.0), np.r_[pulse[:50], np.nan, pulse[51:]], pulse, pulse]
    samples = np.concatenate(waves)
    offsets = np.arange(6) * 200
    noise_mean = np.array([100.0, 100.0, 100.0, np.nan, 100.0])
    first_z = np.array([50.0, 50.0, 50.0, 50.0, np.nan])
    kernel, reference = _both(samples, offsets, noise_mean, np.full(5, 2.0), first_z, np.full(5, 0.15), np.ones(5),
                              np.tile([4.0, 0.1, 0.1, 0.01], (5, 1)))
    assert kernel.reason == reference.reason == ["", NO_SIGNAL, NOT_FINITE, NO_NOISE, NO_AXIS]
    assert abs(kernel.ground_z[0] - (50.0 - 120 * 0.15)) < 0.04
    # a signal still rising at the waveform's end (cut off by the range gate): no mode, no ground
    rising = 100 + np.linspace(0.0, 60.0, 200)
    k, r = _both(rising, np.array([0, 200]), np.array([100.0]), np.array([2.0]), np.array([50.0]), np.array([0.15]),
                 np.ones(1), np.array([[4.0, 0.1, 0.1, 0.01]]))
    assert k.reason == r.reason == [NO_GROUND]


def test_the_profile_finds_the_scans_sample_at_every_height():
    """_profile's bisection for each height bin's first sample at or below it: the linear scan's sample, heights
    landing exactly on a sample included (drop 0.5 m, bins of 1 m), and bins above the waveform's top."""
    from fwcore.metrics.kernel import _profile

    rng = np.random.default_rng(3)
    canopy = rng.uniform(0.0, 5.0, 300)
    canopy[200:] = 0.0
    for ground, drop, bins in ((210.0, 0.5, 150), (210.25, 0.15, 40), (37.5, 1.0, 60)):
        cover, pai, pavd = np.empty(bins), np.empty(bins), np.empty(bins)
        _profile(canopy, ground, drop, canopy.sum() * 1.3, 0.9, 0.5, 1.0, 1.0, cover, pai, pavd)
        pgap = 1.0 - np.cumsum(canopy) / (canopy.sum() * 1.3)
        expected = []
        for h in np.arange(bins) * 1.0:
            value = 1.0
            if h < ground * drop:
                value = pgap[next((j for j in range(canopy.size) if (ground - j) * drop <= h), 0)]
            expected.append(0.9 * (1.0 - min(max(value, 0.0), 1.0)))
        np.testing.assert_array_equal(cover, expected)
        assert cover[0] > 0.0 and (cover[-1] == 0.0) == (bins * 1.0 >= ground * drop)
