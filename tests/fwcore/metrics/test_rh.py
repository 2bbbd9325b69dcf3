import numpy as np

from fwcore.metrics.rh import energy_positions, relative_heights


def test_a_box_of_energy_spreads_rh_evenly_and_truncates_to_centimetres():
    x = np.arange(0, 101, 0.25)
    energy = np.where((x >= 20) & (x <= 70), 1.0, 0.0)
    positions = energy_positions(x, energy, 20.0, 70.0)
    assert positions[0] == 70.0 and positions[100] == 20.0
    assert abs(positions[50] - 45.0) <= 0.25 and np.all(np.diff(positions) <= 0)
    rh = relative_heights(positions, 70.0, 0.15)
    assert rh[0] == 0.0 and rh[100] == 7.5 and abs(rh[50] - 3.75) <= 0.05  # a sub-bin (0.0375 m) and the truncation
    assert relative_heights(np.array([10.0]), 10.333, 0.15)[0] == 0.04  # 0.04995 truncated, not rounded
