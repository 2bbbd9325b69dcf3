"""A flight line's radiometry: where a file's ranges come from (the bundled samples), and the range and incidence of
every echo of a range on a hand-computed geometry."""

import dataclasses

import numpy as np
import pytest

from fwcore.engine.records import WAVEFORM_RESULT, BatchDecomposition
from fwcore.io.las import read_las_pulses
from fwcore.io.records import PointRange
from fwcore.pulses import echo_positions
from fwcore.radiometry.equations import RadiometryConfig
from fwcore.radiometry.flight import FileRadiometry, file_radiometry, range_radiometry, single_returns

HALF_C_M_PER_PS = 299_792_458.0 / 2 * 1e-12  # a return's range per picosecond of its time


def test_where_the_samples_ranges_come_from(leica_dir, pulsewaves_dir):
    riegl = file_radiometry(str(pulsewaves_dir / "riegl_example3.pls"), False, RadiometryConfig())
    assert (riegl.range_source, riegl.beam_divergence_mrad, riegl.beam_divergence_source, riegl.time_system) == (
        "scanner position in the file", 0.5, "file", "adjusted")
    leica = file_radiometry(str(leica_dir / "leica_a.las"), False, RadiometryConfig(beam_divergence_mrad=0.25))
    assert leica.range_source == "" and leica.why_no_range == (
        "leica_a.las: a LAS file does not record where its scanner was: give --trajectory")
    assert (leica.beam_divergence_mrad, leica.beam_divergence_source) == (0.25, "option")
    assert leica.to_dict() == {"range_source": None, "why_no_range": leica.why_no_range, "beam_divergence_mrad": 0.25,
                               "beam_divergence_source": "option"}
    with_trajectory = file_radiometry(str(leica_dir / "leica_a.las"), True, RadiometryConfig(trajectory="sbet.out"))
    assert with_trajectory.range_source == "trajectory sbet.out" and with_trajectory.time_system == "adjusted"


def tilted_flight(leica, range_m: float, tilt_deg: float):
    """49 pulses on flat ground z = 0 (a 7 x 7 grid, 1 m apart), each with one echo at sample 30, its beam tilted
    `tilt_deg` from nadir in the x-z plane, the scanner range_m back along it: (pulses, result)."""
    n = 49
    beam = np.array([np.sin(np.radians(tilt_deg)), 0.0, -np.cos(np.radians(tilt_deg))])
    ground = np.column_stack([np.repeat(np.arange(7.0), 7), np.tile(np.arange(7.0), 7), np.zeros(n)])
    echo_ps = 30 * 1000.0
    pulses = dataclasses.replace(
        leica, pulse_id=np.arange(n), anchor=ground, anchor_location_ps=np.full(n, echo_ps),  # the echo is the anchor
        direction=np.tile(-beam * HALF_C_M_PER_PS, (n, 1)), sample_spacing_ps=np.full(n, 1000.0),
        digitizer_gain=np.ones(n), gps_time=np.arange(n, dtype=float),
        sensor_location_ps=np.full(n, echo_ps - range_m / HALF_C_M_PER_PS))
    per_waveform = np.zeros(n, WAVEFORM_RESULT)
    ones = np.ones(n)
    result = BatchDecomposition(per_waveform, np.arange(n + 1), amplitude=100 * ones, position=30 * ones,
                                sigma=2 * ones, alpha=np.sqrt(2) * ones, fwhm=4.71 * ones, energy=500 * ones,
                                reject=np.zeros(n, np.int8))
    return pulses, result, ground


@pytest.mark.parametrize("range_m, tilt_deg", [(600.0, 30.0), (1234.5, 12.0)])
def test_range_and_incidence_of_a_hand_computed_geometry(leica_dir, range_m, tilt_deg):
    leica = read_las_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 60, max_pulses=49))
    assert len(leica) == 49  # its per-row fields, those the geometry does not set, fit the 49 pulses
    pulses, result, ground = tilted_flight(leica, range_m, tilt_deg)
    xyz = echo_positions(pulses, result)
    np.testing.assert_allclose(xyz, ground, atol=1e-9)
    file = FileRadiometry("hand", "scanner position in the file", "", 0.5, "option", "week", None)
    columns = range_radiometry(pulses, result, xyz, 0.0, file, RadiometryConfig())
    np.testing.assert_allclose(columns["range_m"], range_m, rtol=1e-12)
    # the ground's normal is +z: the beam meets it at its tilt from nadir
    np.testing.assert_allclose(columns["incidence_deg"], tilt_deg, atol=1e-6)
    assert single_returns(result).all()
    without = dataclasses.replace(file, range_source="", why_no_range="no scanner")
    assert np.isnan(range_radiometry(pulses, result, xyz, 0.0, without, RadiometryConfig())["range_m"]).all()
