"""Geolocation along the beam: X = X0 + (L0 - t) x_t, on hand-computed positions."""

import numpy as np

from fwcore.io.geolocate import geolocate


def test_an_echo_is_placed_along_its_pulse_s_direction():
    anchor = np.array([[100.0, 200.0, 50.0], [0.0, 0.0, 0.0]])
    direction = np.array([[0.0, 0.0, 1.5e-4], [1e-4, -2e-4, 3e-4]])  # metres per picosecond
    xyz = geolocate(anchor, np.array([10_000.0, 0.0]), direction, np.array([30_000.0, -1000.0]))
    # the first echo 20 000 ps after the anchor: 3 m below it; the second 1000 ps before the packet's first sample
    np.testing.assert_allclose(xyz, [[100.0, 200.0, 47.0], [0.1, -0.2, 0.3]], rtol=1e-15)


def test_an_echo_at_the_anchor_s_time_is_the_anchor():
    anchor = np.array([[1.0, 2.0, 3.0]])
    assert geolocate(anchor, [500.0], np.array([[7.0, 8.0, 9.0]]), [500.0]).tolist() == anchor.tolist()
