"""LVIS's own metrics, as its Level 2 (LGE) defines them: ZG the lowest detected mode, ZH the highest detected
return, RH10..RH100 the heights above ZG below which that share of the waveform's energy lies.

LVIS's processing (Blair, Rabine & Hofton 1999; Hofton, Minster & Blair 2000) is what GEDI's L2A was adapted from,
so the steps are GEDI's (fwcore.metrics.signal, ground, rh); the settings are LVIS's. Fitted on the 60 channel-1
shots of the shared LVIS clip against LVIS's own Level 2 of the same shots (docs/lvis.md has the table), they differ
from GEDI's algorithm 1 in five ways:

- the modes, the signal's end and the energy are on the waveform smoothed by the transmitted pulse's own width
  (a Gaussian of the pulse's sigma, FWHM / 2.355: 4.5 samples for LVIS), not 0.89 x 6.5 samples;
- the signal's start (ZH) is where the waveform smoothed by only 2 samples first rises above the noise mean plus 5
  standard deviations (GEDI: 3, on the smoothed waveform);
- the signal's end is the last position above the noise mean plus 4.5 standard deviations (GEDI: 6);
- the energy is the smoothed waveform itself from the end to the start, not the waveform above the noise mean
  (with the noise subtracted RH10 is 0.9 m too high and RH98 0.8 m too low);
- positions are on a half-sample grid (LVIS's ZG and ZH fall on half samples of the L1B's axis).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.metrics.kernel import _cumulative, _first_above, _relative_heights, _smooth
from fwcore.metrics.rh import energy_positions, relative_heights
from fwcore.metrics.signal import SIGMA_PER_WIDTH, gaussian_smooth, smoothing_kernel, subbin_grid
from fwcore.metrics.waveform import GEDI_ALGORITHM_1, NO_SIGNAL, MetricSettings, WaveformMetrics, waveform_metrics


@dataclasses.dataclass(frozen=True)
class LvisSettings:
    """How LVIS's Level 2 finds a waveform's signal, ground and heights. Sigmas in samples; thresholds in noise
    standard deviations above the noise mean. The modes' smoothing is the transmitted pulse's sigma, per file."""

    start_smoothing_sigma: float = 2.0  # ZH: the signal's start on a lightly smoothed waveform
    start_threshold_sd: float = 5.0
    end_threshold_sd: float = 4.5  # the signal's end (RH0); a mode must clear it too (3.5: noise modes)
    subbins: int = 2  # positions to half a sample
    energy_above_noise: bool = False  # True: GEDI's energy (the smoothed waveform less the noise mean)

    def mode_settings(self, pulse_sigma: float) -> MetricSettings:
        """GEDI's kernel settings that find LVIS's ground (and L2B's canopy energies from it): the modes and the
        end on the waveform smoothed by the transmitted pulse's sigma."""
        width = float(pulse_sigma) / SIGMA_PER_WIDTH  # L2A's "width" is not the Gaussian's sigma (signal.py)
        return dataclasses.replace(GEDI_ALGORITHM_1, smoothing_width=width, smoothing_width_zcross=width,
                                   front_threshold_sd=self.start_threshold_sd,
                                   back_threshold_sd=self.end_threshold_sd, subbins=self.subbins)


LVIS_L2 = LvisSettings()


def signal_start(samples: np.ndarray, noise_mean: float, noise_sd: float, settings: LvisSettings = LVIS_L2) -> float:
    """ZH's position (samples from the first, on the sub-bin grid): the first where the lightly smoothed waveform
    rises above the start threshold; NaN where it never does."""
    smoothed = gaussian_smooth(samples, settings.start_smoothing_sigma / SIGMA_PER_WIDTH)
    x, values = subbin_grid(smoothed, settings.subbins)
    above = np.flatnonzero(values > noise_mean + settings.start_threshold_sd * noise_sd)
    return float(x[above[0]]) if above.size else np.nan


def lvis_relative_heights(samples: np.ndarray, noise_mean: float, start: float, end: float, ground: float,
                          metres_per_sample: float, pulse_sigma: float,
                          settings: LvisSettings = LVIS_L2) -> np.ndarray:
    """RH0..RH100 (m above ZG, truncated to cm) from the cumulative energy of the pulse-smoothed waveform between
    the signal's end (RH0) and its start (RH100, ZH)."""
    smoothed = gaussian_smooth(samples, pulse_sigma / SIGMA_PER_WIDTH)
    x, values = subbin_grid(smoothed, settings.subbins)
    energy = values - noise_mean if settings.energy_above_noise else values
    return relative_heights(energy_positions(x, energy, start, end), ground, metres_per_sample)


@njit(**JIT)
def _starts_and_heights(samples, offsets, measured, noise_mean, noise_sd, ground, botloc, drop, start_kernel,
                        pulse_kernel, subbins, start_sd, energy_above_noise, start, rh):
    """signal_start and lvis_relative_heights of every measured waveform (the kernel's steps: fwcore.metrics.kernel),
    into start (NaN where nothing rises above the threshold) and rh (only where the start is over the ground)."""
    for i in range(offsets.size - 1):
        if not measured[i]:
            continue
        wave = samples[offsets[i]:offsets[i + 1]]
        smoothed = np.empty(wave.size)
        _smooth(wave, start_kernel[0], int(start_kernel[1]), smoothed)
        top = _first_above(smoothed, subbins, noise_mean[i] + start_sd * noise_sd[i])
        if top < 0:
            continue
        start[i] = top / subbins
        if not start[i] <= ground[i]:
            continue
        _smooth(wave, pulse_kernel[0], int(pulse_kernel[1]), smoothed)
        bottom = int(round(botloc[i] * subbins))
        cumulative = _cumulative(smoothed, noise_mean[i] if energy_above_noise else 0.0, top, bottom, subbins)
        _relative_heights(cumulative, start[i], botloc[i], ground[i], drop[i], subbins, rh[i])


def lvis_metrics(samples: np.ndarray, offsets: np.ndarray, noise_mean: np.ndarray, noise_sd: np.ndarray,
                 first_z: np.ndarray, metres_per_sample: np.ndarray, cos_zenith: np.ndarray, pulse: np.ndarray,
                 pulse_sigma: float, settings: LvisSettings = LVIS_L2) -> WaveformMetrics:
    """Every waveform's metrics as LVIS's Level 2 defines them (arguments as waveform_metrics', `pulse_sigma` the
    transmitted pulse's sigma in samples): ground_z is ZG, toploc ZH's position, rh LVIS's RH; the canopy's
    energies (L2B's) are measured from that ground. A waveform without metrics keeps its reason."""
    base = waveform_metrics(samples, offsets, noise_mean, noise_sd, first_z, metres_per_sample, cos_zenith, pulse,
                            settings.mode_settings(pulse_sigma))
    values = {f.name: getattr(base, f.name).copy() for f in dataclasses.fields(base) if f.name != "reason"}
    reason = list(base.reason)
    measured = np.array([r == "" for r in reason], dtype=bool)
    start = np.full(measured.size, np.nan)
    rh = np.ascontiguousarray(values["rh"])
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    _starts_and_heights(f64(samples), np.ascontiguousarray(offsets, dtype=np.int64), measured, f64(noise_mean),
                        f64(noise_sd), f64(base.ground_index), f64(base.botloc), f64(metres_per_sample),
                        np.array(smoothing_kernel(settings.start_smoothing_sigma / SIGMA_PER_WIDTH), dtype=np.float64),
                        np.array(smoothing_kernel(pulse_sigma / SIGMA_PER_WIDTH), dtype=np.float64),
                        int(settings.subbins), float(settings.start_threshold_sd), bool(settings.energy_above_noise),
                        start, rh)
    values["rh"] = rh
    no_start = measured & ~(start <= base.ground_index)  # nothing above the start threshold over the ground
    for array in values.values():
        array[no_start] = np.nan
    for i in np.flatnonzero(no_start):
        reason[i] = NO_SIGNAL
    values["toploc"] = np.where(measured & ~no_start, start, values["toploc"])
    return WaveformMetrics(**values, reason=reason)
