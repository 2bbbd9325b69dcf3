"""The pulse record: what the reader hands on, one batch of pulses of one file, columnar."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fwcore.records import WaveformBatch
from fwcore.preprocess import median_pulse_fwhm
from fwcore.rng import pulse_seed


@dataclasses.dataclass(frozen=True)
class PulseBatch:
    """Pulses of one file: per pulse (n), their samples (flat) and their system returns (flat)."""

    source_file: str
    pulse_id: np.ndarray  # int64: the packet's byte offset, stable for a pulse of a file
    descriptor_index: np.ndarray  # int16
    gps_time: np.ndarray
    anchor: np.ndarray  # (n, 3) X0, Y0, Z0 of the anchor point (the pulse's lowest return number)
    anchor_location_ps: np.ndarray  # L0: the anchor's return_point_wave_location
    direction: np.ndarray  # (n, 3) x_t, y_t, z_t: metres per ps along the beam
    scan_angle: np.ndarray  # degrees
    point_source_id: np.ndarray
    scan_direction_flag: np.ndarray
    edge_of_flight_line: np.ndarray
    user_data: np.ndarray
    sample_spacing_ps: np.ndarray
    digitizer_gain: np.ndarray
    digitizer_offset: np.ndarray
    bits_per_sample: np.ndarray
    samples: np.ndarray  # float64, flat
    sample_offsets: np.ndarray  # n + 1
    return_xyz: np.ndarray  # (m, 3) the system's own returns
    return_number: np.ndarray
    return_intensity: np.ndarray
    return_location_ps: np.ndarray
    return_offsets: np.ndarray  # n + 1
    rgb: np.ndarray | None = None  # (n, 3) when the points carry colour
    nir: np.ndarray | None = None
    rejected: tuple[tuple[int, str], ...] = ()  # (pulse_id, reason) of pulses that could not be read

    def __len__(self) -> int:
        return self.pulse_id.size

    def pulse_samples(self, i: int) -> np.ndarray:
        return self.samples[self.sample_offsets[i]:self.sample_offsets[i + 1]]

    def single_return_pulse_fwhm_ps(self) -> float:
        """The system pulse FWHM (ps) measured on pulses the system saw as single returns:
        the file does not record it, and the filter and smoothing need it."""
        single = np.flatnonzero(np.diff(self.return_offsets) == 1)
        if single.size == 0:
            raise ValueError(f"{self.source_file}: no single-return pulse to measure the system pulse width")
        width = median_pulse_fwhm([self.pulse_samples(i) for i in single])
        return width * float(np.median(self.sample_spacing_ps[single]))

    def waveforms(self, seed: int) -> WaveformBatch:
        """The engine's input; each pulse's seed comes from the run seed, file name and pulse id."""
        name = Path(self.source_file).name
        return WaveformBatch(
            samples=self.samples, valid=np.ones(self.samples.size, dtype=bool), offsets=self.sample_offsets,
            sample_spacing_ps=self.sample_spacing_ps.astype(np.float64),
            seeds=np.array([pulse_seed(seed, name, int(p)) for p in self.pulse_id], dtype=np.uint64))
