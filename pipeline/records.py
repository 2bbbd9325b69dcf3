"""The records that cross the pipeline's stage boundaries, defined once.

    plan (a worker, per file) -> ReadTask -> read -> PulseRange -> decompose -> DecomposedRange -> geolocate
    -> GeolocatedRange -> write range -> RangePart -> assemble per file
    any stage -> Rejection -> rejected/
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import SystemPulse
from fwcore.engine.records import BatchDecomposition
from fwcore.io import PulseBatch
from fwcore.io.records import PointRange


@dataclasses.dataclass(frozen=True)
class InputFile:
    """One input as planned: where it is, the name its outputs carry, what its time stamps mean, what its
    plan measured of its system pulse."""

    path: str
    name: str  # the input's file name, as the tables' source_file
    stem: str  # unique among the run's inputs: names its part files and per-file outputs
    pulse: SystemPulse  # what the plan measured of the file's system pulse (fwcore.instrument.measure)
    adjusted_standard_gps_time: bool  # LAS global encoding bit 0: gps_time is GPS seconds - 1e9, else week seconds
    crs_wkt: str | None = None  # the CRS every output writes (fwcore.io.formats.input_crs: --crs, else the file's)
    crs_source: str = ""  # where it came from
    crs_named: bool = False  # an EPSG code, a WKT record or --crs; not only a unit, nor nothing
    # the forest metrics' settings (fwcore.metrics.waveform.MetricSettings fields) where the file's products give
    # them (a GEDI L1B's L2A beside it), and from where; None: the defaults for its pulse
    metric_settings: dict | None = None
    metric_settings_source: str = ""

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "pulse": self.pulse.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> "InputFile":
        d = dict(d)
        pulse = d.pop("pulse") if "pulse" in d else d.pop("system")  # "system": a plan an earlier version wrote
        return cls(**d, pulse=SystemPulse.from_dict(pulse))


@dataclasses.dataclass(frozen=True)
class ReadTask:
    """plan -> read: a range of a file."""

    source: InputFile
    point_range: PointRange

    @property
    def start(self) -> int:
        return self.point_range.start

    @property
    def label(self) -> str:
        """The range for a person (logs, errors): its input and points; never the task's repr, which holds the
        file's system response."""
        return f"{self.source.name} points {self.point_range.start}-{self.point_range.stop}"


class Rejection(NamedTuple):
    """The dead letter: a pulse (or a whole range or file, pulse_id -1) that leaves unprocessed, and why."""

    source_file: str
    stem: str  # the input's unique output name
    range_start: int  # -1 for a whole file
    pulse_id: int
    stage: str  # open | read | decompose | geolocate | write
    reason: str


@dataclasses.dataclass(frozen=True)
class PulseRange:
    """read -> decompose: a range's pulses (those whose packet could not be read are Rejections)."""

    task: ReadTask
    pulses: PulseBatch


@dataclasses.dataclass(frozen=True)
class DecomposedRange:
    """decompose -> geolocate: the engine's result for a range's pulses."""

    task: ReadTask
    pulses: PulseBatch
    config: DecompositionConfig  # the run's method (the file's pulse: task.source.pulse)
    result: BatchDecomposition


@dataclasses.dataclass(frozen=True)
class GeolocatedRange:
    """geolocate -> write: one range's outputs as tables and arrays."""

    task: ReadTask
    echoes: pa.Table  # one row per echo, kept and spurious
    pulses: pa.Table  # one row per decomposed pulse
    cloud: dict[str, np.ndarray]  # kept echoes, geolocated (fwcore.pulses.decomposed_echoes)
    views: dict[str, np.ndarray] | None  # for MCAP: per pulse raw samples, fitted model, echoes


class RangePart(NamedTuple):
    """write -> assemble: where one range's point cloud and MCAP parts are (empty when not written)."""

    stem: str
    source_path: str
    range_start: int
    las: str
    mcap: str
    adjusted_standard_gps_time: bool
