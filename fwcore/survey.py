"""What a run derives around the decomposition: a file's system pulse width, the fitted model's samples.

Plain functions over the reader's and the engine's records, so that the
pipeline's stages only call them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fwcore.decompose import BatchDecomposition
from fwcore.io import PointRange, read_pulses
from fwcore.model import waveform_model
from fwcore.pulses import system_pulse_fwhm_ps

PULSE_WIDTH_POINTS = 5000  # the head of a file that measures its pulse width: fixed by the file, not the range size


def file_pulse_fwhm_ps(path: str | Path, point_count: int, fallback_ps: float,
                       head_points: int = PULSE_WIDTH_POINTS) -> float:
    """The file's system pulse FWHM (ps) from the first `head_points` records: their recorded outgoing
    waveforms (PulseWaves) or single-return pulses (LAS); `fallback_ps` for a file without any."""
    if point_count <= 0:
        return fallback_ps
    try:
        return system_pulse_fwhm_ps(read_pulses(PointRange(str(path), 0, min(point_count, head_points))))
    except ValueError:
        return fallback_ps


def model_samples(result: BatchDecomposition, sample_offsets: np.ndarray) -> np.ndarray:
    """Each decomposed pulse's fitted model at its sample times, flat like the samples (0 where not decomposed)."""
    model = np.zeros(int(sample_offsets[-1]), dtype=np.float32)
    for i in np.flatnonzero(result.status == 0):
        lo, hi = sample_offsets[i], sample_offsets[i + 1]
        e_lo, e_hi = result.echo_offsets[i], result.echo_offsets[i + 1]
        model[lo:hi] = waveform_model(np.arange(hi - lo), result.background[i], result.amplitude[e_lo:e_hi],
                                      result.position[e_lo:e_hi], result.sigma[e_lo:e_hi], result.alpha[e_lo:e_hi])
    return model
