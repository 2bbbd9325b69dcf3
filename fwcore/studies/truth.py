"""The truth of a simulated flight (`fwl simulate`): its echoes as a Parquet table beside the LAS."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.io.writer import WaveformLasWriter
from fwcore.simulate import SceneConfig, SensorConfig, simulate_chunks

TRUTH_METADATA_KEY = b"fwlidar.simulation"


@dataclasses.dataclass(frozen=True)
class WrittenFlight:
    """What write_flight wrote."""

    las: Path
    truth: Path
    n_pulses: int
    n_returns: int  # the system's returns: the file's points
    n_echoes: int  # true echoes: the truth's rows


def truth_path(las_path: str | Path) -> Path:
    """sim.las -> sim.truth.parquet"""
    las_path = Path(las_path)
    return las_path.with_name(las_path.stem + ".truth.parquet")


def write_flight(output: str | Path, n_pulses: int, sensor: SensorConfig, scene: SceneConfig, seed: int,
                 layout: str = "las13-wdp") -> WrittenFlight:
    """Simulate a flight into `output` (and its packets) and its truth beside it, one chunk of pulses in
    memory at a time (fwcore.simulate.CHUNK_PULSES), whatever n_pulses."""
    output = Path(output)
    n_returns = n_echoes = 0
    with WaveformLasWriter(output, layout) as las, TruthWriter(truth_path(output), sensor, scene, seed) as truth:
        for chunk in simulate_chunks(n_pulses, sensor, scene, seed, source_file=output.name):
            las.write(chunk.pulses, bits=sensor.bits)
            truth.write(chunk.truth)
            n_returns += chunk.pulses.return_xyz.shape[0]
            n_echoes += chunk.truth["time_ps"].size
            del chunk  # before the next is simulated: one chunk in memory, not two
    return WrittenFlight(output, truth.path, n_pulses, n_returns, n_echoes)


class TruthWriter:
    """The truth table, chunk by chunk (a row group each), with the sensor, scene and seed in its metadata.
    If the writing fails, the partial table is removed."""

    def __init__(self, path: str | Path, sensor: SensorConfig, scene: SceneConfig, seed: int) -> None:
        self.path = Path(path)
        self._meta = {"sensor": dataclasses.asdict(sensor), "scene": dataclasses.asdict(scene), "seed": seed}
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

