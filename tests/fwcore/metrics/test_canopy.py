"""L2B's formulas on L2B's own rv and rg (to 1e-4, the issue's target), and the ground return's fit on a
waveform made of a known ground return and canopy."""

import numpy as np

from fwcore.metrics.canopy import CanopySettings, GroundPulse, canopy_cover, canopy_energy, extended_gaussian, \
    gap_probability, ground_return, plant_area_index, vertical_profile


def test_l2b_formulas_on_l2b_energies(gedi_beams):
    for b in gedi_beams:
        pgap = gap_probability(b["rv"], b["rg"], b["rhov"] / b["rhog"])
        assert np.abs(pgap - b["pgap_theta"]).max() < 1e-4
        assert np.abs(canopy_cover(pgap, b["l2b_cos_zenith"]) - b["cover"]).max() < 1e-4
        assert np.abs(plant_area_index(pgap, b["l2b_cos_zenith"], b["rossg"], b["omega"]) - b["pai"]).max() < 1e-4


def test_no_energy_is_all_gap_and_no_ground_is_infinite_pai():
    assert gap_probability(0.0, 0.0) == 1.0
    assert np.isinf(plant_area_index(gap_probability(10.0, 0.0), 1.0))


def test_ground_return_recovers_a_known_ground_and_its_canopy():
    x = np.arange(1, 201, dtype=float)
    truth = np.array([5000.0, 120.0, 4.0, 0.15])
    ground = extended_gaussian(truth, x)
    canopy_truth = 300.0 * np.exp(-0.5 * ((x - 80.0) / 6.0) ** 2)
    signal = ground + canopy_truth
    peak = x[np.argmax(ground)] - 1  # the lowest mode, 0-based like L2A's zcross
    model, rg = ground_return(signal, peak, GroundPulse(4.0, 0.01, 0.15, 0.001))
    assert abs(rg / truth[0] - 1) < 0.01
    rv = canopy_energy(signal, model, peak).sum()
    assert abs(rv / canopy_truth.sum() - 1) < 0.02


def test_vertical_profile_puts_the_plant_area_at_its_height():
    heights = np.arange(40.0, -5.0, -0.5)  # 0.5 m samples from 40 m down to below the ground
    canopy = np.where((heights > 20) & (heights < 25), 10.0, 0.0)
    cover_z, pai_z, pavd_z = vertical_profile(heights, canopy, canopy.sum(), 1000.0, 1.0, CanopySettings())
    assert pai_z[0] == pai_z[4] > 0 and pai_z[5] == 0  # all the area between 20 and 25 m
    assert np.isclose(np.trapezoid(pavd_z, dx=5.0), pai_z[0], rtol=0.2)
    assert cover_z[0] == canopy_cover(gap_probability(canopy.sum(), 1000.0), 1.0)
