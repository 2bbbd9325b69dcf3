import math

import numpy as np

from fwcore.metrics.ground import cumulative_energy_at, local_energy, lowest_mode, modes, selected_mode, \
    signal_modes
from fwcore.metrics.signal import gaussian_smooth, subbin_grid

SELECTION = dict(pulse_sep_thresh=8.0, cumulative_energy_minimum=1.5, energy_thresh=50.0, amp_thresh=50.0,
                 cumulative_energy_thresh=2.5)  # L2A's algorithm 2


def test_the_lowest_of_two_modes_is_the_ground_at_its_subbin():
    x = np.arange(200.0)
    wave = 50 * np.exp(-0.5 * ((x - 60.3) / 4) ** 2) + 80 * np.exp(-0.5 * ((x - 120.6) / 4) ** 2)
    position, amplitude = modes(wave, 4)
    assert np.allclose(position, [60.25, 120.5]) and amplitude[1] > amplitude[0]
    assert lowest_mode(wave, 40.0, 140.0, 10.0, 4) == 120.5
    assert lowest_mode(wave, 40.0, 100.0, 10.0, 4) == 60.25  # the signal ends before the second
    assert np.isnan(lowest_mode(wave, 40.0, 140.0, 100.0, 4))  # no mode clears the threshold
    assert signal_modes(wave, 40.0, 140.0, 60.0, 4)[0].tolist() == [120.5]


def test_each_rule_of_the_selection_by_hand():
    """Modes at 100, 150 and 190 (top to bottom), the signal ending at 196 (back threshold 10 above the mean)."""
    position = np.array([100.0, 150.0, 190.0])
    amp, cumulative, local = np.array([200.0, 30.0, 30.0]), np.array([90.0, 2.0, 0.5]), np.array([900.0, 40.0, 80.0])
    # the lowest lies within 8 samples of botloc: passed over; the next is weak in every way: passed over too
    assert selected_mode(position, amp, cumulative, local, 196.0, 10.0, **SELECTION) == 0
    # with 60 of local energy the middle mode is the ground
    assert selected_mode(position, amp, cumulative, np.array([900.0, 60.0, 80.0]), 196.0, 10.0, **SELECTION) == 1
    # ... or with 3 % of the energy below it, or an amplitude of 51
    assert selected_mode(position, amp, np.array([90.0, 3.0, 0.5]), local, 196.0, 10.0, **SELECTION) == 1
    assert selected_mode(position, np.array([200.0, 51.0, 30.0]), cumulative, local, 196.0, 10.0, **SELECTION) == 1
    # the lowest mode 10 samples above botloc, 2 % below it and 80 of local energy is the ground; with 0.5 % below
    # it (under cumulative_energy_minimum) it is passed over whatever its local energy
    assert selected_mode(position, amp, np.array([90.0, 2.0, 2.0]), local, 200.0, 10.0, **SELECTION) == 2
    assert selected_mode(position, amp, cumulative, local, 200.0, 10.0, **SELECTION) == 0
    # nothing qualifies: the lowest stays
    assert selected_mode(position, np.array([20.0, 30.0, 30.0]), np.array([1.0, 1.0, 0.5]), local, 196.0, 10.0,
                         **SELECTION) == 2


def test_local_energy_of_a_lone_bump_is_its_area_less_the_line_between_the_window_ends():
    x, a, s = np.arange(0, 100.25, 0.25), 40.0, 4.0
    energy = a * np.exp(-0.5 * ((x - 50.0) / s) ** 2)
    edge = a * math.exp(-0.5 * (8.0 / s) ** 2)
    by_hand = a * s * math.sqrt(2 * math.pi) * math.erf(8.0 / (s * math.sqrt(2))) - 16.0 * edge
    assert abs(local_energy(energy, np.array([50.0]), 8.0, 4)[0] - by_hand) < 0.01 * by_hand
    # on the flank of a wider mode only the bump's own energy counts
    flank = energy + 5.0 * x
    assert abs(local_energy(flank, np.array([50.0]), 8.0, 4)[0] - by_hand) < 0.01 * by_hand


def test_cumulative_energy_counts_from_botloc_up_to_the_mode():
    x = np.arange(0, 20.25, 0.25)
    energy = np.ones_like(x)
    share = cumulative_energy_at(x, energy, 0.0, 20.0, np.array([20.0, 10.0, 0.0]))
    assert np.allclose(share, [1 / 81, 41 / 81, 1.0])


def test_local_and_cumulative_energy_reproduce_l2as_on_the_shared_granule(gedi_beams):
    """rx_modelocalenergy and rx_iwaveamps of algorithm 2 (zcross smoothing 3.5), from L2A's own modes."""
    local_d, share_d = [], []
    for b in gedi_beams:
        l2a = b["algorithms"][2]
        for i in range(len(b["offsets"]) - 1):
            n = int(l2a["rx_nummodes"][i])
            smoothed = gaussian_smooth(b["samples"][b["offsets"][i]:b["offsets"][i + 1]], 3.5)
            x, values = subbin_grid(smoothed, 4)
            energy = values - b["noise_mean"][i]
            at = l2a["rx_modelocs"][i][:n]
            local_d += list(local_energy(energy, at, 8.0, 4) - l2a["rx_modelocalenergy"][i][:n])
            share_d += list(cumulative_energy_at(x, energy, l2a["toploc"][i], l2a["botloc"][i], at)
                            - l2a["rx_iwaveamps"][i][:n])
    local_d, share_d = np.abs(local_d), np.abs(share_d)
    assert np.median(local_d) < 2 and np.percentile(local_d, 90) < 15  # of local energies in the hundreds, vs 50
    assert np.percentile(share_d, 90) < 2e-4  # 0.02 %, vs thresholds of 1.5 and 2.5 %
