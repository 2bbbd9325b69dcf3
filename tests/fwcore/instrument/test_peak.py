"""A peak's vertex, half-height width and crossings, main lobe, and the one strong isolated echo detector."""

import numpy as np
import pytest

from fwcore.instrument.peak import (half_height_crossings, half_height_width, isolated_lobe, local_maxima,
                                    parabola_height, parabola_vertex, width_above_minimum)


def test_parabola_vertex_and_height():
    v = np.array([0.0, 2.0, 1.0])
    shift = parabola_vertex(v, 1)
    assert shift == pytest.approx(1.0 / 6.0)  # 0.5 (0 - 1) / (0 - 4 + 1)
    assert parabola_height(v, 1, shift) == pytest.approx(2.0 + 1.0 / 24.0)
    assert parabola_vertex(np.array([0.0, 1.0, 0.0]), 1) == 0.0
    assert parabola_vertex(v, 0) == 0.0  # at an edge


def test_half_height_crossings_walk_out_to_the_first_sample_at_half():
    triangle = np.array([0.0, 1.0, 2.0, 1.0, 0.0])
    every = np.ones(5, dtype=bool)
    assert half_height_crossings(triangle, every, 2, 2.0) == (1.0, 3.0)
    rising = np.array([0.0, 2.0, 4.0, 3.0])
    assert half_height_crossings(rising, np.ones(4, dtype=bool), 2, 4.0) == (1.0, -1.0)  # the right never falls
    gap = np.array([True, False, True, True, True])
    assert half_height_crossings(triangle, gap, 2, 2.0)[0] == -1.0  # an invalid sample stops the walk


def test_the_two_widths_differ_where_a_sample_sits_at_half():
    t = np.arange(7.0)
    y = np.array([0.0, 0.0, 10.0, 10.0, 20.0, 0.0, 0.0])
    # a response's: the run above half (strictly) ends at the sample at half
    assert half_height_width(t, y) == pytest.approx(4.5 - 3.0)
    # a pulse on its background: samples at half height belong to the pulse
    assert width_above_minimum(y) == pytest.approx(4.5 - 2.0)
    assert width_above_minimum(np.array([10.0, 10.0, 20.0, 30.0, 20.0, 10.0, 10.0])) == pytest.approx(2.0)


def test_isolated_lobe_takes_its_thresholds_from_the_caller():
    t = np.arange(80.0)
    echo = 100.0 * np.exp(-0.5 * ((t - 30.0) / 3.0) ** 2)
    second = echo + 12.0 * np.exp(-0.5 * ((t - 60.0) / 3.0) ** 2)
    lobe = isolated_lobe(echo, 30, 20.0, 0.1)
    assert lobe == (24, 36)  # above 10% of the peak: within 2.15 sigma
    assert isolated_lobe(second, 30, 20.0, 0.15) == lobe  # a return at 12% is the tail's business at 15%
    assert isolated_lobe(second, 30, 20.0, 0.1) is None  # ... and another return at 10%
    assert isolated_lobe(echo, 30, 101.0, 0.1) is None  # too weak
    assert isolated_lobe(echo[25:], 5, 20.0, 0.1) is None  # cut by the record's start


def test_local_maxima():
    assert local_maxima(np.array([0.0, 1.0, 0.0, 2.0, 0.0])) == 2
    assert local_maxima(np.array([0.0, 1.0, 1.0, 0.0])) == 1  # a flat top counts once
    assert local_maxima(np.array([0.0, 1.0])) == 0
