"""The system pulse's width (FWHM), where nothing records it: the outgoing waveforms a file records, the returns
its system saw as single, the isolated echoes of any waveforms, or a NEON-layout CSV's outgoing pulses.

Widths here are in samples unless the name says ps.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fwcore.instrument.peak import isolated_lobe, local_maxima, width_above_minimum
from fwcore.io.neon import NEON_SAMPLE_SPACING_PS
from fwcore.io.records import PulseBatch
from fwcore.engine.model import SQRT_2LN2
from fwcore.engine.smoothing import smoothed_noise_baseline


def median_pulse_fwhm(waveforms, min_samples: int = 5) -> float:
    """The median half-height width (samples) over waveforms of single pulses: outgoing pulses, or
    returns that the system itself saw as single. Raises when no waveform is usable."""
    widths = [width_above_minimum(w) for w in waveforms if len(w) >= min_samples and np.ptp(w) > 0]
    if not widths:
        raise ValueError("no usable waveform to measure the system pulse width")
    return float(np.median(widths))


def recorded_pulse_fwhm_ps(pulses: PulseBatch) -> tuple[float, str] | None:
    """The system pulse FWHM (ps) of a file where it records the pulse, and from what: the median width of
    its outgoing waveforms (PulseWaves), else of the pulses its system saw as single returns (LAS); None
    where it records neither."""
    if pulses.outgoing is not None and pulses.outgoing.size:
        rows = [i for i in range(len(pulses)) if pulses.outgoing_offsets[i + 1] - pulses.outgoing_offsets[i] > 4]
        if rows:
            width = median_pulse_fwhm([pulses.outgoing_samples(i) for i in rows])
            spacing = float(np.median(pulses.outgoing_spacing_ps[rows]))
            if np.isfinite(width) and width > 0:
                return width * spacing, "outgoing waveforms"
    single = np.flatnonzero(np.diff(pulses.return_offsets) == 1)
    if single.size == 0:
        return None
    width = median_pulse_fwhm([pulses.pulse_samples(i) for i in single])
    # a file with outgoing waveforms none of which measures says so too (it was always said this way)
    source = "outgoing waveforms" if pulses.outgoing is not None and pulses.outgoing.size else "single returns"
    return width * float(np.median(pulses.sample_spacing_ps[single])), source


def csv_pulse_fwhm_ps(outgoing, spacing_ps: float = NEON_SAMPLE_SPACING_PS) -> float:
    """The system pulse FWHM (ps) of a NEON-layout CSV's outgoing pulses (fwcore.io.neon.CsvWaveforms): the
    median half-height width of the valid samples."""
    return median_pulse_fwhm([y[v] for y, v in zip(outgoing.samples, outgoing.valid)]) * spacing_ps


@dataclasses.dataclass(frozen=True)
class PulseWidthEstimate:
    """The system pulse FWHM measured on the waveforms themselves, and on how many."""

    fwhm_samples: float
    n_waveforms: int  # isolated single echoes measured
    n_candidates: int  # waveforms looked at


SINGLE_ECHO_SNR = 20.0  # a peak this far above the noise has a well-defined half height
SINGLE_ECHO_OUTSIDE = 0.1  # of the peak: a sample outside the echo's lobe above this is another echo
MEASURE_SMOOTHING = 1.0  # samples; removed again from the width in quadrature
SINGLE_ECHO_QUANTILE = 20.0


def single_echo_fwhm(samples: np.ndarray, valid: np.ndarray) -> float | None:
    """The FWHM (samples) of a waveform's echo if it holds one strong, isolated echo with a single maximum
    (fwcore.instrument.peak.isolated_lobe), else None."""
    smoothed, noise, level = smoothed_noise_baseline(samples, valid, MEASURE_SMOOTHING)
    signal = np.where(valid, smoothed - level, 0.0)
    peak = int(np.argmax(signal))
    lobe = isolated_lobe(signal, peak, SINGLE_ECHO_SNR * noise, SINGLE_ECHO_OUTSIDE)
    if lobe is None:
        return None
    lo, hi = lobe
    if local_maxima(signal[lo:hi + 1]) != 1:
        return None  # a shoulder or a second peak: not a single echo
    width = width_above_minimum(signal[lo - 1:hi + 2])
    corrected = width * width - (2.0 * SQRT_2LN2 * MEASURE_SMOOTHING) ** 2
    return math.sqrt(corrected) if corrected > 0 else None


def estimate_pulse_fwhm(waveforms, valid=None, min_waveforms: int = 5) -> PulseWidthEstimate:
    """The system pulse FWHM (samples) from the waveforms alone, where no outgoing pulse or system
    return says it: the median half-height width of the strong echoes that stand alone in their
    waveform (one local maximum, SNR >= 20, the record's edges clear), at their 20th percentile:
    targets (slopes, canopy) only ever widen an echo, so the narrow ones are nearest the system's
    own response (NEON: 18.7 ns against 15.2 ns outgoing and 15.9 ns impulse response; Leica:
    10.3 ns against 11.0 ns from its single returns). Raises when fewer than min_waveforms qualify."""
    widths = []
    for i, y in enumerate(waveforms):
        y = np.ascontiguousarray(y, dtype=np.float64)
        v = np.ones(y.size, bool) if valid is None else np.ascontiguousarray(valid[i], dtype=bool)
        if y.size < 8 or not np.isfinite(y[v]).all() or v.sum() < 8:
            continue
        width = single_echo_fwhm(y, v)
        if width is not None:
            widths.append(width)
    if len(widths) < min_waveforms:
        raise ValueError(f"only {len(widths)} of {len(waveforms)} waveforms hold an isolated strong echo "
                         f"(need {min_waveforms}) to measure the system pulse width")
    return PulseWidthEstimate(float(np.percentile(widths, SINGLE_ECHO_QUANTILE)), len(widths), len(waveforms))
