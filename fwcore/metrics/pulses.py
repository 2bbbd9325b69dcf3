"""The forest metrics of a batch of decomposed pulses, whatever the sensor: each waveform's vertical axis from its
geolocation, the noise the file records (GEDI's L1B) or the engine measured, the transmitted pulse's shape the
file records (GEDI's extended Gaussian) or the file's system pulse, and the settings for the sensor's pulse.

For a small-footprint airborne pulse (0.5 m) the same definitions measure the column of the beam: its ground is
the lowest mode of that one waveform, its cover the share of energy the canopy returned before the ground
(a gap or a hit, not a fraction of a 25 m footprint); aggregate pulses over map cells or footprints for cover
and PAI that mean what GEDI's mean.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fwcore.engine.records import BatchDecomposition
from fwcore.instrument.pulse import SystemPulse
from fwcore.io.records import PulseBatch
from fwcore.metrics.lvis import lvis_metrics
from fwcore.metrics.waveform import GEDI_ALGORITHM_1, MetricSettings, WaveformMetrics, waveform_metrics

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
# GEDI's transmitted pulse is about 4.3 samples sigma and L2A smooths with a width of 6.5: other sensors keep the
# ratio, so a waveform is smoothed in proportion to its own pulse
SMOOTHING_WIDTH_PER_PULSE_SIGMA = 6.5 / 4.3


def settings_for_pulse(pulse_sigma_samples: float, base: MetricSettings = GEDI_ALGORITHM_1) -> MetricSettings:
    """GEDI's settings with the smoothing scaled to a sensor's pulse (sigma in samples)."""
    width = float(pulse_sigma_samples) * SMOOTHING_WIDTH_PER_PULSE_SIGMA
    return dataclasses.replace(base, smoothing_width=width, smoothing_width_zcross=width)


def vertical_axis(pulses: PulseBatch) -> tuple[np.ndarray, np.ndarray]:
    """Each waveform's first sample's height and the height it drops per sample (m), from its geolocation:
    position = anchor + (L0 - t) direction."""
    first_z = pulses.anchor[:, 2] + pulses.anchor_location_ps * pulses.direction[:, 2]
    return first_z, pulses.direction[:, 2] * pulses.sample_spacing_ps


def top_heights(pulses: PulseBatch, metrics: WaveformMetrics) -> np.ndarray:
    """Each pulse's highest detected return (LVIS's ZH, GEDI L2A's elev_highestreturn): the height of the signal's
    start, toploc; NaN where its metrics were not measured."""
    first_z, drop = vertical_axis(pulses)
    measured = np.array([r == "" for r in metrics.reason], dtype=bool)
    return np.where(measured, first_z - metrics.toploc * drop, np.nan)


def zenith_cosine(pulses: PulseBatch) -> np.ndarray:
    """The beam's zenith cosine: as the file records it (GEDI), else from its direction (a projected CRS)."""
    if pulses.cos_zenith is not None:
        return pulses.cos_zenith
    length = np.linalg.norm(pulses.direction, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 0, np.abs(pulses.direction[:, 2]) / length, np.nan)


def batch_metrics(pulses: PulseBatch, result: BatchDecomposition, pulse: SystemPulse,
                  settings: MetricSettings | None = None,
                  by_algorithm: dict[int, MetricSettings] | None = None) -> WaveformMetrics:
    """Every pulse's metrics (`settings`: the file's, e.g. its L2A algorithm's; else GEDI's scaled to its pulse
    where the file records no transmitted shape); where the file names each shot's algorithm
    (PulseBatch.metric_algorithm) and `by_algorithm` gives their settings, each shot takes its own. An LVIS file
    (PulseBatch.metric_definition "lvis") takes LVIS's Level 2 definitions (fwcore.metrics.lvis)."""
    sigma = pulse.fwhm_ps / np.maximum(pulses.sample_spacing_ps, 1e-9) / FWHM_PER_SIGMA
    if settings is None:
        settings = GEDI_ALGORITHM_1 if pulses.transmit_shape is not None else settings_for_pulse(np.median(sigma))
    columns = metric_columns(pulses, result, pulse)
    if pulses.metric_definition == "lvis":  # LVIS's own Level 2 metrics, smoothed by its transmitted pulse
        return lvis_metrics(pulses.samples, pulses.sample_offsets, *columns, float(np.median(sigma)))
    if not by_algorithm or pulses.metric_algorithm is None:
        return waveform_metrics(pulses.samples, pulses.sample_offsets, *columns, settings)
    algorithm = np.where(np.isin(pulses.metric_algorithm, list(by_algorithm)), pulses.metric_algorithm, 0)
    parts = {}
    for a in np.unique(algorithm):  # each algorithm's shots in one kernel call
        rows = np.flatnonzero(algorithm == a)
        samples, offsets = take_waveforms(pulses.samples, pulses.sample_offsets, rows)
        parts[int(a)] = (rows, waveform_metrics(samples, offsets, *(c[rows] for c in columns),
                                                by_algorithm.get(int(a), settings)))
    return joined_metrics(len(pulses), list(parts.values()))


def metric_columns(pulses: PulseBatch, result: BatchDecomposition, pulse: SystemPulse) -> tuple[np.ndarray, ...]:
    """Per pulse what the metrics' kernel reads beside the samples: noise mean and sd (the file's, else the
    engine's), the first sample's height and the drop per sample, the zenith cosine and the transmitted shape."""
    sigma = pulse.fwhm_ps / np.maximum(pulses.sample_spacing_ps, 1e-9) / FWHM_PER_SIGMA
    if pulses.transmit_shape is not None:
        shape = pulses.transmit_shape
    else:
        shape = np.stack([sigma, sigma / 3.0, np.ones_like(sigma), np.full_like(sigma, 0.3)], axis=1)
    noise_mean = pulses.noise_mean if pulses.noise_mean is not None else result.background
    noise_sd = pulses.noise_sd if pulses.noise_sd is not None else result.noise_sigma
    first_z, drop = vertical_axis(pulses)
    return noise_mean, noise_sd, first_z, drop, zenith_cosine(pulses), shape


def rows_metrics(pulses: PulseBatch, result: BatchDecomposition, pulse: SystemPulse, settings: MetricSettings,
                 rows: np.ndarray) -> WaveformMetrics:
    """The metrics of pulses `rows` only, by `settings` (GEDI: one L2A algorithm's): a subset's, at its cost."""
    samples, offsets = take_waveforms(pulses.samples, pulses.sample_offsets, rows)
    return waveform_metrics(samples, offsets, *(c[rows] for c in metric_columns(pulses, result, pulse)), settings)


def take_waveforms(samples: np.ndarray, offsets: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Waveforms `rows` of a flat batch as a flat batch of their own."""
    lengths = offsets[rows + 1] - offsets[rows]
    index = np.repeat(offsets[rows] - np.r_[0, np.cumsum(lengths)[:-1]], lengths) + np.arange(lengths.sum())
    return samples[index], np.r_[0, np.cumsum(lengths)].astype(np.int64)


def joined_metrics(n: int, parts: list[tuple[np.ndarray, WaveformMetrics]]) -> WaveformMetrics:
    """Several row subsets' metrics as one record of n rows."""
    first = parts[0][1]
    values = {f.name: np.full((n, *getattr(first, f.name).shape[1:]), np.nan)
              for f in dataclasses.fields(WaveformMetrics) if f.name != "reason"}
    reason = [""] * n
    for rows, metrics in parts:
        for name, array in values.items():
            array[rows] = getattr(metrics, name)
        for i, r in zip(rows, metrics.reason):
            reason[i] = r
    return WaveformMetrics(**values, reason=reason)
