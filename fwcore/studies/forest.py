"""A forest to measure against: terrain, trees, a clearing and buildings, flown by the simulator's sensor.

The scene is spatially coherent and seeded: terrain with two slopes, a break of slope and a ditch; trees as
ellipsoidal crowns (position, height, crown radius and depth, leaf area density rising towards the top and a
denser sunlit shell); a round clearing; a few flat-roofed buildings. Each pulse's beam is traced through it
(fwcore.studies.forest_trace): the leaf area it crosses intercepts its energy by Beer's law,
dE = T (1 - exp(-G LAD ds / cos theta)), G = 0.5 (spherical leaves), T what is left; the intercepted energy is
gathered into at most MAX_ECHOES - 1 vegetation echoes (1.5 m layers, the strongest kept), then the ground
takes what is left (or a roof stops the beam). Energies follow the radar equation's proportions
(reflectance x share of the footprint), so the waveform's ground and canopy energies give the gap
probability as GEDI L2B reads it, with rho_v / rho_g = VEGETATION_REFLECTANCE / GROUND_REFLECTANCE.

The truth is per echo (the flight's truth table, `surface` ground, vegetation or roof) and per 1 m cell
(forest_truth): terrain, canopy height (0 where open), crown cover (vertical projection of the crowns) and
plant area index (the leaf area density integrated over the vertical).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterator

import numpy as np

from fwcore.studies.forest_trace import TreeIndex, trace_leaf_area
from fwcore.studies.simulate import (CHUNK_PULSES, MAX_ECHOES, SceneConfig, SensorConfig, SimulatedFlight,
                                     _chunk_rng, chunk_of_echoes, echo_area, scan_geometry, sensor_position)

G_PROJECTION = 0.5  # leaf projection function of a spherical leaf angle distribution
VEGETATION_REFLECTANCE = 0.45
GROUND_REFLECTANCE = 0.30
ROOF_REFLECTANCE = 0.20
STEP_M = 0.25  # the trace's height step
LAYER_M = 1.5  # vegetation echoes gather the energy of layers this thick (resolvable at a 4 ns pulse)
MIN_LAYER_SHARE = 0.015  # a layer intercepting less of the pulse is no echo
TRACE_TOP_M = 40.0  # above the ground hit: over the tallest crown on any slope of the scene
RANGE_SIGMA_M = 0.255  # the 4 ns pulse's sigma in range: a layer's spread broadens its echo by it


@dataclasses.dataclass(frozen=True)
class ForestConfig:
    """The forest's trees, clearing, buildings and terrain (metres; positions relative to the flight's
    start, y across track)."""

    trees_per_ha: float = 260.0
    tree_height_m: tuple[float, float] = (8.0, 28.0)
    crown_depth_ratio: tuple[float, float] = (0.35, 0.6)  # crown depth / tree height
    crown_radius_ratio: tuple[float, float] = (0.12, 0.22)  # crown radius / tree height
    leaf_density: tuple[float, float] = (0.05, 0.15)  # m2/m3 at the crown base ...
    top_density_factor: float = 2.0  # ... this many times more at the crown top
    shell_density: tuple[float, float] = (2.0, 4.0)  # m2/m3 in the outer shell of the crown ...
    shell_fraction: float = 0.06  # ... this fraction of the crown's normalised radius
    clearing_radius_m: float = 16.0
    buildings: int = 3
    building_size_m: tuple[float, float] = (8.0, 16.0)
    building_height_m: tuple[float, float] = (5.0, 10.0)
    slope: tuple[float, float] = (0.06, 0.03)  # terrain gradient dz/dx, dz/dy
    break_y_m: float = 40.0  # the slope across track steepens by break_slope past this y
    break_slope: float = 0.18
    ditch_x_m: float = 0.0  # a ditch across track through this x (tilted by ditch_tilt) ...
    ditch_tilt: float = 0.15
    ditch_depth_m: float = 1.2  # ... this deep, Gaussian of this half width
    ditch_width_m: float = 1.5


# the flight of a forest: a narrower swath than the default's, denser, with packets long enough for tall trees
FOREST_SCENE = SceneConfig(max_scan_angle_deg=12.0, pulses_per_line=250)
FOREST_SAMPLES = 360


def terrain(x: np.ndarray, y: np.ndarray, forest: ForestConfig) -> np.ndarray:
    """The terrain's z, metres: two slopes, a break of slope across track, a ditch, a gentle roll."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    z = 120.0 + forest.slope[0] * x + forest.slope[1] * y + 0.8 * np.sin(x / 17.0) * np.cos(y / 23.0)
    z = z + forest.break_slope * np.maximum(y - forest.break_y_m, 0.0)
    d = x - forest.ditch_x_m - forest.ditch_tilt * y  # horizontal offset from the ditch's axis (near enough)
    return z - forest.ditch_depth_m * np.exp(-0.5 * (d / forest.ditch_width_m) ** 2)


@dataclasses.dataclass(frozen=True)
class Forest:
    """One drawn forest: trees (x, y, crown centre z, half depth, radius, base and top leaf density, shell
    density) and buildings (xmin, ymin, xmax, ymax, roof z), over `bounds` (xmin, ymin, xmax, ymax)."""

    config: ForestConfig
    bounds: tuple[float, float, float, float]
    trees: np.ndarray  # (n, 8)
    buildings: np.ndarray  # (k, 5)
    clearing: tuple[float, float]
    index: TreeIndex

    def terrain(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return terrain(x, y, self.config)


def flight_bounds(n_pulses: int, scene: SceneConfig, margin: float = 20.0) -> tuple[float, float, float, float]:
    """The ground the flight can see, with a margin."""
    end = sensor_position(np.array([scene.start_gps_time + n_pulses / scene.pulse_rate_hz]), scene)[0, 0]
    half = (scene.altitude_m + 60.0) * math.tan(math.radians(scene.max_scan_angle_deg))
    return (-margin, -half - margin, float(end) + margin, half + margin)


def draw_forest(bounds: tuple[float, float, float, float], forest: ForestConfig, seed: int) -> Forest:
    """Trees, buildings and a clearing over `bounds`, the same for the same seed."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1 << 20,)))  # apart from the chunks'
    xmin, ymin, xmax, ymax = bounds
    cx, cy = xmin + (xmax - xmin) * rng.uniform(0.3, 0.7), ymin + (ymax - ymin) * rng.uniform(0.2, 0.45)
    buildings = []
    for _ in range(1000 * forest.buildings):  # a small scene may hold fewer: give up rather than loop
        if len(buildings) == forest.buildings or xmax - xmin < 60 or ymax - ymin < 60:
            break
        w, h = rng.uniform(*forest.building_size_m, 2)
        bx, by = rng.uniform(xmin + 20, max(xmax - 20 - w, xmin + 21)), rng.uniform(ymin + 20, ymax - 20 - h)
        box = (bx, by, bx + w, by + h)
        if any(not (box[2] + 6 < b[0] or b[2] + 6 < box[0] or box[3] + 6 < b[1] or b[3] + 6 < box[1])
               for b in buildings) or math.hypot(bx + w / 2 - cx, by + h / 2 - cy) < forest.clearing_radius_m + 12:
            continue
        base = float(terrain(np.array([bx, bx + w, bx, bx + w]), np.array([by, by, by + h, by + h]), forest).min())
        buildings.append((*box, base + rng.uniform(*forest.building_height_m)))
    area_ha = (xmax - xmin) * (ymax - ymin) / 1e4
    n = rng.poisson(forest.trees_per_ha * area_ha)
    tx, ty = rng.uniform(xmin, xmax, n), rng.uniform(ymin, ymax, n)
    height = rng.uniform(*forest.tree_height_m, n)
    depth = height * rng.uniform(*forest.crown_depth_ratio, n)
    radius = height * rng.uniform(*forest.crown_radius_ratio, n)
    keep = np.hypot(tx - cx, ty - cy) > forest.clearing_radius_m + radius
    for b in buildings:  # no crown over a roof: a roof's echoes are the roof's
        keep &= ~((tx + radius > b[0] - 1) & (tx - radius < b[2] + 1) & (ty + radius > b[1] - 1)
                  & (ty - radius < b[3] + 1))
    base_z = terrain(tx, ty, forest)
    trees = np.column_stack([tx, ty, base_z + height - depth / 2, depth / 2, radius,
                             rng.uniform(*forest.leaf_density, n), np.full(n, forest.top_density_factor),
                             rng.uniform(*forest.shell_density, n)])[keep]
    return Forest(forest, bounds, trees, np.asarray(buildings, float).reshape(-1, 5), (cx, cy),
                  TreeIndex.of(trees, forest.shell_fraction))


def _ground_hit(sensor_xyz: np.ndarray, beam: np.ndarray, forest: ForestConfig) -> tuple[np.ndarray, np.ndarray]:
    """Range to the terrain and the hit, by fixed-point steps on the terrain's height (slopes of a few tens of
    percent converge in a few steps; a ditch's walls in a few more)."""
    cos = -beam[:, 2]
    rng_m = (sensor_xyz[:, 2] - 120.0) / cos
    for _ in range(12):
        hit = sensor_xyz + beam * rng_m[:, None]
        rng_m = (sensor_xyz[:, 2] - terrain(hit[:, 0], hit[:, 1], forest)) / cos
    return rng_m, sensor_xyz + beam * rng_m[:, None]


def _terrain_cos(hit: np.ndarray, beam: np.ndarray, forest: ForestConfig) -> np.ndarray:
    """|cos| of the incidence on the terrain, its normal by central differences."""
    e = 0.05
    x, y = hit[:, 0], hit[:, 1]
    dx = (terrain(x + e, y, forest) - terrain(x - e, y, forest)) / (2 * e)
    dy = (terrain(x, y + e, forest) - terrain(x, y - e, forest)) / (2 * e)
    n = np.stack([-dx, -dy, np.ones_like(dx)], axis=1)
    n /= np.linalg.norm(n, axis=1)[:, None]
    return np.abs(np.einsum("ij,ij->i", n, beam))


def forest_echoes(first: int, n: int, scene: SceneConfig, sensor: SensorConfig, drawn: Forest,
                  rng: np.random.Generator) -> tuple:
    """Per pulse first..first+n-1: the geometry and up to MAX_ECHOES surfaces in time order, in the tuple
    fwcore.studies.simulate.chunk_of_echoes takes."""
    gps, angle, sensor_xyz, beam = scan_geometry(first, n, scene)
    ground_range, hit = _ground_hit(sensor_xyz, beam, drawn.config)
    cos = -beam[:, 2]
    steps = int(round(TRACE_TOP_M / STEP_M))
    lad, roof_up = trace_leaf_area(hit, beam, STEP_M, steps, drawn.index, drawn.buildings)
    # Beer's law down the beam from the top: bin k spans heights k..k+1 steps above the hit
    q = 1.0 - np.exp(-G_PROJECTION * lad * (STEP_M / cos)[:, None])
    roofed = np.isfinite(roof_up)
    above_roof = np.arange(steps)[None, :] * STEP_M >= np.where(roofed, roof_up, -1.0)[:, None]
    q = np.where(roofed[:, None] & ~above_roof, 0.0, q)
    from_top = q[:, ::-1]
    left = np.cumprod(1.0 - from_top, axis=1)
    before = np.concatenate([np.ones((n, 1)), left[:, :-1]], axis=1)
    share = (before * from_top)[:, ::-1]  # the pulse's energy each bin intercepts
    transmitted = left[:, -1]
    # layers of LAYER_M down from the first leaf the beam meets: their energy, energy-weighted height, spread
    per = int(round(LAYER_M / STEP_M))
    layers = int(math.ceil(steps / per))
    h = (np.arange(steps) + 0.5) * STEP_M
    met = share > 0
    top = np.where(met.any(axis=1), steps - 1 - np.argmax(met[:, ::-1], axis=1), steps - 1)
    layer = np.clip((top[:, None] - np.arange(steps)[None, :]) // per, 0, layers - 1)
    key = (np.arange(n)[:, None] * layers + layer).ravel()
    energy = np.bincount(key, weights=share.ravel(), minlength=n * layers).reshape(n, layers)
    moment = np.bincount(key, weights=(share * h).ravel(), minlength=n * layers).reshape(n, layers)
    second = np.bincount(key, weights=(share * h * h).ravel(), minlength=n * layers).reshape(n, layers)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = moment / energy
        spread = np.sqrt(np.maximum(second / energy - centre ** 2, 0.0))
    energy = np.where(energy >= MIN_LAYER_SHARE, energy, 0.0)
    strongest = np.argsort(-energy, axis=1)[:, :MAX_ECHOES - 1]
    e_k = np.take_along_axis(energy, strongest, axis=1)
    c_k = np.take_along_axis(centre, strongest, axis=1)
    veg = e_k > 0
    w_k = np.where(veg, np.take_along_axis(spread, strongest, axis=1), 0.0)
    n_veg = veg.sum(axis=1)

    ranges = np.zeros((n, MAX_ECHOES))
    fill = np.zeros((n, MAX_ECHOES))
    spread_m = np.zeros((n, MAX_ECHOES))
    kind = np.zeros((n, MAX_ECHOES), dtype=np.int8)
    ranges[:, :MAX_ECHOES - 1] = np.where(veg, ground_range[:, None] - c_k / cos[:, None], 0.0)
    fill[:, :MAX_ECHOES - 1] = e_k
    spread_m[:, :MAX_ECHOES - 1] = w_k
    kind[:, :MAX_ECHOES - 1] = np.where(veg, 1, 0)
    # the last surface: the ground with what is left, or the roof
    rows = np.arange(n)
    ranges[rows, n_veg] = np.where(roofed, ground_range - np.nan_to_num(roof_up) / cos, ground_range)
    fill[rows, n_veg] = transmitted
    kind[rows, n_veg] = np.where(roofed, 2, 0)
    count = n_veg + 1
    has = np.arange(MAX_ECHOES)[None, :] < count[:, None]
    order = np.argsort(np.where(has, ranges, np.inf), axis=1)
    take = lambda a: np.take_along_axis(a, order, axis=1)  # noqa: E731
    ranges, fill, spread_m, kind = take(ranges), take(fill), take(spread_m), take(kind)

    reflectance = np.where(kind == 1, VEGETATION_REFLECTANCE, np.where(kind == 2, ROOF_REFLECTANCE,
                                                                       GROUND_REFLECTANCE))
    ground_cos = _terrain_cos(hit, beam, drawn.config)
    cos_alpha = np.where(kind == 0, ground_cos[:, None], np.where(kind == 2, cos[:, None], 1.0))
    width = np.clip(np.sqrt(1.0 + (spread_m / RANGE_SIGMA_M) ** 2), 1.0, 2.5)
    width = np.where(kind == 0, 1.0 + 0.5 * (1.0 - ground_cos[:, None]) * 10.0, width)  # slopes broaden the ground
    width = np.clip(width, 1.0, 2.5)
    alpha = rng.uniform(1.3, 1.6, (n, MAX_ECHOES))
    radar_k = scene.radar_amplitude * echo_area(np.full(1, sensor.pulse_fwhm_ps), np.full(1, np.sqrt(2.0)))[0] \
        * 500.0 ** 2
    energy_dn = radar_k * reflectance * cos_alpha * fill / np.where(has, ranges, 1.0) ** 2
    amplitude = np.where(has, energy_dn / echo_area(sensor.pulse_fwhm_ps * width, np.where(has, alpha, 1.4)), 0.0)
    incidence = np.where(has & (kind != 1), np.degrees(np.arccos(np.clip(cos_alpha, 0.0, 1.0))), np.nan)
    return (gps, angle, sensor_xyz, beam, count, np.where(has, ranges, 0.0), amplitude, width, alpha, kind,
            np.where(has, reflectance, np.nan), incidence)


# amplitudes of a reflectance-1 extended target at 500 m: the forest's echoes reach the 8-bit digitizer's top
# only on bright open ground
FOREST_RADAR_AMPLITUDE = 600.0


def forest_flight_scene(scene: SceneConfig = FOREST_SCENE) -> SceneConfig:
    """The forest's flight: the scene's geometry with the forest's radar amplitude."""
    return dataclasses.replace(scene, radar_amplitude=FOREST_RADAR_AMPLITUDE)


def simulate_forest_chunks(n_pulses: int, sensor: SensorConfig, scene: SceneConfig, forest: ForestConfig,
                           seed: int = 0, source_file: str = "simulated.las",
                           drawn: Forest | None = None) -> Iterator[SimulatedFlight]:
    """The forest flight of n_pulses pulses, CHUNK_PULSES at a time (each chunk's noise its own stream)."""
    if n_pulses < 1:
        raise ValueError("simulate at least one pulse")
    drawn = drawn or draw_forest(flight_bounds(n_pulses, scene), forest, seed)
    for chunk, first in enumerate(range(0, n_pulses, CHUNK_PULSES)):
        rng = _chunk_rng(seed, chunk)
        count = min(CHUNK_PULSES, n_pulses - first)
        yield chunk_of_echoes(first, count, sensor, scene, rng, source_file,
                              forest_echoes(first, count, scene, sensor, drawn, rng))
