"""Every pulse's forest metrics in one call: the settings (GEDI L2A's algorithm 1 by default), the per-pulse record
and the batch function over the flat samples the readers hand on.

    waveform_metrics(samples, offsets, noise_mean, noise_sd, first_z, metres_per_sample, cos_zenith, pulse, settings)
        -> WaveformMetrics (the numba kernel, fwcore.metrics.kernel; reference_metrics: the same in NumPy): ground_z, rh (n, 101), rv, rg, pgap, cover, pai, cover_z / pai_z / pavd_z (n, 30),
           and a reason per pulse ('' when measured; otherwise why its metrics are null)

Heights come from each waveform's own vertical axis: the first sample's elevation and the vertical drop per
sample (GEDI: elevation_bin0 to elevation_lastbin over count - 1 samples; airborne: the beam's direction).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fwcore.metrics.canopy import CanopySettings, GroundPulse, canopy_cover, canopy_energy, gap_probability, \
    ground_return, plant_area_index, vertical_profile
from fwcore.metrics.ground import cumulative_energy_at, local_energy, selected_mode, signal_modes
from fwcore.metrics.rh import PERCENTILES, energy_positions, relative_heights
from fwcore.metrics.signal import gaussian_smooth, signal_extent, smoothing_kernel, subbin_grid

NO_SIGNAL = "no signal above the noise thresholds"
NO_GROUND = "no mode above the back threshold: no ground"
NO_NOISE = "no finite noise estimate"
NOT_FINITE = "non-finite samples"
NO_AXIS = "no vertical axis (the beam is horizontal or its geolocation is missing)"


@dataclasses.dataclass(frozen=True)
class MetricSettings:
    """How a waveform's signal, ground and heights are found (GEDI L2A's rx_processing settings) and the canopy's
    constants (L2B). Widths are in samples; thresholds in noise standard deviations above the noise mean."""

    smoothing_width: float = 6.5  # rx_smoothing_width_locs: the signal's extent and the RH energy
    smoothing_width_zcross: float = 6.5  # rx_smoothing_width_zcross: the modes
    front_threshold_sd: float = 3.0  # rx_front_threshold: the signal starts above it
    back_threshold_sd: float = 6.0  # rx_back_threshold: the signal ends above it; a mode must clear it
    subbins: int = 4  # rx_subbin_resolution: positions to a quarter sample
    signal_search_buffer: float = 1.0  # L2B: samples kept either side of the signal for its energies
    ground_centre_buffer: float = 4.0  # L2B: the ground return's centre within this many samples of the ground
    # L2A's mode selection (fwcore.metrics.ground): off in algorithm 1, on in algorithm 2
    select_mode: bool = False  # enable_select_mode
    pulse_sep_thresh: float = 8.0  # samples: modes this near botloc are passed over; the local energy's half window
    cumulative_energy_minimum: float = 0.0  # %: modes with less energy below them are passed over
    cumulative_energy_thresh: float = 0.0  # %: ... and a mode with more is the ground
    energy_thresh: float = 50.0  # a mode with more local energy is the ground
    amp_thresh: float = 50.0  # a mode with a higher amplitude above the noise mean is the ground
    max_modes: int = 20  # rx_max_mode_count: the modes kept for mode_z (the lowest, where there are more)
    canopy: CanopySettings = CanopySettings()

    @property
    def mode_selection(self) -> np.ndarray:
        """The selection's thresholds as the kernel takes them (select_mode as 0/1 first)."""
        return np.array([float(self.select_mode), self.pulse_sep_thresh, self.cumulative_energy_minimum,
                         self.cumulative_energy_thresh, self.energy_thresh, self.amp_thresh], dtype=np.float64)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "MetricSettings":
        return cls(**{**d, "canopy": CanopySettings(**d.get("canopy", {}))})


GEDI_ALGORITHM_1 = MetricSettings()


@dataclasses.dataclass(frozen=True)
class WaveformMetrics:
    """Per pulse (n rows): positions in samples from the first, heights in metres; NaN where `reason` says why."""

    toploc: np.ndarray
    botloc: np.ndarray
    ground_index: np.ndarray
    ground_z: np.ndarray
    mode_z: np.ndarray  # (n, max_modes): every mode's height, top to bottom, NaN-padded (those below ground_z passed over)
    rh: np.ndarray  # (n, 101) RH0..RH100, m above the ground
    rv: np.ndarray  # canopy energy (sample units of the waveform's digital numbers)
    rg: np.ndarray  # ground energy
    pgap: np.ndarray
    cover: np.ndarray
    pai: np.ndarray
    cover_z: np.ndarray  # (n, bins)
    pai_z: np.ndarray
    pavd_z: np.ndarray  # m2/m3
    reason: list[str]

    def __len__(self) -> int:
        return self.ground_z.size


def empty_metrics(n: int, bins: int, modes: int) -> dict[str, np.ndarray]:
    return {"toploc": np.full(n, np.nan), "botloc": np.full(n, np.nan), "ground_index": np.full(n, np.nan),
            "ground_z": np.full(n, np.nan), "mode_z": np.full((n, modes), np.nan), "rh": np.full((n, PERCENTILES.size), np.nan), "rv": np.full(n, np.nan),
            "rg": np.full(n, np.nan), "pgap": np.full(n, np.nan), "cover": np.full(n, np.nan),
            "pai": np.full(n, np.nan), "cover_z": np.full((n, bins), np.nan), "pai_z": np.full((n, bins), np.nan),
            "pavd_z": np.full((n, bins), np.nan)}


def pulse_metrics(samples: np.ndarray, noise_mean: float, noise_sd: float, first_z: float,
                  metres_per_sample: float, cos_zenith: float, pulse: GroundPulse,
                  settings: MetricSettings = GEDI_ALGORITHM_1) -> dict:
    """One waveform's metrics as a dict of scalars and arrays, with 'reason' ('' when measured); `pulse` is the
    transmitted pulse's shape the ground return is fitted with."""
    if not (np.isfinite(noise_mean) and np.isfinite(noise_sd)):
        return {"reason": NO_NOISE}
    if not np.isfinite(samples).all():
        return {"reason": NOT_FINITE}
    if not (np.isfinite(first_z) and np.isfinite(metres_per_sample) and metres_per_sample > 0):
        return {"reason": NO_AXIS}
    smoothed = gaussian_smooth(samples, settings.smoothing_width)
    x, values = subbin_grid(smoothed, settings.subbins)
    back = noise_mean + settings.back_threshold_sd * noise_sd
    toploc, botloc = signal_extent(x, values, noise_mean + settings.front_threshold_sd * noise_sd, back)
    if not np.isfinite(toploc):
        return {"reason": NO_SIGNAL}
    zcross_smoothed = (smoothed if settings.smoothing_width_zcross == settings.smoothing_width
                       else gaussian_smooth(samples, settings.smoothing_width_zcross))
    position, amplitude = signal_modes(zcross_smoothed, toploc, botloc, back, settings.subbins)
    if not position.size:
        return {"reason": NO_GROUND, "toploc": toploc, "botloc": botloc}
    # the modes' energies, and the RH, from the waveform the modes are found on (rx_smoothing_width_zcross)
    energy = subbin_grid(zcross_smoothed, settings.subbins)[1] - noise_mean
    ground = float(position[ground_mode(x, energy, position, amplitude - noise_mean, toploc, botloc,
                                        back - noise_mean, settings)])
    rh = relative_heights(energy_positions(x, energy, toploc, botloc), ground, metres_per_sample)
    mode_z = np.full(settings.max_modes, np.nan)
    kept = position[-settings.max_modes:] if settings.max_modes > 0 else position[:0]
    mode_z[:kept.size] = first_z - kept * metres_per_sample
    # L2B's energies: the raw waveform above the noise mean, within the signal and a buffer (1-based like its fit)
    sample = np.arange(1, samples.size + 1)
    buffer = settings.signal_search_buffer
    signal = np.where((sample > toploc - buffer) & (sample < botloc + buffer), np.maximum(samples - noise_mean, 0), 0)
    model, rg = ground_return(signal, ground, pulse, settings.ground_centre_buffer)
    canopy = canopy_energy(signal, model, ground)
    rv = float(canopy.sum())
    pgap = float(gap_probability(rv, rg, settings.canopy.rhov_rhog))
    cover_z, pai_z, pavd_z = vertical_profile((ground - np.arange(samples.size)) * metres_per_sample, canopy, rv, rg,
                                              cos_zenith, settings.canopy)
    return {"reason": "", "toploc": toploc, "botloc": botloc, "ground_index": ground,
            "ground_z": first_z - ground * metres_per_sample, "mode_z": mode_z, "rh": rh, "rv": rv, "rg": rg, "pgap": pgap,
            "cover": float(canopy_cover(pgap, cos_zenith)),
            "pai": float(plant_area_index(pgap, cos_zenith, settings.canopy.rossg, settings.canopy.omega)),
            "cover_z": cover_z, "pai_z": pai_z, "pavd_z": pavd_z}


def ground_mode(x: np.ndarray, energy: np.ndarray, position: np.ndarray, amplitude_above_mean: np.ndarray,
                toploc: float, botloc: float, back_above_mean: float, settings: MetricSettings) -> int:
    """The index of the ground among the modes (top to bottom): the lowest, or L2A's selection where enabled, among
    the lowest `max_modes` (L2A keeps rx_max_mode_count modes: its selected mode is one of them)."""
    if not settings.select_mode:
        return position.size - 1
    first = max(position.size - max(settings.max_modes, 1), 0)
    position, amplitude_above_mean = position[first:], amplitude_above_mean[first:]
    cumulative = 100.0 * cumulative_energy_at(x, energy, toploc, botloc, position)
    local = local_energy(energy, position, settings.pulse_sep_thresh, settings.subbins)
    return first + selected_mode(position, amplitude_above_mean, cumulative, local, botloc, back_above_mean,
                                 settings.pulse_sep_thresh, settings.cumulative_energy_minimum,
                                 settings.energy_thresh, settings.amp_thresh, settings.cumulative_energy_thresh)


REASONS = ("", NO_NOISE, NOT_FINITE, NO_AXIS, NO_SIGNAL, NO_GROUND)  # by fwcore.metrics.kernel's codes


def waveform_metrics(samples: np.ndarray, offsets: np.ndarray, noise_mean: np.ndarray, noise_sd: np.ndarray,
                     first_z: np.ndarray, metres_per_sample: np.ndarray, cos_zenith: np.ndarray,
                     pulse: np.ndarray, settings: MetricSettings = GEDI_ALGORITHM_1) -> WaveformMetrics:
    """Every waveform's metrics (the numba kernel, fwcore.metrics.kernel; pulse_metrics is its reference):
    waveform i is samples[offsets[i]:offsets[i + 1]]; per-waveform arrays beside, and `pulse` (n, 4): each shot's
    transmitted pulse as GroundPulse fields (sigma, its error, gamma, its error)."""
    from fwcore.metrics.kernel import metrics_kernel

    n = offsets.size - 1
    bins = settings.canopy.profile_heights.size
    out = empty_metrics(n, bins, max(int(settings.max_modes), 0))
    scalars = np.full((n, 10), np.nan)
    reason = np.zeros(n, dtype=np.int8)
    f64 = lambda a: np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), (n,)))  # noqa: E731
    canopy = settings.canopy
    metrics_kernel(np.ascontiguousarray(samples, dtype=np.float64), np.ascontiguousarray(offsets, dtype=np.int64),
                   f64(noise_mean), f64(noise_sd), f64(first_z), f64(metres_per_sample), f64(cos_zenith),
                   np.ascontiguousarray(np.asarray(pulse, dtype=np.float64).reshape(n, 4)),
                   np.array([*smoothing_kernel(settings.smoothing_width),
                             *smoothing_kernel(settings.smoothing_width_zcross)], dtype=np.float64),
                   np.array([settings.front_threshold_sd, settings.back_threshold_sd], dtype=np.float64),
                   int(settings.subbins),
                   np.array([settings.signal_search_buffer, settings.ground_centre_buffer], dtype=np.float64),
                   np.array([canopy.rhov_rhog, canopy.rossg, canopy.omega, canopy.profile_step_m], dtype=np.float64),
                   settings.mode_selection, reason, scalars, out["rh"], out["cover_z"], out["pai_z"], out["pavd_z"],
                   out["mode_z"])
    for column, name in enumerate(("toploc", "botloc", "ground_index", "ground_z", "rv", "rg", "pgap", "cover",
                                   "pai")):
        out[name] = scalars[:, column]
    return WaveformMetrics(**out, reason=[REASONS[r] for r in reason])


def reference_metrics(samples: np.ndarray, offsets: np.ndarray, noise_mean: np.ndarray, noise_sd: np.ndarray,
                      first_z: np.ndarray, metres_per_sample: np.ndarray, cos_zenith: np.ndarray,
                      pulse: np.ndarray, settings: MetricSettings = GEDI_ALGORITHM_1) -> WaveformMetrics:
    """waveform_metrics by pulse_metrics, a waveform at a time in NumPy: the kernel's reference."""
    n = offsets.size - 1
    out = empty_metrics(n, settings.canopy.profile_heights.size, settings.max_modes)
    reasons = []
    for i in range(n):
        row = pulse_metrics(samples[offsets[i]:offsets[i + 1]], float(noise_mean[i]), float(noise_sd[i]),
                            float(first_z[i]), float(metres_per_sample[i]), float(cos_zenith[i]),
                            GroundPulse(*map(float, pulse[i])), settings)
        reasons.append(row.pop("reason"))
        for name, value in row.items():
            out[name][i] = value
    return WaveformMetrics(**out, reason=reasons)
