import numpy as np

from fwcore.terrain.canopy_height import METRES_PER_PS, echo_tops


def test_a_hard_target_keeps_its_height_and_a_deep_canopy_leads_by_half_its_depth():
    system = 4000.0  # ps
    depth_m = 2.0
    depth_ps = depth_m / METRES_PER_PS
    widened = np.hypot(system, depth_ps)  # a Gaussian pulse through a Gaussian-like depth: widths add in quadrature
    tops = echo_tops(np.array([10.0, 10.0, 10.0, 10.0]), np.array([system, 3000.0, widened, np.nan]), system)
    assert tops[0] == 10.0 and tops[1] == 10.0 and tops[3] == 10.0
    assert np.isclose(tops[2], 10.0 + depth_m / 2)
