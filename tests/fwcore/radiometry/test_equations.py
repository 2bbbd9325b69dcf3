"""Radiometry: the radar equation, local planes and incidence, the per-echo flags and the calibration on a reference
patch of known reflectance."""

import json
import math

import numpy as np
import pytest

from fwcore.radiometry.equations import (CALIBRATED, RELATIVE, UNAVAILABLE, CalibrationReference, EchoGeometry,
                                         RadiometryConfig, backscatter_coefficient, backscatter_cross_section,
                                         calibration_from_samples, calibration_samples, diffuse_reflectance,
                                         echo_radiometry, incidence_angle, local_plane_normals, metric_beam,
                                         parse_calibration_reference)
from fwcore.radiometry.errors import RadiometryError

DOWN = np.array([0.0, 0.0, -1.0])


def plane_grid(n, slope_x, slope_y):
    """n x n points 1 m apart on z = slope_x x + slope_y y."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    x, y = x.ravel(), y.ravel()
    return np.stack([x, y, slope_x * x + slope_y * y], axis=1)


# ---------------------------------------------------------------- the radar equation

def test_cross_section_is_constant_times_range_to_the_fourth_times_energy():
    assert backscatter_cross_section(np.array([2.0]), np.array([10.0]), 0.5)[0] == pytest.approx(10000.0)
    assert backscatter_cross_section(np.array([3.0]), np.array([2.0]), 1.0)[0] == pytest.approx(48.0)


def test_backscatter_coefficient_is_four_sigma_over_pi_r2_beta2():
    # 4 * 2 / (pi * 100^2 * (1e-3)^2) = 8 / (pi * 0.01) = 800 / pi
    gamma = backscatter_coefficient(np.array([2.0]), np.array([100.0]), 1e-3)
    assert gamma[0] == pytest.approx(800.0 / math.pi, rel=1e-12)


def test_diffuse_reflectance_divides_by_four_cos_incidence_and_nan_incidence_is_normal():
    rho = diffuse_reflectance(np.array([2.0, 2.0, 1.0]), np.array([math.pi / 3, np.nan, 0.0]))
    np.testing.assert_allclose(rho, [1.0, 0.5, 0.25], rtol=1e-12)  # 2/(4*0.5), 2/(4*1), 1/4


def test_a_lambertian_extended_target_gives_its_reflectance_back():
    rho, r, alpha, beta = 0.3, np.array([250.0, 1200.0]), np.array([0.4, 1.1]), 0.3e-3
    sigma = math.pi * rho * r ** 2 * beta ** 2 * np.cos(alpha)
    back = diffuse_reflectance(backscatter_coefficient(sigma, r, beta), alpha)
    np.testing.assert_allclose(back, [0.3, 0.3], rtol=1e-12)


# ---------------------------------------------------------------- local planes and incidence

def test_normals_of_a_tilted_plane_and_incidence_from_a_vertical_beam():
    xyz = plane_grid(15, 0.2, 0.1)
    normals = local_plane_normals(xyz, 10, 5.0, 0.10)
    assert np.isfinite(normals).all()
    expected = np.array([-0.2, -0.1, 1.0]) / math.sqrt(0.04 + 0.01 + 1.0)
    np.testing.assert_allclose(np.abs(normals @ expected), 1.0, rtol=0, atol=1e-9)  # parallel, either sense
    interior = (xyz[:, 0] >= 2) & (xyz[:, 0] <= 12) & (xyz[:, 1] >= 2) & (xyz[:, 1] <= 12)
    incidence = incidence_angle(normals[interior], np.tile(DOWN, (interior.sum(), 1)))
    np.testing.assert_allclose(incidence, math.atan(math.sqrt(0.2 ** 2 + 0.1 ** 2)), rtol=0, atol=1e-6)
    # the beam's sense does not matter
    np.testing.assert_allclose(incidence_angle(normals[interior], np.tile(-DOWN, (interior.sum(), 1))), incidence,
                               rtol=0, atol=1e-12)


def test_normals_survive_large_coordinates():
    xyz = plane_grid(15, 0.2, 0.1) + np.array([500_000.0, 5_300_000.0, 400.0])
    normals = local_plane_normals(xyz, 10, 5.0, 0.10)
    incidence = incidence_angle(normals, np.tile(DOWN, (len(xyz), 1)))
    np.testing.assert_allclose(incidence, math.atan(math.sqrt(0.05)), rtol=0, atol=1e-6)


def test_scattered_points_and_too_few_points_have_no_plane():
    rng = np.random.default_rng(11)
    cloud = rng.uniform(0.0, 10.0, size=(300, 3))
    assert np.isnan(local_plane_normals(cloud, 10, 5.0, 0.10)).all()
    few = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert np.isnan(local_plane_normals(few, 10, 5.0, 0.10)).all()


def test_points_on_a_line_have_no_plane():
    line = np.stack([np.arange(20.0), np.zeros(20), np.zeros(20)], axis=1)
    assert np.isnan(local_plane_normals(line, 10, 5.0, 0.10)).all()


def test_a_point_with_no_neighbours_in_the_radius_has_no_plane():
    xyz = np.vstack([plane_grid(8, 0.0, 0.0), [[100.0, 100.0, 0.0]]])
    normals = local_plane_normals(xyz, 10, 5.0, 0.10)
    assert np.isnan(normals[-1]).all()
    assert np.isfinite(normals[:-1]).all()


# ---------------------------------------------------------------- per-echo radiometry

def flat_geometry(n=10, range_m=500.0, energy=2.0):
    xyz = plane_grid(n, 0.0, 0.0)
    m = len(xyz)
    return EchoGeometry(xyz=xyz, beam=np.tile(DOWN, (m, 1)), range_m=np.full(m, range_m), energy=np.full(m, energy),
                        kept=np.ones(m, dtype=bool))


def test_a_given_constant_makes_echoes_calibrated():
    out = echo_radiometry(flat_geometry(range_m=100.0, energy=2.0), RadiometryConfig(calibration_constant=3e-8), 0.5)
    assert (out["radiometry"] == CALIBRATED).all()
    np.testing.assert_allclose(out["backscatter_cross_section_m2"], 3e-8 * 100.0 ** 4 * 2.0, rtol=1e-12)  # 6.0
    # gamma = 4 * 6 / (pi * 1e4 * 0.25e-6) = 9600 / pi; rho = gamma / 4 at normal incidence
    np.testing.assert_allclose(out["backscatter_coefficient"], 9600.0 / math.pi, rtol=1e-12)
    np.testing.assert_allclose(out["reflectance"], 2400.0 / math.pi, rtol=1e-9)
    np.testing.assert_allclose(out["incidence_deg"], 0.0, rtol=0, atol=1e-6)


def test_without_a_constant_echoes_are_relative_with_c_equal_to_one_in_km_and_ns():
    # the RIEGL sample's median echo: 3.8e5 DN x ps at 500 m (with C = 1 in m and ps its reflectance was 1.2e17)
    out = echo_radiometry(flat_geometry(range_m=500.0, energy=3.8e5), RadiometryConfig(), 0.5)
    assert (out["radiometry"] == RELATIVE).all() and (out["reflectance_basis"] == "incidence").all()
    np.testing.assert_allclose(out["backscatter_cross_section_m2"], 0.5 ** 4 * 380.0, rtol=1e-12)  # 23.75
    # gamma = 4 x 23.75 / (pi 500^2 (0.5e-3)^2) = 95 / (0.0625 pi); rho = gamma / 4 at normal incidence
    np.testing.assert_allclose(out["backscatter_coefficient"], 95.0 / (0.0625 * math.pi), rtol=1e-9)
    np.testing.assert_allclose(out["reflectance"], 380.0 / math.pi, rtol=1e-9)  # 121
    np.testing.assert_array_equal(out["range_m"], 500.0)


def test_an_echo_without_range_is_unavailable_and_nan():
    geometry = flat_geometry()
    geometry.range_m[3] = np.nan
    out = echo_radiometry(geometry, RadiometryConfig(calibration_constant=1e-9), 0.5)
    assert out["radiometry"][3] == UNAVAILABLE
    assert (np.delete(out["radiometry"], 3) == CALIBRATED).all()
    for column in ("range_m", "incidence_deg", "backscatter_cross_section_m2", "backscatter_coefficient",
                   "reflectance"):
        assert np.isnan(out[column][3]), column
    assert np.isfinite(np.delete(out["reflectance"], 3)).all()


def test_without_beam_divergence_only_the_cross_section_is_given():
    out = echo_radiometry(flat_geometry(range_m=10.0, energy=3.0), RadiometryConfig(), None)
    np.testing.assert_allclose(out["backscatter_cross_section_m2"], 3e-11, rtol=1e-12)  # 1e-15 x 1e4 x 3
    assert np.isnan(out["backscatter_coefficient"]).all() and np.isnan(out["reflectance"]).all()
    assert (out["radiometry"] == RELATIVE).all() and (out["reflectance_basis"] == "null: no beam divergence").all()


def test_incidence_is_only_for_kept_echoes():
    geometry = flat_geometry(range_m=10.0, energy=1.0)
    geometry.kept[12] = False
    out = echo_radiometry(geometry, RadiometryConfig(), 1.0)
    assert np.isnan(out["incidence_deg"][12])
    assert np.isfinite(np.delete(out["incidence_deg"], 12)).all()
    # its reflectance is the apparent one (normal incidence): gamma / 4 = 4 * 1e-11 / (pi * 100 * 1e-6) / 4
    assert out["reflectance"][12] == pytest.approx(1e-7 / math.pi, rel=1e-12)
    assert out["reflectance_basis"][12] == "apparent: no plane" and out["reflectance_basis"][0] == "incidence"


def test_incidence_in_degrees_on_a_tilted_plane():
    xyz = plane_grid(15, 0.2, 0.1)
    m = len(xyz)
    geometry = EchoGeometry(xyz, np.tile(DOWN, (m, 1)), np.full(m, 300.0), np.ones(m), np.ones(m, dtype=bool))
    out = echo_radiometry(geometry, RadiometryConfig(), 0.5)
    np.testing.assert_allclose(out["incidence_deg"], math.degrees(math.atan(math.sqrt(0.05))), rtol=0, atol=1e-5)


# ---------------------------------------------------------------- calibration on a reference patch

K, RHO, BETA_MRAD, RANGE_M = 4.0e6, 0.3, 0.5, 500.0
PATCH = CalibrationReference((0.0, 0.0, 14.5, 19.5), RHO)


def patch_scene(noise=None):
    """A 25 x 20 grid on z = 0, lit straight down from 500 m; x < 14.5 is the patch. Energies follow a Lambertian
    target: E = K rho cos(a) / R^2. Every 7th echo is not a single return."""
    x, y = np.meshgrid(np.arange(25.0), np.arange(20.0), indexing="ij")
    xyz = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    m = len(xyz)
    energy = np.full(m, K * RHO * 1.0 / RANGE_M ** 2)
    if noise is not None:
        energy = energy * (1.0 + noise * np.random.default_rng(5).standard_normal(m))
    single = np.arange(m) % 7 != 0
    geometry = EchoGeometry(xyz, np.tile(DOWN, (m, 1)), np.full(m, RANGE_M), energy, np.ones(m, dtype=bool))
    columns = echo_radiometry(geometry, RadiometryConfig(), BETA_MRAD)
    return columns, xyz, single


def test_calibration_finds_the_constant_that_makes_sigma_lambertian():
    columns, xyz, single = patch_scene()
    calibration = calibration_from_samples(calibration_samples(columns, xyz, single, PATCH, BETA_MRAD))
    expected = math.pi * (BETA_MRAD * 1e-3) ** 2 / K  # C with C R^4 E = pi rho R^2 beta^2 cos a
    assert calibration.constant == pytest.approx(expected, rel=1e-9)
    inside_single = (xyz[:, 0] <= 14.5) & single
    assert inside_single.sum() < 300  # 15 x 20 inside, some of them not single
    assert calibration.n == inside_single.sum()
    assert calibration.spread == pytest.approx(0.0, abs=1e-9)
    # with that constant, the patch reads back its reflectance
    m = len(xyz)
    calibrated = echo_radiometry(EchoGeometry(xyz, np.tile(DOWN, (m, 1)), np.full(m, RANGE_M),
                                              np.full(m, K * RHO / RANGE_M ** 2), np.ones(m, dtype=bool)),
                                 RadiometryConfig(calibration_constant=calibration.constant), BETA_MRAD)
    np.testing.assert_allclose(calibrated["reflectance"], RHO, rtol=1e-8)


def test_calibration_with_5_percent_noise_keeps_the_median_and_reports_the_spread():
    columns, xyz, single = patch_scene(noise=0.05)
    calibration = calibration_from_samples(calibration_samples(columns, xyz, single, PATCH, BETA_MRAD))
    expected = math.pi * (BETA_MRAD * 1e-3) ** 2 / K
    assert abs(calibration.constant / expected - 1.0) < 0.02
    assert 0.02 < calibration.spread < 0.08
    assert calibration.spread == pytest.approx(0.05, abs=0.01)  # 1.4826 MAD / median: the noise's 5%
    assert calibration.p10 < calibration.constant < calibration.p90


def test_calibration_without_samples_is_refused():
    with pytest.raises(RadiometryError, match="no single return"):
        calibration_from_samples(np.array([]))
    with pytest.raises(RadiometryError):
        calibration_from_samples(np.array([np.nan, -1.0, 0.0]))


# ---------------------------------------------------------------- options

def test_calibration_reference_parses_bbox_and_reflectance():
    reference = parse_calibration_reference("0,0,10,10=0.25")
    assert reference.bbox == (0.0, 0.0, 10.0, 10.0)
    assert reference.reflectance == 0.25
    assert parse_calibration_reference("-5.5,2,3,4.5=1").bbox == (-5.5, 2.0, 3.0, 4.5)


@pytest.mark.parametrize("text", ["0,0,10,10=0", "0,0,10,10=-1", "0,0,10,10=1.5"])
def test_calibration_reference_outside_zero_one_is_refused(text):
    with pytest.raises(RadiometryError, match=r"\(0, 1\]"):
        parse_calibration_reference(text)


@pytest.mark.parametrize("text", ["=-1", "=1.5", "0,0,10=0.2", "0,0,10,10,12=0.2", "a,0,10,10=0.2", "0,0,10,10=x",
                                  "10,0,0,10=0.2", "0,0,10,10,=0.2", "0,5,10,5=0.2", "0,0,inf,10=0.2"])
def test_malformed_calibration_references_are_refused(text):
    with pytest.raises(RadiometryError):
        parse_calibration_reference(text)


def test_empty_patch_is_refused_as_empty():
    with pytest.raises(RadiometryError, match="empty"):
        parse_calibration_reference("10,0,0,10=0.2")


def test_calibration_reference_from_a_json_file(tmp_path):
    path = tmp_path / "reference.json"
    path.write_text(json.dumps({"bbox": [1, 2, 30, 40], "reflectance": 0.3}))
    reference = parse_calibration_reference(str(path))
    assert reference.bbox == (1.0, 2.0, 30.0, 40.0) and reference.reflectance == 0.3
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"bbox": [1, 2, 30, 40]}))
    with pytest.raises(RadiometryError, match="bad.json.*not a calibration reference"):
        parse_calibration_reference(str(bad))


def test_reference_contains_its_bbox_edges():
    inside = PATCH.contains(np.array([0.0, 14.5, 14.6, 5.0, -0.1]), np.array([19.5, 0.0, 5.0, 19.6, 5.0]))
    np.testing.assert_array_equal(inside, [True, True, False, False, False])


def test_config_refuses_bad_constant_and_divergence():
    for bad in (-1.0, 0.0, math.nan, math.inf):
        with pytest.raises(RadiometryError, match="calibration-constant"):
            RadiometryConfig(calibration_constant=bad)
    for bad in (0.0, -0.3, math.nan):
        with pytest.raises(RadiometryError, match="beam-divergence-mrad"):
            RadiometryConfig(beam_divergence_mrad=bad)
    with pytest.raises(RadiometryError, match="local plane"):
        RadiometryConfig(plane_neighbours=2)


def test_config_round_trips_through_a_dict():
    config = RadiometryConfig(calibration_reference=CalibrationReference((0.0, 0.0, 1.0, 1.0), 0.2),
                              calibration_constant=2e-9, beam_divergence_mrad=0.3)
    again = RadiometryConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert again == config
    assert again.calibrated and again.constant() == 2e-9
    assert not RadiometryConfig().calibrated and RadiometryConfig().constant() == 1e-15  # 1 in km and ns


# ---------------------------------------------------------------- metric beams

def test_metric_beam_is_light_two_way_per_ps_in_metres():
    def along_x(step):
        return np.array([[step, 0.0, 0.0]])

    assert metric_beam(along_x(1.499e-4))[0]  # 0.1499 m per 1000 ps
    assert metric_beam(np.array([[0.0, 0.6 * 1.499e-4, -0.8 * 1.499e-4]]))[0]  # any direction
    assert not metric_beam(along_x(1e-9))[0]  # degrees
    assert not metric_beam(along_x(4.9e-4))[0]  # feet
    np.testing.assert_array_equal(metric_beam(np.array([[1.499e-4, 0, 0], [1e-9, 0, 0]])), [True, False])


def wall_geometry(n=10, range_m=500.0, energy=3.8e5):
    """Echoes on a vertical plane x = 0 (a wall, or echoes of a few pulses along their beams) seen from above."""
    yy, zz = np.meshgrid(np.arange(n) * 0.5, np.arange(n) * 0.5)
    xyz = np.stack([np.zeros(n * n), yy.ravel(), zz.ravel()], axis=1)
    m = len(xyz)
    return EchoGeometry(xyz=xyz, beam=np.tile(DOWN, (m, 1)), range_m=np.full(m, range_m),
                        energy=np.full(m, energy), kept=np.ones(m, dtype=bool))


def test_a_plane_along_the_beam_gives_no_incidence_and_the_apparent_reflectance():
    # the plane holds the beam: incidence 90 deg, 1 / cos alpha 1e16 (the simulated flight's 1e15 reflectances)
    calibrated = RadiometryConfig(calibration_constant=3.7e-17)
    out = echo_radiometry(wall_geometry(), calibrated, 0.5)
    assert np.isnan(out["incidence_deg"]).all()
    assert (out["reflectance_basis"] == "apparent: untrusted plane").all()
    # apparent: C R^4 E x 4 / (pi R^2 beta^2) / 4 = 3.7e-17 x 500^2 x 3.8e5 / (pi x 0.25e-6) = 0.4477
    np.testing.assert_allclose(out["reflectance"], 3.7e-17 * 500.0 ** 2 * 3.8e5 / (math.pi * 0.25e-6), rtol=1e-9)
    assert (out["radiometry"] == CALIBRATED).all()


def test_incidence_is_trusted_up_to_80_degrees():
    from fwcore.radiometry.equations import trusted_incidence

    kept = trusted_incidence(np.radians([0.0, 45.0, 79.9, 80.1, 89.99, np.nan]))
    np.testing.assert_allclose(np.degrees(kept), [0.0, 45.0, 79.9, np.nan, np.nan, np.nan])


def test_an_echo_without_energy_has_null_radiometry_and_says_why():
    geometry = flat_geometry(range_m=500.0, energy=3.8e5)
    geometry.energy[[4, 5]] = [0.0, np.inf]
    out = echo_radiometry(geometry, RadiometryConfig(calibration_constant=3.7e-17), 0.5)
    for column in ("backscatter_cross_section_m2", "backscatter_coefficient", "reflectance"):
        assert np.isnan(out[column][[4, 5]]).all() and np.isfinite(np.delete(out[column], [4, 5])).all()
    assert list(out["reflectance_basis"][[3, 4, 5]]) == ["incidence", "null: no energy", "null: no energy"]
    assert list(out["radiometry"][[3, 4]]) == [CALIBRATED, "unavailable"]
    np.testing.assert_array_equal(out["range_m"], 500.0)


def test_a_plane_whose_tilt_is_uncertain_is_not_trusted_where_it_moves_cos_alpha_by_more_than_5_percent():
    from fwcore.radiometry.equations import trusted_incidence

    # tan(45 deg) x 0.04 = 4%: trusted; x 0.06 = 6%: not; at 10 deg tan = 0.176: 0.06 rad moves cos by 1%
    kept = trusted_incidence(np.radians([45.0, 45.0, 10.0]), np.array([0.04, 0.06, 0.06]))
    np.testing.assert_allclose(np.degrees(kept), [45.0, np.nan, 10.0])


def test_the_tilt_uncertainty_of_a_fitted_plane():
    from fwcore.radiometry.equations import local_planes

    # 9 points: a 3 x 3 grid 1 m apart, z = +-0.01 m in a checkerboard: misfit variance ~1e-4 about the plane,
    # variance 2/3 m^2 along either axis: tilt sqrt(1e-4 x 80/81 / (9 x 2/3)) ~ 0.004 rad
    x, y = np.meshgrid(np.arange(3.0), np.arange(3.0))
    z = 0.01 * np.where((x + y) % 2 == 0, 1.0, -1.0)
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    normals, tilt = local_planes(xyz, 10, 5.0, 0.10)
    assert np.isfinite(normals).all()
    centred = xyz - xyz.mean(axis=0)
    values = np.linalg.eigvalsh(centred.T @ centred / 9)
    np.testing.assert_allclose(tilt, np.sqrt(values[0] / (9 * values[1])), rtol=1e-9)
    assert 0.003 < tilt[0] < 0.005
