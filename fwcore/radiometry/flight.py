"""A flight line's radiometry: where its ranges come from, its beam divergence, the check of a trajectory
against it, the calibration on a reference patch, and the radiometric columns of a range's echoes.

    file -> file_radiometry (range source, beam divergence) -> range_radiometry per range (fwcore.radiometry.equations)
    driver, before any decomposition: check_flight (trajectory) -> calibrate_on_reference (C_cal)
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from pathlib import Path

import numpy as np

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import SystemPulse
from fwcore.io import PointRange, crs_wkt, read_pulses
from fwcore.io.formats import GEDI_L1B, LVIS_L1B, PULSEWAVES, format_of
from fwcore.io.records import PulseBatch
from fwcore.pulses import echo_positions, echo_times_ps, pulse_waveforms
from fwcore.radiometry.equations import (Calibration, EchoGeometry, RadiometryConfig, calibration_from_samples,
                                         calibration_samples, echo_radiometry, echo_ranges, metric_beam)
from fwcore.radiometry.errors import RadiometryError
from fwcore.radiometry.trajectory import (Trajectory, cached_trajectory, check_trajectory, file_stamp, load_trajectory,
                                          time_system_of)
from fwcore.engine.records import BatchDecomposition

LOG = logging.getLogger("fwl")
CHECK_PULSES = 2000  # the pulses a trajectory is checked against (where they came from)


@dataclasses.dataclass(frozen=True)
class FileRadiometry:
    """What a file gives radiometry: where its ranges come from (or why there are none) and its beam divergence."""

    path: str
    range_source: str  # "scanner position in the file" | "trajectory NAME" | "" (none)
    why_no_range: str  # when range_source is ""
    beam_divergence_mrad: float | None
    beam_divergence_source: str  # option | file | none
    time_system: str  # week | adjusted: the file's GPS times
    crs_wkt: str | None

    def trajectory(self, config: RadiometryConfig) -> Trajectory | None:
        if not self.range_source.startswith("trajectory"):
            return None
        return cached_trajectory(config.trajectory, self.crs_wkt)

    def to_dict(self) -> dict:
        return {"range_source": self.range_source or None, "why_no_range": self.why_no_range or None,
                "beam_divergence_mrad": self.beam_divergence_mrad,
                "beam_divergence_source": self.beam_divergence_source}


def _sample(path: str) -> PulseBatch:
    """A file's first pulses, read once per version of the file (the range source and the trajectory's check)."""
    return _cached_sample(str(path), file_stamp(path))


@functools.lru_cache(maxsize=8)
def _cached_sample(path: str, stamp: tuple[int, int]) -> PulseBatch:
    return read_pulses(PointRange(path, 0, CHECK_PULSES, max_pulses=CHECK_PULSES))


def file_radiometry(path: str, adjusted_standard_gps_time: bool, config: RadiometryConfig) -> FileRadiometry:
    """Where a file's ranges come from: PulseWaves files whose descriptors place the optical centre at a
    constant offset from the anchor (RIEGL, Optech, GeoLas writers) carry it per pulse; otherwise the run's
    trajectory, if any; none where the file's coordinates are not metres. Its beam divergence: the option,
    else the file's scanner record, else none. Once per process and version of the file."""
    return _file_radiometry(str(path), adjusted_standard_gps_time, config, file_stamp(path))


@functools.lru_cache(maxsize=256)
def _file_radiometry(path: str, adjusted_standard_gps_time: bool, config: RadiometryConfig,
                     stamp: tuple[int, int]) -> FileRadiometry:
    name = Path(path).name
    wkt = crs_wkt(path)
    divergence, divergence_source = config.beam_divergence_mrad, "option"
    system = "adjusted" if adjusted_standard_gps_time else "week"
    source, why = "", ""
    if format_of(path) is PULSEWAVES:
        from fwcore.io.pulsewaves import open_pulsewaves

        pw = open_pulsewaves(path)
        if divergence is None:
            known = [s.beam_divergence_mrad for s in pw.scanners.values() if s.beam_divergence_mrad]
            divergence, divergence_source = (known[0], "file") if known else (None, "none")
        sample = _sample(path)
        has_centre = sample.sensor_location_ps is not None and np.isfinite(sample.sensor_location_ps).any()
        system = time_system_of(sample.gps_time)
        if has_centre:
            source = "scanner position in the file"
        else:
            why = f"{name}: its pulse descriptors place the anchor at no constant distance from the scanner"
        if len(sample) and not metric_beam(sample.direction).any():
            source, why = "", f"{name}: its coordinates are not metres (geographic or feet): no range"
    elif divergence is None:
        divergence_source = "none"
    if not source and config.trajectory and not why.endswith("no range"):
        sample = _sample(path)
        if len(sample) and not metric_beam(sample.direction).any():
            why = f"{name}: its coordinates are not metres (geographic or feet): no range"
        else:
            source, why = f"trajectory {Path(config.trajectory).name}", ""
    if not source and not why and format_of(path) in (GEDI_L1B, LVIS_L1B):
        why = (f"{name}: {format_of(path).name}'s coordinates are geographic (degrees): no range per echo; its "
               f"energies are in pulses/")
    if not source and not why:
        why = f"{name}: a LAS file does not record where its scanner was: give --trajectory"
    return FileRadiometry(str(path), source, why, divergence, divergence_source, system, wkt)


def _gps_time_span(path: str) -> np.ndarray:
    """The first and last GPS time of a file's pulses, read a chunk of points at a time."""
    if format_of(path) is PULSEWAVES:
        from fwcore.io.pulsewaves import open_pulsewaves

        pw = open_pulsewaves(path)
        lo, hi = np.inf, -np.inf
        for at in range(0, pw.point_count, 1_000_000):
            t = pw.records(at, at + 1_000_000)["T"] * pw.header.t_scale + pw.header.t_offset
            lo, hi = min(lo, float(t.min())), max(hi, float(t.max()))
        return np.array([lo, hi])
    import laspy

    lo, hi = np.inf, -np.inf
    with laspy.open(path) as las:
        for points in las.chunk_iterator(1_000_000):
            t = np.asarray(points.gps_time)
            if t.size:
                lo, hi = min(lo, float(t.min())), max(hi, float(t.max()))
    return np.array([lo, hi])


def check_flight(path: str, adjusted_standard_gps_time: bool, config: RadiometryConfig) -> FileRadiometry:
    """Before any decomposition: the file's radiometry, its trajectory loaded and checked against it (it covers
    the file's times and stands where the pulses came from). Raises RadiometryError naming the file and the fix."""
    file = file_radiometry(path, adjusted_standard_gps_time, config)
    if file.range_source.startswith("trajectory"):
        trajectory = load_trajectory(config.trajectory, file.crs_wkt, Path(path).name)
        span = _gps_time_span(path)
        if np.all(np.isfinite(span)):
            sample = _sample(path)
            beam = -sample.direction / np.linalg.norm(sample.direction, axis=1)[:, None]
            check_trajectory(trajectory, Path(path).name, file.time_system, np.r_[sample.gps_time, span],
                             sample.anchor, beam)
    return file


def range_radiometry(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray, range_offset_ps: float,
                     file: FileRadiometry, config: RadiometryConfig) -> dict[str, np.ndarray]:
    """The radiometric columns (fwcore.radiometry.equations.echo_radiometry) of every echo of a range, in the engine's order;
    the echo's energy in the instrument's linear units (digitizer gain applied) x ps."""
    owner = result.echo_waveform
    direction = pulses.direction[owner]
    sensor = pulses.sensor_location_ps[owner] if pulses.sensor_location_ps is not None else None
    range_m = echo_ranges(xyz, echo_times_ps(pulses, result, range_offset_ps), direction, pulses.gps_time[owner],
                          sensor if file.range_source.startswith("scanner") else None, file.trajectory(config),
                          file.time_system)
    norm = np.linalg.norm(direction, axis=1)
    beam = -direction / np.where(norm > 0, norm, 1.0)[:, None]
    energy = result.energy * pulses.sample_spacing_ps[owner] * pulses.digitizer_gain[owner]
    geometry = EchoGeometry(xyz, beam, range_m, energy, result.reject == 0)
    return echo_radiometry(geometry, config, file.beam_divergence_mrad)


def single_returns(result: BatchDecomposition) -> np.ndarray:
    """Per echo: kept, and the only kept echo of its pulse."""
    kept = result.reject == 0
    per_pulse = np.bincount(result.echo_waveform[kept], minlength=len(result))
    return kept & (per_pulse[result.echo_waveform] == 1)


@dataclasses.dataclass(frozen=True)
class PatchFile:
    """One input as the calibration reads it: its planned ranges, the run's method and the file's pulse."""

    path: str
    ranges: tuple[PointRange, ...]
    config: DecompositionConfig
    pulse: SystemPulse  # with the range offset that places its echoes
    adjusted_standard_gps_time: bool


def calibrate_on_reference(files: list[PatchFile], config: RadiometryConfig) -> Calibration:
    """C_cal from the reference patch's single returns over every input: the pulses whose strongest sample lies
    in the patch are decomposed (the patch's neighbours make its planes), then each single return inside it with a
    range and a local plane gives one value; their median is C_cal. Raises RadiometryError when the patch holds
    no pulse (before any decomposition) or no usable single return."""
    reference = config.calibration_reference
    relative = dataclasses.replace(config, calibration_constant=None)
    chosen = []
    for f in files:
        for r in f.ranges:
            pulses = read_pulses(r)
            rows = _pulses_in_patch(pulses, reference)
            if rows.size:
                chosen.append((f, _take(pulses, rows)))
    if not chosen:
        names = ", ".join(Path(f.path).name for f in files)
        raise RadiometryError(f"--calibration-reference {','.join(f'{v:g}' for v in reference.bbox)}: no pulse of "
                              f"{names} reaches the patch: give a patch inside the flight's coverage (in the inputs' "
                              "coordinates)")
    samples = [np.zeros(0)]
    for f, pulses in chosen:
        file = file_radiometry(f.path, f.adjusted_standard_gps_time, relative)
        if file.beam_divergence_mrad is None or not file.range_source:  # it cannot tell C_cal (run.check_radiometry)
            continue
        result = decompose_batch(pulse_waveforms(pulses, f.config.seed), f.config, f.pulse, threads=1)
        xyz = echo_positions(pulses, result, f.pulse.range_offset_ps)
        columns = range_radiometry(pulses, result, xyz, f.pulse.range_offset_ps, file, relative)
        samples.append(calibration_samples(columns, xyz, single_returns(result), reference, file.beam_divergence_mrad))
    values = np.concatenate(samples)
    if not np.isfinite(values).any():
        raise RadiometryError(f"--calibration-reference: the patch holds {sum(len(p) for _, p in chosen)} pulses but "
                              "no single return with a range and a local plane: give a patch of open, flat ground")
    return calibration_from_samples(values)


def _pulses_in_patch(pulses: PulseBatch, reference) -> np.ndarray:
    """Rows whose strongest sample (where the surface that dominates them is) lies inside the patch."""
    if not len(pulses):
        return np.zeros(0, np.int64)
    lengths = np.diff(pulses.sample_offsets)
    row = np.repeat(np.arange(len(pulses)), lengths)
    first = np.lexsort((-pulses.samples, row))[pulses.sample_offsets[:-1][lengths > 0]]  # each row's largest
    peak = np.zeros(len(pulses), np.int64)
    peak[lengths > 0] = first - pulses.sample_offsets[:-1][lengths > 0]
    dt = pulses.anchor_location_ps - peak * pulses.sample_spacing_ps
    xyz = pulses.anchor + dt[:, None] * pulses.direction
    return np.flatnonzero(reference.contains(xyz[:, 0], xyz[:, 1]))


def _take(pulses: PulseBatch, rows: np.ndarray) -> PulseBatch:
    """The rows of a batch (waveforms and per-row fields; the system's returns are not needed here)."""
    lengths = np.diff(pulses.sample_offsets)[rows]
    offsets = np.zeros(rows.size + 1, np.int64)
    np.cumsum(lengths, out=offsets[1:])
    samples = np.concatenate([pulses.pulse_samples(int(i)) for i in rows]) if rows.size else np.zeros(0)
    fields = {}
    for field in dataclasses.fields(PulseBatch):
        value = getattr(pulses, field.name)
        if field.name == "samples":
            fields[field.name] = samples
        elif field.name == "sample_offsets":
            fields[field.name] = offsets
        elif field.name in ("return_xyz", "return_number", "return_intensity", "return_location_ps",
                            "number_of_returns"):
            fields[field.name] = value[:0] if isinstance(value, np.ndarray) else value
        elif field.name == "return_offsets":
            fields[field.name] = np.zeros(rows.size + 1, np.int64)
        elif field.name in ("outgoing", "outgoing_offsets", "outgoing_spacing_ps", "rejected"):
            fields[field.name] = None if field.name != "rejected" else ()
        elif isinstance(value, np.ndarray) and value.shape[:1] == (len(pulses),):
            fields[field.name] = value[rows]
        else:
            fields[field.name] = value
    return PulseBatch(**fields)
