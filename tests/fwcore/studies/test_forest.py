"""The forest scene: seeded, coherent, and each pulse's echoes as Beer's law and the geometry say."""

import numpy as np

from fwcore.studies.forest import (G_PROJECTION, GROUND_REFLECTANCE, VEGETATION_REFLECTANCE, ForestConfig,
                                   draw_forest, flight_bounds, forest_echoes, forest_flight_scene,
                                   simulate_forest_chunks, terrain)
from fwcore.studies.simulate import SensorConfig

SCENE = forest_flight_scene()
SENSOR = SensorConfig(samples_per_packet=360)


def test_the_same_seed_draws_the_same_forest_and_another_another():
    bounds = flight_bounds(100_000, SCENE)  # a second of flight: room for the buildings
    a, b, c = (draw_forest(bounds, ForestConfig(), s) for s in (5, 5, 6))
    np.testing.assert_array_equal(a.trees, b.trees)
    assert a.trees.shape != c.trees.shape or not np.array_equal(a.trees, c.trees)
    assert len(a.buildings) == ForestConfig().buildings
    # no trunk in the clearing
    assert (np.hypot(a.trees[:, 0] - a.clearing[0], a.trees[:, 1] - a.clearing[1]) > 16).all()


def test_the_terrain_has_its_break_of_slope_and_its_ditch():
    f = ForestConfig()
    x = np.array([30.0, 30.0])
    slope_before = (terrain(x, np.array([20.0, 21.0]), f)[1] - terrain(x, np.array([20.0, 21.0]), f)[0])
    slope_after = (terrain(x, np.array([60.0, 61.0]), f)[1] - terrain(x, np.array([60.0, 61.0]), f)[0])
    assert abs(slope_after - slope_before - f.break_slope) < 0.05
    axis = terrain(np.array([0.0]), np.array([0.0]), f)[0]
    bank = terrain(np.array([6.0]), np.array([0.0]), f)[0] - 6 * f.slope[0]
    assert bank - axis > 0.9 * f.ditch_depth_m


def test_echoes_conserve_the_pulse_and_the_ground_lies_on_the_terrain():
    drawn = draw_forest(flight_bounds(5000, SCENE), ForestConfig(), 3)
    flight = next(simulate_forest_chunks(5000, SENSOR, SCENE, ForestConfig(), 3, drawn=drawn))
    t = flight.truth
    ground = t["surface"] == "ground"
    np.testing.assert_allclose(t["z"][ground], terrain(t["x"][ground], t["y"][ground], ForestConfig()), atol=0.01)
    # energies: reflectance x the share of the pulse; a pulse's shares (vegetation's and the ground's) sum to
    # at most 1 (layers weaker than MIN_LAYER_SHARE are dropped), and nearly 1
    gps, angle, sensor_xyz, beam, count, ranges, amplitude, width, alpha, kind, rho, inc = forest_echoes(
        0, 5000, SCENE, SENSOR, drawn, np.random.default_rng(0))
    has = np.arange(ranges.shape[1])[None, :] < count[:, None]
    assert set(np.unique(rho[has])) <= {VEGETATION_REFLECTANCE, GROUND_REFLECTANCE, 0.2}
    open_ground = count == 1
    assert open_ground.any() and (count > 2).any()


def test_the_ground_keeps_what_the_leaves_let_through_by_beer_s_law():
    """Each echo's share of the pulse from its energy (E = K rho cos f / R^2); the ground's share is
    exp(-G x the leaf area met along the beam / cos(theta)), traced again here; the shares sum to nearly 1."""
    from fwcore.studies.forest import STEP_M, TRACE_TOP_M
    from fwcore.studies.forest_trace import trace_leaf_area
    from fwcore.studies.simulate import echo_area

    drawn = draw_forest(flight_bounds(5000, SCENE), ForestConfig(), 4)
    gps, angle, sensor_xyz, beam, count, ranges, amplitude, width, alpha, kind, rho, inc = forest_echoes(
        0, 5000, SCENE, SENSOR, drawn, np.random.default_rng(0))
    k = SCENE.radar_amplitude * echo_area(np.full(1, SENSOR.pulse_fwhm_ps), np.full(1, np.sqrt(2.0)))[0] * 500.0 ** 2
    has = np.arange(ranges.shape[1])[None, :] < count[:, None]
    energy = np.where(has, amplitude * echo_area(SENSOR.pulse_fwhm_ps * width, np.where(has, alpha, 1.4)), 0.0)
    cos = np.where(kind == 1, 1.0, np.cos(np.radians(np.nan_to_num(inc))))
    share = np.where(has, energy * ranges ** 2 / (k * np.nan_to_num(rho, nan=1.0) * cos), 0.0)
    last = count - 1
    rows = np.arange(count.size)
    on_ground = kind[rows, last] == 0
    hit = sensor_xyz + beam * ranges[rows, last][:, None]
    steps = int(round(TRACE_TOP_M / STEP_M))
    lad, _ = trace_leaf_area(hit[on_ground], beam[on_ground], STEP_M, steps, drawn.index, drawn.buildings)
    expected = np.exp(-G_PROJECTION * lad.sum(axis=1) * STEP_M / -beam[on_ground, 2])
    np.testing.assert_allclose(share[rows, last][on_ground], expected, rtol=1e-6, atol=1e-9)
    total = share.sum(axis=1)[on_ground]
    assert (total <= 1 + 1e-9).all() and np.median(total) > 0.97
    assert (expected < 0.5).sum() > 100  # pulses under dense crowns are among them
