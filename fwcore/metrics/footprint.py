"""A large footprint's waveform built from small ones (GEDI from the air, as the GEDI team's gediRat does from
discrete returns): each airborne echo's energy on a common vertical axis, weighted by the large footprint's
Gaussian at the echo's distance from its centre, then through the large sensor's pulse; its metrics are GEDI's
(fwcore.metrics.waveform: L2A's ground and RH, L2B's cover, PAI and profile).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

GEDI_FOOTPRINT_SIGMA_M = 5.5  # the footprint's Gaussian: gediRat's default fSigma (a 25 m footprint, about 4 sigma)
GEDI_PULSE_FWHM_NS = 15.6  # the transmitted pulse's width (GEDI L1B's typical tx pulse)
GEDI_SAMPLE_NS = 1.0  # the digitiser's 1 ns: 0.15 m of range
METRES_PER_NS = 0.299792458 / 2.0
RELATIVE_NOISE = 1e-3  # the simulated waveform's noise sd, as a share of its peak: the thresholds' scale


@dataclasses.dataclass(frozen=True)
class FootprintSensor:
    """The large-footprint sensor: its Gaussian footprint, pulse and sampling, in metres."""

    sigma_m: float = GEDI_FOOTPRINT_SIGMA_M
    pulse_sigma_m: float = GEDI_PULSE_FWHM_NS / (2.0 * math.sqrt(2.0 * math.log(2.0))) * METRES_PER_NS
    sample_m: float = GEDI_SAMPLE_NS * METRES_PER_NS

    @property
    def radius_m(self) -> float:
        """Echoes beyond this distance weigh less than 1e-3 of the centre's."""
        return self.sigma_m * math.sqrt(2.0 * math.log(1e3))


def footprint_waveform(dx: np.ndarray, dy: np.ndarray, z: np.ndarray, energy: np.ndarray,
                       sensor: FootprintSensor = FootprintSensor()) -> tuple[np.ndarray, float]:
    """The waveform (samples from the top down, noise-free, zero background) of echoes at (dx, dy) metres from the
    footprint's centre, elevations z and energies; and the elevation of its first sample. Empty without echoes."""
    dx, dy, z, energy = (np.asarray(a, float) for a in (dx, dy, z, energy))
    weight = np.exp(-(dx ** 2 + dy ** 2) / (2.0 * sensor.sigma_m ** 2)) * np.nan_to_num(energy)
    keep = weight > 0
    if not keep.any():
        return np.zeros(0), math.nan
    z, weight = z[keep], weight[keep]
    pad = 6.0 * sensor.pulse_sigma_m + 30 * sensor.sample_m  # the pulse's tails and the metrics' search buffers
    top = z.max() + pad
    n = int(math.ceil((top - (z.min() - pad)) / sensor.sample_m)) + 1
    position = (top - z) / sensor.sample_m
    # each echo split between its two nearest samples (linear): its centre kept between samples
    below = np.floor(position).astype(np.int64)
    frac = position - below
    impulse = np.bincount(below, weights=weight * (1 - frac), minlength=n + 1)[:n] + \
        np.bincount(np.minimum(below + 1, n), weights=weight * frac, minlength=n + 1)[:n]
    half = int(math.ceil(5 * sensor.pulse_sigma_m / sensor.sample_m))
    t = np.arange(-half, half + 1) * sensor.sample_m
    pulse = np.exp(-0.5 * (t / sensor.pulse_sigma_m) ** 2)
    pulse /= pulse.sum()
    return np.convolve(impulse, pulse, mode="same"), float(top)


def footprint_metrics(samples: np.ndarray, top_z: float, sensor: FootprintSensor = FootprintSensor()) -> dict:
    """GEDI's metrics of a simulated footprint waveform (fwcore.metrics.waveform.pulse_metrics): ground
    elevation, RH, cover, PAI and the 5 m profile; 'reason' says why not where they could not be measured."""
    from fwcore.metrics.canopy import GroundPulse
    from fwcore.metrics.waveform import pulse_metrics

    if samples.size == 0 or not samples.max() > 0:
        return {"reason": "no echo in the footprint"}
    noise = RELATIVE_NOISE * float(samples.max())
    return pulse_metrics(samples, 0.0, noise, top_z, sensor.sample_m, 1.0,
                         GroundPulse.gaussian_like(sensor.pulse_sigma_m / sensor.sample_m))
