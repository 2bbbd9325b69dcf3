"""The truth of a simulated flight (`fwl simulate`): its echoes as a Parquet table beside the LAS."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Iterable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.io.writer import WaveformLasWriter
from fwcore.studies.simulate import SceneConfig, SensorConfig, sensor_position, simulate_chunks

TRUTH_METADATA_KEY = b"fwlidar.simulation"


@dataclasses.dataclass(frozen=True)
class WrittenFlight:
    """What write_flight wrote."""

    las: Path
    truth: Path
    n_pulses: int
    n_returns: int  # the system's returns: the file's points
    n_echoes: int  # true echoes: the truth's rows
    trajectory: Path | None = None  # the scanner's positions: gps_time, x, y, z
    calibration: Path | None = None  # a patch of known reflectance (radiometric scenes)


def truth_path(las_path: str | Path) -> Path:
    """sim.las -> sim.truth.parquet"""
    las_path = Path(las_path)
    return las_path.with_name(las_path.stem + ".truth.parquet")


def trajectory_path(las_path: str | Path) -> Path:
    """sim.las -> sim.trajectory.csv"""
    las_path = Path(las_path)
    return las_path.with_name(las_path.stem + ".trajectory.csv")


def calibration_path(las_path: str | Path) -> Path:
    """sim.las -> sim.calibration.json"""
    las_path = Path(las_path)
    return las_path.with_name(las_path.stem + ".calibration.json")


TRAJECTORY_RATE_HZ = 1000.0  # a fast INS's rate ...
TRAJECTORY_KNOTS = 20_000  # ... or faster, for a short flight's climb: linear interpolation stays within 0.1 mm


def write_trajectory(path: str | Path, n_pulses: int, scene: SceneConfig) -> Path:
    """The scanner's positions during the flight (and 10 ms either side) as CSV gps_time, x, y, z."""
    duration = n_pulses / scene.pulse_rate_hz
    rate = min(scene.pulse_rate_hz, max(TRAJECTORY_RATE_HZ, TRAJECTORY_KNOTS / duration))
    times = scene.start_gps_time + np.arange(-0.01, duration + 0.01 + 0.5 / rate, 1.0 / rate)
    xyz = sensor_position(times, scene)
    np.savetxt(path, np.column_stack([times, xyz]), delimiter=",", header="gps_time,x,y,z", comments="",
               fmt=("%.6f", "%.4f", "%.4f", "%.4f"))
    return Path(path)


def write_calibration_reference(path: str | Path, n_pulses: int, scene: SceneConfig) -> Path:
    """The scene's calibration patch as --calibration-reference reads it: {"bbox": [...], "reflectance": R}
    (with the beam divergence the scene was flown with, which the LAS cannot record)."""
    end = sensor_position(np.array([scene.start_gps_time + n_pulses / scene.pulse_rate_hz]), scene)[0, 0]
    value = {"bbox": [0.0, scene.patch_y_m[0], float(end), scene.patch_y_m[1]],
             "reflectance": scene.patch_reflectance, "beam_divergence_mrad": scene.beam_divergence_mrad}
    Path(path).write_text(json.dumps(value, indent=1) + "\n")
    return Path(path)


def write_flight(output: str | Path, n_pulses: int, sensor: SensorConfig, scene: SceneConfig, seed: int,
                 layout: str = "las13-wdp", chunks: Iterable | None = None,
                 extra_meta: dict | None = None) -> WrittenFlight:
    """Simulate a flight into `output` (and its packets) and its truth beside it, one chunk of pulses in
    memory at a time (fwcore.studies.simulate.CHUNK_PULSES), whatever n_pulses. `chunks`: another scene's
    chunks of the same flight (the forest's), `extra_meta` what it adds to the truth's metadata."""
    output = Path(output)
    n_returns = n_echoes = 0
    if chunks is None:
        chunks = simulate_chunks(n_pulses, sensor, scene, seed, source_file=output.name)
    with WaveformLasWriter(output, layout) as las, \
            TruthWriter(truth_path(output), sensor, scene, seed, extra_meta) as truth:
        for chunk in chunks:
            las.write(chunk.pulses, bits=sensor.bits)
            truth.write(chunk.truth)
            n_returns += chunk.pulses.return_xyz.shape[0]
            n_echoes += chunk.truth["time_ps"].size
            del chunk  # before the next is simulated: one chunk in memory, not two
    trajectory = write_trajectory(trajectory_path(output), n_pulses, scene)
    calibration = (write_calibration_reference(calibration_path(output), n_pulses, scene) if scene.radiometry
                   else None)
    return WrittenFlight(output, truth.path, n_pulses, n_returns, n_echoes, trajectory, calibration)


class TruthWriter:
    """The truth table, chunk by chunk (a row group each), with the sensor, scene and seed in its metadata.
    If the writing fails, the partial table is removed."""

    def __init__(self, path: str | Path, sensor: SensorConfig, scene: SceneConfig, seed: int,
                 extra_meta: dict | None = None) -> None:
        self.path = Path(path)
        self._meta = {"sensor": dataclasses.asdict(sensor), "scene": dataclasses.asdict(scene), "seed": seed,
                      **(extra_meta or {})}
        self._writer: pq.ParquetWriter | None = None

    def __enter__(self) -> "TruthWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._writer is not None:
            self._writer.close()
        if exc_type is not None:
            self.path.unlink(missing_ok=True)

    def write(self, truth: dict[str, np.ndarray]) -> None:
        table = pa.table({k: (pa.array(v.tolist(), pa.string()) if v.dtype == object else v)
                          for k, v in truth.items()})
        table = table.replace_schema_metadata({TRUTH_METADATA_KEY: json.dumps(self._meta).encode()})
        if self._writer is None:
            self._writer = pq.ParquetWriter(self.path, table.schema)
        self._writer.write_table(table)

