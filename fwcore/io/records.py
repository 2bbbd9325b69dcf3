"""The pulse record: what the readers hand on, one batch of waveforms of one file, columnar.

A row is one pulse's returning waveform: a LAS pulse has one; of a PulseWaves
pulse's returning channels (RIEGL records a high-power one beside the low-power
one where that saturates) the reader keeps one, its segments joined.
"""

from __future__ import annotations

import dataclasses
import numpy as np

IDENTITY_QUANTUM_M = 1e-4  # anchors are compared at 0.1 mm: finer than any file's coordinate scale


@dataclasses.dataclass(frozen=True)
class PointRange:
    """Records [start, stop) of a file, plus outside points of pulses it owns, minus points of pulses it does not.

    For LAS the records are point records; for PulseWaves, pulse records.
    """

    path: str
    start: int
    stop: int
    extra_points: tuple[int, ...] = ()
    foreign_points: tuple[int, ...] = ()
    n_pulses: int = -1  # pulses this range owns (-1: not planned)
    max_pulses: int | None = None  # read only the first max_pulses of them (a run's --limit)
    problems: tuple[str, ...] = ()  # the file's losses (e.g. truncated records), reported by its first range


@dataclasses.dataclass(frozen=True)
class PulseBatch:
    """Waveforms of one file: per row (n), their samples (flat) and the system's returns (flat, LAS only)."""

    source_file: str
    pulse_id: np.ndarray  # int64: the pulse's identity (pulse_identity), the same in every encoding of the data
    packet_offset: np.ndarray  # int64: where the samples are (LAS packet offset; PulseWaves offset to waves)
    descriptor_index: np.ndarray  # int16
    gps_time: np.ndarray
    anchor: np.ndarray  # (n, 3) X0, Y0, Z0 of the anchor point
    anchor_location_ps: np.ndarray  # L0: the anchor's time after the first sample (LAS return_point_wave_location)
    direction: np.ndarray  # (n, 3) x_t, y_t, z_t: position = anchor + (L0 - t) * direction, t in ps
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
    return_xyz: np.ndarray  # (m, 3) the system's own returns (none in PulseWaves)
    return_number: np.ndarray
    return_intensity: np.ndarray
    return_location_ps: np.ndarray
    return_offsets: np.ndarray  # n + 1
    classification: np.ndarray | None = None  # per row, when the input classifies its pulses or points
    channel: np.ndarray | None = None  # int16 per row: PulseWaves sampling channel (LAS: 0)
    segment: np.ndarray | None = None  # int16 per row: returning segments joined after the first (LAS: 0)
    rgb: np.ndarray | None = None  # (n, 3) when the points carry colour
    nir: np.ndarray | None = None
    outgoing: np.ndarray | None = None  # float64 flat: the recorded outgoing waveform per row, where recorded
    outgoing_offsets: np.ndarray | None = None  # n + 1
    outgoing_spacing_ps: np.ndarray | None = None
    rejected: tuple[tuple[int, str], ...] = ()  # (pulse_id, reason) of pulses that could not be read; -1: no pulse
    # per return: how many returns the system reported for its pulse (LAS number_of_returns), where recorded;
    # more than the file holds where it was clipped to a plot (omitted_returns)
    number_of_returns: np.ndarray | None = None
    # per row: the packet time (ps, like echo times) at which the beam is at the scanner's optical centre, where
    # the file says (PulseWaves with a constant optical-centre-to-anchor offset); NaN or None where it does not
    sensor_location_ps: np.ndarray | None = None
    # per row, where the file records them (GEDI, LVIS): the noise mean and standard deviation of the digitizer,
    # the beam's zenith cosine, the transmitted pulse's extended Gaussian (sigma, its error, gamma, its error;
    # samples) and the quality flags the mission sets
    noise_mean: np.ndarray | None = None
    noise_sd: np.ndarray | None = None
    cos_zenith: np.ndarray | None = None
    transmit_shape: np.ndarray | None = None  # (n, 4)
    stale_return_flag: np.ndarray | None = None
    degrade_flag: np.ndarray | None = None
    # per row: the waveform algorithm the mission's product selected for the shot (GEDI L2A's selected_algorithm,
    # 0: none), whose settings its forest metrics take
    metric_algorithm: np.ndarray | None = None
    # per row: the shot's land cover in the L2A granule beside (land_cover_data/pft_class, region_class; 255: L2A
    # has not the shot), which names its biomass model's stratum (fwcore.metrics.biomass); None: not recorded
    pft_class: np.ndarray | None = None
    region_class: np.ndarray | None = None
    # per row, where the mission numbers its shots (int64): LVIS's file id (LFID) and shot number, GEDI's shot
    # number (lfid None), so its products join by them
    lfid: np.ndarray | None = None
    shot_number: np.ndarray | None = None
    # whose definitions the forest metrics follow: "" GEDI L2A's (fwcore.metrics.waveform), "lvis" LVIS Level 2's
    # (fwcore.metrics.lvis)
    metric_definition: str = ""

    def __len__(self) -> int:
        return self.pulse_id.size

    def pulse_samples(self, i: int) -> np.ndarray:
        return self.samples[self.sample_offsets[i]:self.sample_offsets[i + 1]]

    def return_pulse(self) -> np.ndarray:
        """For each of the system's returns, the row of its pulse."""
        return np.repeat(np.arange(len(self)), np.diff(self.return_offsets))

    def omitted_returns(self) -> np.ndarray:
        """Per pulse, how many returns the system reported that the file does not hold: a file clipped to a
        plot keeps only the returns inside it, and the rest of their pulse's returns say how many there were
        (Leica sample: 21, in 16 pulses). 0 where the file records no count."""
        held = np.diff(self.return_offsets)
        if self.number_of_returns is None or not self.number_of_returns.size:
            return np.zeros(len(self), dtype=np.int64)
        reported = np.zeros(len(self), dtype=np.int64)
        np.maximum.at(reported, self.return_pulse(), self.number_of_returns.astype(np.int64))
        return np.maximum(reported - held, 0)

    def outgoing_samples(self, i: int) -> np.ndarray:
        if self.outgoing is None:
            return np.zeros(0)
        return self.outgoing[self.outgoing_offsets[i]:self.outgoing_offsets[i + 1]]

    def channels(self) -> np.ndarray:
        return self.channel if self.channel is not None else np.zeros(len(self), np.int16)

    def segments(self) -> np.ndarray:
        return self.segment if self.segment is not None else np.zeros(len(self), np.int16)


def pulse_identity(gps_time: np.ndarray, anchor: np.ndarray, target: np.ndarray | None = None,
                   quantum: float = IDENTITY_QUANTUM_M) -> np.ndarray:
    """A 53-bit id per pulse from what the pulse is: its GPS time and anchor (and target, where given),
    coordinates compared in steps of `quantum` (1 for a format's stored integers).

    Pulses equal in all of these (files without time stamps, T = 0) are told
    apart by the order of their records: the k-th repeat hashes k in. Nothing
    of the encoding (packet offsets, descriptor numbering, file name) enters,
    so .las+.wdp, .laz+.wdz and a rewrite give the same ids.
    """
    n = len(gps_time)
    parts = [np.ascontiguousarray(np.asarray(gps_time, dtype=np.float64)).view(np.int64)[:, None],
             np.round(np.asarray(anchor, dtype=np.float64) / quantum).astype(np.int64)]
    if target is not None:
        parts.append(np.round(np.asarray(target, dtype=np.float64) / quantum).astype(np.int64))
    key = np.ascontiguousarray(np.concatenate(parts, axis=1))
    rows = key.view(np.dtype((np.void, key.shape[1] * 8))).ravel()
    _, inverse, counts = np.unique(rows, return_inverse=True, return_counts=True)
    repeat = np.zeros(n, dtype=np.int64)
    if n and counts.max() > 1:  # the k-th record of a repeated key, in record order
        order = np.argsort(inverse, kind="stable")
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        repeat[order] = np.arange(n) - first[inverse[order]]
    h = np.full(n, 0x9E3779B97F4A7C15, dtype=np.uint64)
    for column in (*key.T, repeat):
        h = _mix64(h ^ _mix64(column.astype(np.uint64)))
    # 53 bits: exact as a JavaScript/JSON number (the viewer), still unlikely to collide within a file
    return (h >> np.uint64(11)).astype(np.int64)


def _mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser, vectorised (uint64 arithmetic wraps)."""
    with np.errstate(over="ignore"):
        z = z + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))
