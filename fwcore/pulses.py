"""The one bridge between the formats (fwcore.io) and the engine: pulses -> waveforms, echoes -> points.

    file -> io (PulseBatch) -> pulse_waveforms -> engine -> echo_positions / decomposed_echoes -> sinks
"""

from __future__ import annotations

import numpy as np

from fwcore.engine.records import BatchDecomposition, WaveformBatch
from fwcore.io.geolocate import geolocate
from fwcore.io.records import PulseBatch
from fwcore.rng import pulse_seeds

# LAS class 1, "unclassified", for every echo whatever the sensor: echoes are points the decomposition made and
# nothing classified (an input point's class, ground say, is its own, not that of every echo of its pulse)
UNCLASSIFIED = 1


SIGNAL_THRESHOLD_SD = 3.0  # GEDI L2A's front threshold: the signal starts 3 noise sigmas above the noise mean
SIGNAL_MARGIN_SAMPLES = 40  # kept either side of the signal: the pulse's rise and tail, and noise to fit beside it


def signal_windows(pulses: PulseBatch) -> np.ndarray:
    """Per sample, whether the engine sees it: all of them, except in waveforms whose file records the noise
    (GEDI), where the long noise either side of the signal is set aside: from SIGNAL_MARGIN_SAMPLES before the
    smoothed waveform first rises SIGNAL_THRESHOLD_SD noise sigmas above the noise mean to as many after it last
    does (a GEDI shot's 800 samples hold about 150 of signal; a waveform that never rises keeps them all)."""
    valid = np.ones(pulses.samples.size, dtype=bool)
    if pulses.noise_mean is None or pulses.noise_sd is None:
        return valid
    kernel = np.exp(-0.5 * (np.arange(-12, 13) / 4.0) ** 2)
    kernel /= kernel.sum()
    for i in range(len(pulses)):
        lo, hi = pulses.sample_offsets[i], pulses.sample_offsets[i + 1]
        smoothed = np.convolve(pulses.samples[lo:hi], kernel, mode="same")[12:-12]  # the edges' zeros left out
        above = np.flatnonzero(smoothed > pulses.noise_mean[i] + SIGNAL_THRESHOLD_SD * pulses.noise_sd[i]) + 12
        if above.size:
            valid[lo:hi] = False
            valid[lo + max(above[0] - SIGNAL_MARGIN_SAMPLES, 0):lo + min(above[-1] + SIGNAL_MARGIN_SAMPLES + 1, hi - lo)] = True
    return valid


def pulse_waveforms(pulses: PulseBatch, seed: int) -> WaveformBatch:
    """The engine's input: one waveform per row, seeded from the run seed, the pulse's identity and
    its returning segment (never the file name or the packet offset: every encoding of the data
    draws the same random streams); where the file records the noise, its sigma as the engine's floor and
    only the signal's window valid (signal_windows)."""
    return WaveformBatch(
        samples=pulses.samples, valid=signal_windows(pulses), offsets=pulses.sample_offsets,
        sample_spacing_ps=pulses.sample_spacing_ps.astype(np.float64),
        seeds=pulse_seeds(seed, pulses.pulse_id, pulses.segments() + 256 * pulses.channels()),
        noise_floor=pulses.noise_sd)


def echo_times_ps(pulses: PulseBatch, result: BatchDecomposition, range_offset_ps: float = 0.0) -> np.ndarray:
    """Every echo's time within its packet (ps), in the result's echo order, on the system's range
    reference: its centre's time plus the file's range offset (fwcore.instrument.pulse.SystemPulse: where the
    system places a return against the fitted echo's centre)."""
    return result.position * pulses.sample_spacing_ps[result.echo_waveform] + range_offset_ps


def echo_positions(pulses: PulseBatch, result: BatchDecomposition, range_offset_ps: float = 0.0) -> np.ndarray:
    """Positions (m, 3) of every echo of decomposed pulses, in the result's echo order, at echo_times_ps."""
    owner = result.echo_waveform
    return geolocate(pulses.anchor[owner], pulses.anchor_location_ps[owner], pulses.direction[owner],
                     echo_times_ps(pulses, result, range_offset_ps))


def decomposed_echoes(pulses: PulseBatch, result: BatchDecomposition,
                      positions: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Columns of the kept echoes, geolocated, with return numbers recomputed in time order: what
    fwcore.io.writer.write_point_cloud writes. `positions` are those of every echo, when the caller has them."""
    kept = result.reject == 0
    owner = result.echo_waveform[kept]
    spacing = pulses.sample_spacing_ps[owner]
    xyz = (echo_positions(pulses, result) if positions is None else positions)[kept]
    # echoes are sorted by position within a waveform, so a running count is the return number
    n_kept = np.bincount(owner, minlength=len(result))
    first = np.concatenate([[0], np.cumsum(n_kept)[:-1]])
    return_number = np.arange(owner.size) - first[owner] + 1
    amplitude = result.amplitude[kept]
    columns = {
        "pulse_id": pulses.pulse_id[owner],
        "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
        "gps_time": pulses.gps_time[owner],
        "return_number": return_number,
        "number_of_returns": n_kept[owner],
        # 8-bit digitizers scaled to the 16-bit intensity range
        "intensity": np.clip(np.round(amplitude * 2.0 ** (16 - pulses.bits_per_sample[owner])), 0, 65535),
        "classification": np.full(owner.size, UNCLASSIFIED, np.uint8),
        "scan_angle": pulses.scan_angle[owner],
        "scan_direction_flag": pulses.scan_direction_flag[owner],
        "edge_of_flight_line": pulses.edge_of_flight_line[owner],
        "point_source_id": pulses.point_source_id[owner],
        "user_data": pulses.user_data[owner],
        "channel": pulses.channels()[owner],
        "amplitude": amplitude,
        "echo_width": result.fwhm[kept] * spacing,
        "alpha": result.alpha[kept],
        "echo_energy": result.energy[kept] * spacing,
        "fit_error": result.fit_error[owner],
    }
    if pulses.rgb is not None:
        columns["rgb"] = pulses.rgb[owner]
    if pulses.nir is not None:
        columns["nir"] = pulses.nir[owner]
    return columns
