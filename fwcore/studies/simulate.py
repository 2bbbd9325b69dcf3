"""Synthetic flights with known echoes: a scene, a sensor, and the truth of every echo.

A flight line at constant altitude scans across track (sawtooth scan angle)
over gently rolling terrain with trees (one to five vegetation layers over
the ground) and flat roofs (some pulses split between a roof edge and the
ground). Each surface the beam meets is a generalized Gaussian echo of its own
amplitude, width and shape; the sensor adds background, Gaussian noise plus
signal-dependent (Poisson-like) noise, and quantises to 8 or 16 bits with
saturation. An online detector (threshold crossings, as a scanner's) gives
the system's own returns, written as the points that carry each packet.

Times count from each packet's first sample, as the pipeline's do; sigma is
Chauve's, with t in ps (fwcore.engine.model); x, y, z follow the same geolocation as
the reader's (X = X0 + (L0 - t) x_t).

With `SceneConfig.radiometry`, every surface has a diffuse reflectance and every echo the energy of the radar
equation (Wagner 2006): E = K rho cos(alpha) f / R^2, f the share of the footprint the surface fills (1 for an
extended target), alpha its incidence; the flying height climbs during the flight so that ranges vary, and
a band of the ground (the calibration patch) has one known reflectance and nothing above it.

A flight is simulated in chunks of CHUNK_PULSES pulses, each from its own random stream (the seed and the
chunk's index), so a flight of any size is written holding one chunk (fwcore.studies.truth.write_flight).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterator

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.io.records import PulseBatch
from fwcore.io.writer import packet_byte_offsets, pulse_ids_as_written
from fwcore.instrument.response import SystemResponse
from fwcore.instrument.shape import echo_shape
from fwcore.engine.model import LN2, SQRT_2LN2, tabulated_areas, tabulated_model

LIGHT_M_PER_PS = 299792458.0e-12
RANGE_M_PER_PS = LIGHT_M_PER_PS / 2.0  # two-way travel: a ps of echo time is this much range
MAX_ECHOES = 6
MAX_RETURNS = 5
# Pulses simulated at a time. The flight's bytes depend on it (each chunk draws from its own stream), so it
# is fixed, not an option; a flight of at most one chunk is the flight simulated before there were chunks.
CHUNK_PULSES = 100_000
RESPONSE_WIDEST = 3.0  # x the response's FWHM: the widest echo a response's table holds
_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2


@dataclasses.dataclass(frozen=True)
class SensorConfig:
    """The digitizer and the emitted pulse."""

    pulse_fwhm_ps: float = 4000.0
    sample_spacing_ps: float = 1000.0
    samples_per_packet: int = 200
    digitizer_gain: float = 0.01  # volts per DN, written to the descriptor
    digitizer_offset: float = 0.0
    background: float = 12.0  # DN
    noise_sigma: float = 1.5  # DN, Gaussian
    shot_noise: float = 0.05  # DN of variance per DN of signal (Poisson-like)
    bits: int = 8
    detection_threshold: float = 6.0  # x noise_sigma above background: the online detector
    # the packet starts this long (plus a random fraction of a sample) before the first surface
    pre_trigger_ps: float = 15000.0
    # The instrument's response (fwcore.instrument): echoes are it broadened by their targets, FWHM
    # pulse_fwhm_ps x the target's width factor. None: the generalized Gaussians of the method's model.
    response: SystemResponse | None = None
    # DN per unit of the scene's amplitudes: a 16-bit digitizer spreads the same echoes over more counts than its
    # noise (a RiPROCESS export's strong returns stand hundreds of sigma above it); weak layers stay in noise units
    amplitude_scale: float = 1.0
    # The response is not the same from pulse to pulse: each pulse's afterpulse (a response's bump behind its
    # peak) is drawn from 1 +/- this share of its mean height, so the fit's one table leaves a residual behind
    # a strong echo (a RIEGL export: weak echoes the fit needs and the filter drops). 0: every pulse the same.
    afterpulse_jitter: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.response, dict):  # read back from a truth table's metadata
            object.__setattr__(self, "response", SystemResponse.from_dict(self.response))
        if self.bits not in (8, 16):
            raise ValueError("bits must be 8 or 16")
        if self.samples_per_packet < 20 or self.sample_spacing_ps <= 0 or self.pulse_fwhm_ps <= 0:
            raise ValueError("need at least 20 samples per packet and positive spacing and pulse width")


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """The flight line and what it flies over."""

    altitude_m: float = 500.0
    speed_m_s: float = 60.0
    pulse_rate_hz: float = 100_000.0
    pulses_per_line: int = 400  # one scan line, edge to edge
    max_scan_angle_deg: float = 20.0
    canopy_cover: float = 0.45  # fraction of pulses through vegetation
    canopy_height_m: tuple[float, float] = (6.0, 22.0)
    roof_fraction: float = 0.12
    roof_height_m: tuple[float, float] = (4.0, 12.0)
    weak_echo_fraction: float = 0.15  # vegetation layers near the noise floor
    # grass and litter on open ground: a weak surface just above the ground on this share of its pulses
    # (fwcore.studies.simulate._ground_cover), of this share of the ground's amplitude, this high above it
    ground_cover_fraction: float = 0.0
    ground_cover_share: tuple[float, float] = (0.03, 0.1)
    ground_cover_height_m: tuple[float, float] = (0.15, 0.45)
    start_gps_time: float = 400_000.0
    # radiometry: reflectances and the radar equation's energies (otherwise amplitudes are drawn at random)
    radiometry: bool = False
    altitude_change_m: float = 0.0  # the flying height climbs this much (a cosine ramp) ...
    altitude_change_s: float = 1.0  # ... over this many seconds from the start
    beam_divergence_mrad: float = 0.5
    radar_amplitude: float = 2000.0  # DN: the peak of a reflectance-1 extended target at 500 m, normal incidence
    patch_y_m: tuple[float, float] = (-90.0, -50.0)  # the calibration patch: a band of open ground ...
    patch_reflectance: float = 0.25  # ... of this reflectance


@dataclasses.dataclass(frozen=True)
class SimulatedFlight:
    """The pulses (ready for fwcore.io.writer.write_waveform_las) and the truth of every echo."""

    pulses: PulseBatch
    truth: dict[str, np.ndarray]  # one entry per true echo, see TRUTH_COLUMNS
    bits: int


TRUTH_COLUMNS = ("pulse_id", "echo_index", "surface", "time_ps", "amplitude", "sigma_ps", "alpha", "fwhm_ps",
                 "noise_sigma", "x", "y", "z", "range_m", "reflectance", "incidence_deg", "extended", "energy")
SURFACES = ("ground", "vegetation", "roof")
GROUND_REFLECTANCES = (0.05, 0.1, 0.2, 0.3, 0.45, 0.6)  # asphalt to bright soil, a block of 20 m each
RADAR_REFERENCE_RANGE_M = 500.0


def sensor_position(gps_time: np.ndarray, scene: SceneConfig) -> np.ndarray:
    """The scanner's optical centre (n, 3) at these times: straight along x at the scene's speed, climbing by
    altitude_change_m over altitude_change_s (a cosine ramp, then level)."""
    t = np.asarray(gps_time, dtype=float) - scene.start_gps_time
    ramp = np.clip(t / scene.altitude_change_s, 0.0, 1.0)
    climb = scene.altitude_change_m * 0.5 * (1.0 - np.cos(np.pi * ramp))
    return np.stack([scene.speed_m_s * t, np.zeros(t.size), scene.altitude_m + 120.0 + climb], axis=1)


def _terrain_normal(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Unit upward normals of _terrain (its gradient, analytically)."""
    dx = 6.0 / 90.0 * np.cos(x / 90.0) + 1.5 / 23.0 * np.cos((x + y) / 23.0)
    dy = -4.0 / 70.0 * np.sin(y / 70.0) + 1.5 / 23.0 * np.cos((x + y) / 23.0)
    n = np.stack([-dx, -dy, np.ones_like(dx)], axis=1)
    return n / np.linalg.norm(n, axis=1)[:, None]


def echo_area(fwhm_ps: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The area (ps per unit amplitude) of a generalized Gaussian echo exp(-|t|^(alpha^2) / (2 sigma^2)) of
    this FWHM: 2 Gamma(1 + 1/p) h / ln2^(1/p), p = alpha^2, h = FWHM / 2."""
    from scipy.special import gamma

    p = np.asarray(alpha, dtype=float) ** 2
    return 2.0 * gamma(1.0 + 1.0 / p) * (np.asarray(fwhm_ps) / 2.0) / LN2 ** (1.0 / p)


def _terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Rolling terrain, metres."""
    return 120.0 + 6.0 * np.sin(x / 90.0) + 4.0 * np.cos(y / 70.0) + 1.5 * np.sin((x + y) / 23.0)


def scan_geometry(first: int, n: int, scene: SceneConfig):
    """Per pulse first..first+n-1: GPS time, scan angle (radians), the scanner's position and the unit beam."""
    i = first + np.arange(n)
    gps = scene.start_gps_time + i / scene.pulse_rate_hz
    line, step = np.divmod(i, scene.pulses_per_line)
    frac = step / max(scene.pulses_per_line - 1, 1)
    forward = line % 2 == 0  # the mirror sweeps back and forth
    angle = np.radians(scene.max_scan_angle_deg) * np.where(forward, 2 * frac - 1, 1 - 2 * frac)
    sensor_xyz = sensor_position(gps, scene)
    beam = np.stack([np.zeros(n), np.sin(angle), -np.cos(angle)], axis=1)
    return gps, angle, sensor_xyz, beam


def _pulse_geometry(first: int, n: int, scene: SceneConfig):
    """Per pulse first..first+n-1: GPS time, scan angle, sensor position, beam, the range to the ground and
    where the beam meets it (no random draw)."""
    gps, angle, sensor_xyz, beam = scan_geometry(first, n, scene)
    # ground range: two fixed-point steps on the terrain height are plenty at these slopes
    ground_range = (sensor_xyz[:, 2] - 120.0) / np.cos(angle)
    for _ in range(3):
        hit = sensor_xyz + beam * ground_range[:, None]
        ground_range = (sensor_xyz[:, 2] - _terrain(hit[:, 0], hit[:, 1])) / np.cos(angle)
    hit = sensor_xyz + beam * ground_range[:, None]
    return gps, angle, sensor_xyz, beam, ground_range, hit


def _tree_echoes(rng: np.random.Generator, scene: SceneConfig, sensor: SensorConfig, tree: np.ndarray,
                 ground_range: np.ndarray, ground_amplitude: np.ndarray, angle: np.ndarray, echoes) -> np.ndarray:
    """Trees: 1 to 5 layers between 1 m above ground and the crown top, then the ground, written into
    echoes = (range, amplitude, width, alpha, kind, count) in place; returns the layers drawn per pulse."""
    rng_range, amplitude, width, alpha, kind, count = echoes
    n = tree.size
    layers = rng.integers(1, 6, n)
    height = rng.uniform(*scene.canopy_height_m, n)
    transmitted = np.ones(n)
    for k in range(MAX_ECHOES - 1):
        on = tree & (layers > k)
        depth = height * (1.0 - (k + rng.uniform(0.1, 0.9, n)) / (MAX_ECHOES - 1))  # metres above ground, top first
        depth = np.maximum(depth, 1.0)
        layer_amplitude = rng.uniform(15, 110, n) * sensor.amplitude_scale * transmitted
        weak = rng.random(n) < scene.weak_echo_fraction
        layer_amplitude = np.where(weak, rng.uniform(3.0, 6.0, n) * sensor.noise_sigma, layer_amplitude)
        rng_range[on, k] = ground_range[on] - depth[on] / np.cos(angle[on])
        amplitude[on, k] = layer_amplitude[on]
        width[on, k] = rng.uniform(1.0, 1.8, on.sum())
        alpha[on, k] = rng.uniform(1.2, 2.2, on.sum())
        kind[on, k] = 1
        transmitted = np.where(on, transmitted * rng.uniform(0.5, 0.85, n), transmitted)
    rows = np.flatnonzero(tree)
    last = layers[tree]
    rng_range[rows, last] = ground_range[tree]
    amplitude[rows, last] = ground_amplitude[tree] * transmitted[tree]
    width[rows, last] = 1.0 + 0.8 * np.sin(angle[tree]) ** 2
    alpha[rows, last] = rng.uniform(1.3, 2.0, tree.sum())
    kind[rows, last] = 0
    count[tree] = layers[tree] + 1
    return layers


def _scene_echoes(first: int, n: int, scene: SceneConfig, sensor: SensorConfig, rng: np.random.Generator):
    """Per pulse first..first+n-1: geometry, and up to MAX_ECHOES surfaces (range, amplitude, FWHM factor,
    alpha, kind)."""
    gps, angle, sensor_xyz, beam, ground_range, hit = _pulse_geometry(first, n, scene)
    rng_range = np.zeros((n, MAX_ECHOES))
    amplitude = np.zeros((n, MAX_ECHOES))
    width = np.ones((n, MAX_ECHOES))
    alpha = np.zeros((n, MAX_ECHOES))
    kind = np.zeros((n, MAX_ECHOES), dtype=np.int8)
    count = np.ones(n, dtype=np.int64)
    # roofs on a block grid, trees elsewhere by chance
    block = (np.floor(hit[:, 0] / 35.0) * 7 + np.floor(hit[:, 1] / 35.0) * 3) % 9
    roof = (block < 9 * scene.roof_fraction) & (rng.random(n) < 0.95)
    tree = ~roof & (rng.random(n) < scene.canopy_cover)
    if scene.radiometry:  # the calibration patch is open ground
        open_ground = (hit[:, 1] >= scene.patch_y_m[0]) & (hit[:, 1] <= scene.patch_y_m[1])
        roof, tree = roof & ~open_ground, tree & ~open_ground
    # ground: the last echo; under canopy it keeps what the layers let through
    ground_amplitude = rng.uniform(40, 200, n) * sensor.amplitude_scale
    rng_range[:, 0] = ground_range
    width[:, 0] = 1.0 + 0.8 * np.sin(angle) ** 2 + rng.uniform(0, 0.15, n)
    alpha[:, 0] = rng.uniform(1.3, 2.0, n)
    kind[:, 0] = 0
    # roofs: one flat echo, or at an edge a roof and the ground
    roof_height = rng.uniform(*scene.roof_height_m, n)
    edge = roof & (rng.random(n) < 0.3)
    rng_range[roof, 0] = ground_range[roof] - roof_height[roof] / np.cos(angle[roof])
    kind[roof, 0] = 2
    alpha[roof, 0] = rng.uniform(1.6, 2.2, roof.sum())
    rng_range[edge, 1] = ground_range[edge]
    amplitude[edge, 1] = rng.uniform(20, 120, edge.sum()) * sensor.amplitude_scale
    width[edge, 1] = 1.0 + rng.uniform(0, 0.2, edge.sum())
    alpha[edge, 1] = rng.uniform(1.3, 2.0, edge.sum())
    kind[edge, 1] = 0
    count[edge] = 2
    layers = _tree_echoes(rng, scene, sensor, tree, ground_range, ground_amplitude, angle,
                          (rng_range, amplitude, width, alpha, kind, count))
    amplitude[~tree & ~edge, 0] = ground_amplitude[~tree & ~edge]
    amplitude[edge, 0] = rng.uniform(40, 200, edge.sum()) * sensor.amplitude_scale
    if scene.ground_cover_fraction > 0.0:  # drawn only when asked: a scene without it keeps its bytes
        _ground_cover(rng, scene, ~tree & ~roof, ground_range, angle, (rng_range, amplitude, width, alpha, kind, count))
    reflectance = np.full((n, MAX_ECHOES), np.nan)
    incidence = np.full((n, MAX_ECHOES), np.nan)
    if scene.radiometry:
        amplitude, reflectance, incidence = _radar_echoes(rng, scene, sensor, hit, beam, angle, rng_range, width,
                                                          alpha, kind, count, tree, edge, layers, amplitude)
    # echoes in time order: the layers are drawn top first, but keep the guarantee explicit
    order = np.argsort(np.where(np.arange(MAX_ECHOES)[None, :] < count[:, None], rng_range, np.inf), axis=1)
    take = lambda a: np.take_along_axis(a, order, axis=1)  # noqa: E731
    return (gps, angle, sensor_xyz, beam, count, take(rng_range), take(amplitude), take(width), take(alpha),
            take(kind), take(reflectance), take(incidence))


def _ground_cover(rng: np.random.Generator, scene: SceneConfig, open_ground: np.ndarray, ground_range: np.ndarray,
                  angle: np.ndarray, echoes) -> None:
    """Grass and litter on open ground: on scene.ground_cover_fraction of its pulses a weak surface
    (scene.ground_cover_share of the ground's amplitude) scene.ground_cover_height_m above the ground, under one
    pulse width from it, added to echoes = (range, amplitude, width, alpha, kind, count) in place."""
    rng_range, amplitude, width, alpha, kind, count = echoes
    n = open_ground.size
    on = open_ground & (rng.random(n) < scene.ground_cover_fraction) & (count < MAX_ECHOES)
    height = rng.uniform(*scene.ground_cover_height_m, n)
    share = rng.uniform(*scene.ground_cover_share, n)
    rows = np.flatnonzero(on)
    k = count[rows]
    rng_range[rows, k] = ground_range[rows] - height[rows] / np.cos(angle[rows])
    amplitude[rows, k] = share[rows] * amplitude[rows, 0]
    width[rows, k] = rng.uniform(1.0, 1.3, rows.size)
    alpha[rows, k] = rng.uniform(1.3, 2.0, rows.size)
    kind[rows, k] = 1
    count[rows] += 1


def _radar_echoes(rng, scene, sensor, hit, beam, angle, rng_range, width, alpha, kind, count, tree, edge, layers,
                  drawn):
    """Amplitudes from the radar equation: E = K rho cos(alpha) f / R^2 over each echo's area; the
    reflectance and incidence of each surface. Vegetation near the noise floor keeps its drawn amplitude."""
    n = hit.shape[0]
    block = (np.floor(hit[:, 0] / 20.0) * 5 + np.floor(hit[:, 1] / 20.0) * 3) % len(GROUND_REFLECTANCES)
    ground_rho = np.asarray(GROUND_REFLECTANCES)[block.astype(int)]
    in_patch = (hit[:, 1] >= scene.patch_y_m[0]) & (hit[:, 1] <= scene.patch_y_m[1])
    ground_rho = np.where(in_patch, scene.patch_reflectance, ground_rho)
    roof_rho = 0.1 + 0.4 * ((np.floor(hit[:, 0] / 35.0) * 3 + np.floor(hit[:, 1] / 35.0) * 7) % 5) / 4.0
    leaf_rho = rng.uniform(0.3, 0.6, (n, MAX_ECHOES))
    share = rng.uniform(0.05, 0.35, (n, MAX_ECHOES))  # the footprint a vegetation layer intercepts
    roof_share = rng.uniform(0.3, 0.7, n)
    cos_ground = np.abs(np.einsum("ij,ij->i", _terrain_normal(hit[:, 0], hit[:, 1]), beam))
    cos_flat = np.cos(angle)
    reference_area = echo_area(np.full(1, sensor.pulse_fwhm_ps), np.full(1, np.sqrt(2.0)))[0]
    radar_k = scene.radar_amplitude * reference_area * RADAR_REFERENCE_RANGE_M ** 2
    has = np.arange(MAX_ECHOES)[None, :] < count[:, None]
    reflectance = np.where(kind == 0, ground_rho[:, None], np.where(kind == 2, roof_rho[:, None], leaf_rho))
    cos_alpha = np.where(kind == 0, cos_ground[:, None], np.where(kind == 2, cos_flat[:, None], 1.0))
    # the footprint each surface fills: vegetation layers in turn, the rest to the ground; a roof edge splits
    fill = np.ones((n, MAX_ECHOES))
    left = np.ones(n)
    for k in range(MAX_ECHOES):
        veg = tree & (k < layers)
        fill[veg, k] = share[veg, k] * left[veg]
        left = np.where(veg, left * (1.0 - share[:, k]), left)
    rows = np.flatnonzero(tree)
    fill[rows, layers[tree]] = left[tree]
    fill[edge, 0] = roof_share[edge]
    fill[edge, 1] = 1.0 - roof_share[edge]
    energy = radar_k * reflectance * cos_alpha * fill / np.where(has, rng_range, 1.0) ** 2
    fwhm = sensor.pulse_fwhm_ps * width
    amplitude = np.where(has, energy / echo_area(fwhm, np.where(has, alpha, np.sqrt(2.0))), 0.0)
    weak = (kind == 1) & (drawn < 6.5 * sensor.noise_sigma)  # the drawn near-noise-floor layers stay weak
    amplitude = np.where(weak, drawn, amplitude)
    incidence = np.where(has & (kind != 1), np.degrees(np.arccos(np.clip(cos_alpha, 0.0, 1.0))), np.nan)
    return amplitude, np.where(has, reflectance, np.nan), incidence


@njit(**JIT)
def _render(time_ps, amplitude, sigma_ps, alpha, count, n_samples, spacing, background, noise, shot, top,
            normal, shaped, out):
    """Waveforms (pulse-major) with noise from `normal` (standard normal draws), quantised and saturated;
    `shaped` holds the signal of echoes of a response (pulse-major; zeros where the echoes are analytic)."""
    for p in range(count.size):
        for i in range(n_samples):
            t = i * spacing
            signal = shaped[p * n_samples + i]
            for k in range(count[p]):
                z = abs(t - time_ps[p, k])
                signal += amplitude[p, k] * math.exp(-z ** (alpha[p, k] ** 2) / (2.0 * sigma_ps[p, k] ** 2))
            sd = math.sqrt(noise * noise + shot * signal)
            v = round(background + signal + sd * normal[p * n_samples + i])
            out[p * n_samples + i] = min(max(v, 0.0), top)


@njit(**JIT)
def _detect(samples, n_samples, threshold, out_index, out_count):
    """The online detector: one return per excursion above threshold, at its highest sample."""
    for p in range(out_count.size):
        base = p * n_samples
        found = 0
        i = 0
        while i < n_samples and found < out_index.shape[1]:
            if samples[base + i] > threshold:
                best = i
                while i < n_samples and samples[base + i] > threshold:
                    if samples[base + i] > samples[base + best]:
                        best = i
                    i += 1
                out_index[p, found] = best
                found += 1
            i += 1
        if found == 0:  # a pulse still needs a point to carry its packet: the strongest sample
            best = 0
            for i in range(n_samples):
                if samples[base + i] > samples[base + best]:
                    best = i
            out_index[p, 0] = best
            found = 1
        out_count[p] = found


def simulate_flight(n_pulses: int, sensor: SensorConfig = SensorConfig(), scene: SceneConfig = SceneConfig(),
                    seed: int = 0, source_file: str = "simulated.las") -> SimulatedFlight:
    """Simulate n_pulses pulses in memory; the same arguments give the same flight, chunk by chunk the
    flight of simulate_chunks."""
    chunks = list(simulate_chunks(n_pulses, sensor, scene, seed, source_file))
    return chunks[0] if len(chunks) == 1 else _concatenate(chunks)


def simulate_chunks(n_pulses: int, sensor: SensorConfig = SensorConfig(), scene: SceneConfig = SceneConfig(),
                    seed: int = 0, source_file: str = "simulated.las") -> Iterator[SimulatedFlight]:
    """The flight of n_pulses pulses, CHUNK_PULSES at a time, in pulse order: one chunk in memory at a time.

    Each chunk's packet offsets are those of the whole file (packets in pulse order, as
    fwcore.io.writer writes them), so its pulses are what the reader will say of the written flight.
    """
    if n_pulses < 1:
        raise ValueError("simulate at least one pulse")
    for chunk, first in enumerate(range(0, n_pulses, CHUNK_PULSES)):
        yield _simulate_chunk(first, min(CHUNK_PULSES, n_pulses - first), sensor, scene, _chunk_rng(seed, chunk),
                              source_file)


def _chunk_rng(seed: int, chunk: int) -> np.random.Generator:
    """Chunk 0 draws from the seed itself (the flight before chunks); chunk k > 0 from the seed's k-th child
    stream (numpy's SeedSequence spawn key), independent of every other seed's and chunk's."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(chunk,) if chunk else ()))


def _simulate_chunk(first: int, n_pulses: int, sensor: SensorConfig, scene: SceneConfig, rng: np.random.Generator,
                    source_file: str) -> SimulatedFlight:
    """Pulses first..first+n_pulses-1 of the flight."""
    return chunk_of_echoes(first, n_pulses, sensor, scene, rng, source_file,
                           _scene_echoes(first, n_pulses, scene, sensor, rng))


def chunk_of_echoes(first: int, n_pulses: int, sensor: SensorConfig, scene: SceneConfig, rng: np.random.Generator,
                    source_file: str, echoes: tuple) -> SimulatedFlight:
    """The pulses of a chunk whose surfaces a scene has placed: echoes = (gps, angle, sensor_xyz, beam, count,
    ranges, amplitude, width, alpha, kind, reflectance, incidence), per pulse up to MAX_ECHOES in time order;
    the sensor renders, adds noise and detects (the forest scene, fwcore.studies.forest, places its own)."""
    gps, angle, sensor_xyz, beam, count, ranges, amplitude, width, alpha, kind, reflectance, incidence = echoes
    has = np.arange(MAX_ECHOES)[None, :] < count[:, None]
    top_range = ranges[:, 0]
    noise_draws = rng.standard_normal(n_pulses * sensor.samples_per_packet)  # drawn first, as before the phase
    # the first surface's sub-sample phase: a packet starts at a sample, not at the same point of every pulse
    pre_trigger = sensor.pre_trigger_ps + rng.uniform(0.0, sensor.sample_spacing_ps, n_pulses)
    time_ps = np.where(has, pre_trigger[:, None] + (ranges - top_range[:, None]) / RANGE_M_PER_PS, 0.0)
    window_ps = (sensor.samples_per_packet - 1) * sensor.sample_spacing_ps
    if np.any(time_ps[has] > window_ps - 3 * sensor.pulse_fwhm_ps):
        raise ValueError("the packet is too short for the scene's heights: raise samples_per_packet")
    fwhm_ps = sensor.pulse_fwhm_ps * width
    half = fwhm_ps / 2.0
    p = alpha ** 2
    sigma_ps = np.where(has, np.sqrt(np.where(has, half, 1.0) ** p / (2.0 * LN2)), 1.0)
    n_samples = sensor.samples_per_packet
    top = float((1 << sensor.bits) - 1)
    samples = np.empty(n_pulses * n_samples)
    shaped = np.zeros(n_pulses * n_samples)
    energy = amplitude * echo_area(fwhm_ps, np.where(has, alpha, np.sqrt(2.0)))
    if sensor.response is not None:
        # echoes of the response: rendered here, the analytic ones given no amplitude
        energy = _response_echoes(sensor, has, amplitude, time_ps, fwhm_ps, shaped, rng)
        alpha = np.full(alpha.shape, np.nan)
        sigma_ps = fwhm_ps / _FWHM_PER_SIGMA
    _render(time_ps, np.where(has & (sensor.response is None), amplitude, 0.0), sigma_ps,
            np.where(has & np.isfinite(alpha), alpha, 1.0), count, n_samples, sensor.sample_spacing_ps,
            sensor.background, sensor.noise_sigma, sensor.shot_noise, top, noise_draws,
            shaped, samples)
    return_index = np.zeros((n_pulses, MAX_RETURNS), dtype=np.int64)
    return_count = np.zeros(n_pulses, dtype=np.int64)
    threshold = sensor.background + sensor.detection_threshold * sensor.noise_sigma
    _detect(samples, n_samples, threshold, return_index, return_count)

    # geometry: a point at packet time t lies at P0 + beam (t - pre_trigger) c/2, P0 the first surface (its pulse's)
    first_surface = sensor_xyz + beam * top_range[:, None]
    direction = -beam * RANGE_M_PER_PS  # the reader's X = X0 + (L0 - t) x_t

    def position(owner, t_ps):
        return first_surface[owner] + beam[owner] * ((t_ps - pre_trigger[owner]) * RANGE_M_PER_PS)[:, None]

    pulses = _flight_pulses(first, sensor, scene, source_file, gps, angle, direction, samples, return_index,
                            return_count, position)
    pulse_id = pulses.pulse_id

    e_owner = np.repeat(np.arange(n_pulses), count)
    e_time = time_ps[has]
    e_xyz = position(e_owner, e_time)
    truth = {
        "pulse_id": pulse_id[e_owner], "echo_index": np.concatenate([np.arange(c) for c in count]),
        "surface": np.array(SURFACES, dtype=object)[kind[has]], "time_ps": e_time, "amplitude": amplitude[has],
        "sigma_ps": sigma_ps[has], "alpha": alpha[has], "fwhm_ps": fwhm_ps[has],
        "noise_sigma": np.full(e_owner.size, sensor.noise_sigma),
        "x": e_xyz[:, 0], "y": e_xyz[:, 1], "z": e_xyz[:, 2],
        "range_m": ranges[has], "reflectance": reflectance[has], "incidence_deg": incidence[has],
        "extended": np.repeat(count == 1, count),  # the one surface fills the footprint
        "energy": energy[has],
    }
    return SimulatedFlight(pulses, truth, sensor.bits)


def _response_echoes(sensor: SensorConfig, has: np.ndarray, amplitude: np.ndarray, time_ps: np.ndarray,
                     fwhm_ps: np.ndarray, shaped: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The echoes of the sensor's response added to `shaped` (pulse after pulse, samples_per_packet each);
    returns their energies (0 where a pulse has no such echo)."""
    n_samples = sensor.samples_per_packet
    shape = echo_shape(sensor.response, sensor.sample_spacing_ps, RESPONSE_WIDEST)
    s = fwhm_ps / _FWHM_PER_SIGMA / sensor.sample_spacing_ps  # each echo's equal-FWHM sigma, samples
    t = np.arange(n_samples, dtype=float)
    for p_, k in zip(*np.nonzero(has)):
        shaped[p_ * n_samples:(p_ + 1) * n_samples] += tabulated_model(
            t, 0.0, amplitude[p_, k], time_ps[p_, k] / sensor.sample_spacing_ps, s[p_, k], shape)
    area = tabulated_areas(shape, s) * sensor.sample_spacing_ps
    if sensor.afterpulse_jitter > 0.0:
        _jitter_afterpulses(sensor, has, amplitude, time_ps, rng, shaped)
    return np.where(has, amplitude * area, 0.0)


def _jitter_afterpulses(sensor: SensorConfig, has: np.ndarray, amplitude: np.ndarray, time_ps: np.ndarray,
                        rng: np.random.Generator, shaped: np.ndarray) -> None:
    """Each pulse's afterpulse a random share (1 +/- sensor.afterpulse_jitter) of the response's mean one: the
    difference added to `shaped` behind every echo, a bump of the pulse's width at the afterpulse's delay."""
    delay_ps, height = sensor.response.afterpulse()
    if height <= 0.0:
        return
    n_samples = sensor.samples_per_packet
    share = rng.uniform(-sensor.afterpulse_jitter, sensor.afterpulse_jitter, has.shape[0])  # one draw a pulse
    t = np.arange(n_samples) * sensor.sample_spacing_ps
    sigma = sensor.pulse_fwhm_ps / _FWHM_PER_SIGMA
    for p_, k in zip(*np.nonzero(has)):
        bump = share[p_] * height * amplitude[p_, k]
        shaped[p_ * n_samples:(p_ + 1) * n_samples] += bump * np.exp(
            -0.5 * ((t - time_ps[p_, k] - delay_ps) / sigma) ** 2)


def _flight_pulses(first: int, sensor: SensorConfig, scene: SceneConfig, source_file: str, gps: np.ndarray,
                   angle: np.ndarray, direction: np.ndarray, samples: np.ndarray, return_index: np.ndarray,
                   return_count: np.ndarray, position) -> PulseBatch:
    """The chunk's pulses as the reader will give them: the detected returns as points (position(owner, t)
    places them), each pulse anchored at its first return, packets at their offsets in the whole file."""
    n_pulses, n_samples = gps.size, sensor.samples_per_packet
    r_has = np.arange(MAX_RETURNS)[None, :] < return_count[:, None]
    r_owner = np.repeat(np.arange(n_pulses), return_count)
    r_time = (return_index[r_has] * sensor.sample_spacing_ps).astype(np.float64)
    r_xyz = position(r_owner, r_time)
    r_intensity = samples[r_owner * n_samples + return_index[r_has]].astype(np.uint16)
    return_offsets = np.zeros(n_pulses + 1, dtype=np.int64)
    np.cumsum(return_count, out=return_offsets[1:])
    return_number = (np.arange(r_owner.size) - return_offsets[r_owner] + 1).astype(np.uint8)
    first_return = return_offsets[:-1]

    lengths = np.full(n_pulses, n_samples)
    first_packet_byte = first * n_samples * (sensor.bits // 8)  # the packets of the chunks before this one
    pulse_id = pulse_ids_as_written(gps, r_xyz[first_return])  # what the reader will say of the written file
    return PulseBatch(
        source_file=source_file, pulse_id=pulse_id,
        packet_offset=packet_byte_offsets(lengths, np.full(n_pulses, sensor.bits)) + first_packet_byte,
        descriptor_index=np.ones(n_pulses, np.int16), gps_time=gps,
        anchor=r_xyz[first_return], anchor_location_ps=r_time[first_return], direction=direction,
        scan_angle=np.degrees(angle), point_source_id=np.ones(n_pulses, np.uint16),
        scan_direction_flag=(((first + np.arange(n_pulses)) // scene.pulses_per_line) % 2 == 0).astype(np.uint8),
        edge_of_flight_line=np.isin((first + np.arange(n_pulses)) % scene.pulses_per_line,
                                    (0, scene.pulses_per_line - 1)).astype(np.uint8),
        user_data=np.zeros(n_pulses, np.uint8), sample_spacing_ps=np.full(n_pulses, sensor.sample_spacing_ps),
        digitizer_gain=np.full(n_pulses, sensor.digitizer_gain),
        digitizer_offset=np.full(n_pulses, sensor.digitizer_offset),
        bits_per_sample=np.full(n_pulses, sensor.bits, np.int16), samples=samples,
        sample_offsets=np.arange(n_pulses + 1, dtype=np.int64) * n_samples, return_xyz=r_xyz,
        return_number=return_number, return_intensity=r_intensity, return_location_ps=r_time,
        return_offsets=return_offsets)


def _concatenate(chunks: list[SimulatedFlight]) -> SimulatedFlight:
    """Consecutive chunks as one flight (offsets into the samples and the returns shifted to match)."""
    batches = [c.pulses for c in chunks]
    fields = {}
    for field in dataclasses.fields(PulseBatch):
        values = [getattr(b, field.name) for b in batches]
        if field.name in ("sample_offsets", "return_offsets"):
            ends = np.cumsum([0] + [v[-1] for v in values[:-1]])
            fields[field.name] = np.concatenate([values[0][:1]] + [v[1:] + e for v, e in zip(values, ends)])
        elif isinstance(values[0], np.ndarray):
            fields[field.name] = np.concatenate(values)
        else:  # the source file, and optional columns the simulator leaves unset
            fields[field.name] = values[0]
    truth = {k: np.concatenate([c.truth[k] for c in chunks]) for k in chunks[0].truth}
    return SimulatedFlight(PulseBatch(**fields), truth, chunks[0].bits)


def render_truth(truth: dict[str, np.ndarray], n_samples: int, spacing_ps: float, background: float,
                 response: SystemResponse | None = None) -> np.ndarray:
    """The noiseless waveform of each pulse in the truth (pulse order of first appearance), (pulses, samples);
    echoes of `response` where the flight was simulated with one."""
    ids, first, owner = np.unique(truth["pulse_id"], return_index=True, return_inverse=True)
    rank = np.empty(ids.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(ids.size)  # pulse ids are hashes: keep pulse order
    owner = rank[owner]
    t = np.arange(n_samples) * spacing_ps
    out = np.full((ids.size, n_samples), background, dtype=float)
    if response is not None:
        shape = echo_shape(response, spacing_ps, RESPONSE_WIDEST)
        for k in range(owner.size):
            out[owner[k]] += tabulated_model(np.arange(n_samples), 0.0, truth["amplitude"][k],
                                             truth["time_ps"][k] / spacing_ps, truth["sigma_ps"][k] / spacing_ps, shape)
        return out
    for k in range(owner.size):
        out[owner[k]] += truth["amplitude"][k] * np.exp(
            -np.abs(t - truth["time_ps"][k]) ** (truth["alpha"][k] ** 2) / (2 * truth["sigma_ps"][k] ** 2))
    return out
