"""The truth of a simulated flight (`fwl simulate`): its echoes as a Parquet table beside the LAS."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.simulate import SceneConfig, SensorConfig, SimulatedFlight

TRUTH_METADATA_KEY = b"fwlidar.simulation"


def truth_path(las_path: str | Path) -> Path:
    """sim.las -> sim.truth.parquet"""
    las_path = Path(las_path)
    return las_path.with_name(las_path.stem + ".truth.parquet")


def write_truth(path: str | Path, flight: SimulatedFlight, sensor: SensorConfig, scene: SceneConfig,
                seed: int) -> Path:
    """The truth table, with the sensor, scene and seed in its metadata."""
    table = pa.table({k: (pa.array(v.tolist(), pa.string()) if v.dtype == object else v)
                      for k, v in flight.truth.items()})
    meta = {"sensor": dataclasses.asdict(sensor), "scene": dataclasses.asdict(scene), "seed": seed}
    table = table.replace_schema_metadata({TRUTH_METADATA_KEY: json.dumps(meta).encode()})
    pq.write_table(table, path)
    return Path(path)
