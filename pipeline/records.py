"""The records that cross the pipeline's stage boundaries, defined once."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from fwcore.io.records import PointRange


class ReadTask(NamedTuple):
    """plan -> read: a range of a file, and the system pulse FWHM measured for that file."""

    point_range: PointRange
    system_pulse_fwhm_ps: float


class RejectedPulse(NamedTuple):
    """Anything that leaves the dataflow unprocessed: a pulse (or a whole file, pulse_id -1) and why."""

    source_file: str
    pulse_id: int
    stage: str  # open | read | decompose
    reason: str


@dataclasses.dataclass(frozen=True)
class DecomposedBatch:
    """decompose + geolocate -> sinks: one range's results as tables, plus what the per-file sinks need."""

    source_file: str  # the input's name
    source_path: str  # where the input is, for the LAS sink's header template
    range_start: int  # first point of the range: names the part files
    echoes: pa.Table  # one row per echo, kept and spurious
    pulses: pa.Table  # one row per decomposed pulse
    cloud: dict[str, np.ndarray]  # kept echoes, geolocated (fwcore.pulses.decomposed_echoes)
    views: dict[str, np.ndarray] | None = None  # for MCAP: per pulse raw samples, fitted model, echoes
