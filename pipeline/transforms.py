"""The Beam transforms: each a thin adapter over a fwcore function.

    input paths -> PlanRanges -> Reshuffle -> ReadPulses -> Decompose -> Geolocate -> sinks -> Done
                                                                                \\-> rejected/

Rejections travel in the main stream as RejectedPulse records, which every
stage passes through untouched, and are split off by type at the sinks; all
sinks join in one last step. Tagged outputs would read better, but Beam
2.77's Dask runner hands a tagged output's consumer every output of the
ParDo, and computes only the graph's last step: this shape runs unchanged on
every runner.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

import apache_beam as beam
import numpy as np
from apache_beam.metrics import Metrics

from fwcore.config import DecompositionConfig
from fwcore.decompose import STATUS_REASONS, BatchDecomposition, decompose_batch
from fwcore.io import PointRange, PulseBatch, plan_point_ranges, read_pulses
from fwcore.io.writer import write_point_cloud
from fwcore.pulses import decomposed_echoes, echo_positions, pulse_waveforms, system_pulse_fwhm_ps
from pipeline.outputs import InputNames
from pipeline.records import DecomposedBatch, ReadTask, RejectedPulse
from pipeline.sinks import write_mcap, write_part
from pipeline.tables import REJECTED_SCHEMA, pulse_tables

LOG = logging.getLogger("fwl")
NAMESPACE = "fwl"
PULSE_WIDTH_POINTS = 5000


# ---------------------------------------------------------------- plan

class _PlanFile(beam.DoFn):
    def __init__(self, config: DecompositionConfig, points_per_range: int, limit: int | None, names: InputNames):
        self.config, self.points_per_range, self.limit, self.names = config, points_per_range, limit, names

    def process(self, path: str):
        try:
            ranges = plan_point_ranges(path, self.points_per_range)
            fwhm = self.config.system_pulse_fwhm_ps
            if fwhm is None:
                fwhm = self._measured_pulse_fwhm(ranges)
        except (OSError, ValueError) as err:
            Metrics.counter(NAMESPACE, "files_rejected").inc()
            yield RejectedPulse(self.names.name(path), -1, "open", str(err))
            return
        remaining = self.limit
        for r in ranges:
            if remaining is not None:
                if remaining <= 0:
                    break
                r = dataclasses.replace(r, max_pulses=min(remaining, r.n_pulses))
                remaining -= r.max_pulses
            yield ReadTask(r, fwhm)

    def _measured_pulse_fwhm(self, ranges: list[PointRange]) -> float:
        """The file's pulse width from the single-return pulses of its first PULSE_WIDTH_POINTS points
        (fixed by the file, not by the range size); the configured default without any."""
        if not ranges:
            return self.config.pulse_fwhm_ps()
        head = PointRange(ranges[0].path, 0, min(ranges[-1].stop, PULSE_WIDTH_POINTS))
        try:
            return system_pulse_fwhm_ps(read_pulses(head))
        except ValueError:
            return self.config.pulse_fwhm_ps()


@dataclasses.dataclass
class PlanRanges(beam.PTransform):
    """Input paths (expanded by the driver) -> ReadTasks (a few thousand pulses each), or a RejectedPulse
    for an unreadable file."""

    config: DecompositionConfig
    points_per_range: int = 5000
    limit: int | None = None
    names: InputNames = InputNames({}, {})

    def expand(self, paths):
        return paths | "PlanFile" >> beam.ParDo(_PlanFile(self.config, self.points_per_range, self.limit, self.names))


# ---------------------------------------------------------------- read

class ReadPulses(beam.DoFn):
    """ReadTask -> (PulseBatch, pulse FWHM); pulses whose packet cannot be read -> rejected."""

    def __init__(self, names: InputNames = InputNames({}, {})):
        self.names = names
        self.read = Metrics.counter(NAMESPACE, "pulses_read")
        self.rejected = Metrics.counter(NAMESPACE, "pulses_rejected")

    def process(self, task: ReadTask | RejectedPulse):
        if isinstance(task, RejectedPulse):
            yield task
            return
        pulses = read_pulses(task.point_range)
        name = self.names.name(pulses.source_file)
        self.read.inc(len(pulses) + len(pulses.rejected))
        self.rejected.inc(len(pulses.rejected))
        for pulse_id, reason in pulses.rejected:
            yield RejectedPulse(name, int(pulse_id), "read", reason)
        if len(pulses):
            yield pulses, task.system_pulse_fwhm_ps, task.point_range.start


# ---------------------------------------------------------------- decompose

class Decompose(beam.DoFn):
    """(PulseBatch, FWHM, range start) -> (..., BatchDecomposition): the batched numba engine, one call per range.

    setup() compiles the kernels once per worker (from numba's cache when warm).
    """

    def __init__(self, config: DecompositionConfig, names: InputNames = InputNames({}, {})):
        self.config, self.names = config, names
        self.decomposed = Metrics.counter(NAMESPACE, "pulses_decomposed")
        self.rejected = Metrics.counter(NAMESPACE, "pulses_rejected")

    def setup(self):
        from fwcore.decompose import WaveformBatch
        warm = WaveformBatch.from_waveforms([np.r_[np.zeros(8), 50.0, 100.0, 50.0, np.zeros(8)]], 1000.0, [0])
        decompose_batch(warm, self.config.replace(generations=1), threads=1)

    def process(self, element):
        if isinstance(element, RejectedPulse):
            yield element
            return
        pulses, fwhm, start = element
        config = self.config.replace(system_pulse_fwhm_ps=fwhm)
        began = time.perf_counter()
        # one thread per worker: Beam's workers are the parallelism; results do not depend on it
        result = decompose_batch(pulse_waveforms(pulses, config.seed), config, threads=1)
        seconds = time.perf_counter() - began
        name = self.names.name(pulses.source_file)
        ok = result.status == 0
        self.decomposed.inc(int(ok.sum()))
        self.rejected.inc(int((~ok).sum()))
        for i in np.flatnonzero(~ok):
            yield RejectedPulse(name, int(pulses.pulse_id[i]), "decompose", STATUS_REASONS[result.status[i]])
        LOG.info("%s points %d+: %d pulses decomposed, %d rejected, %.1f pulses/s", name, start, ok.sum(),
                 (~ok).sum(), len(pulses) / max(seconds, 1e-9))
        yield pulses, config, start, result


# ---------------------------------------------------------------- geolocate

def _waveform_views(pulses: PulseBatch, result: BatchDecomposition) -> dict[str, np.ndarray]:
    """What the MCAP sink needs per pulse, as compact arrays (JSON is made one message at a time when writing)."""
    model = np.zeros(pulses.samples.size, dtype=np.float32)
    for i in range(len(pulses)):
        w = result.waveform(i)
        lo, hi = pulses.sample_offsets[i], pulses.sample_offsets[i + 1]
        if not w.status:
            model[lo:hi] = w.model(np.arange(hi - lo))
    owner = result.echo_waveform
    spacing = pulses.sample_spacing_ps
    return {"pulse_id": pulses.pulse_id, "gps_time": pulses.gps_time, "sample_spacing_ps": spacing,
            "sample_offsets": pulses.sample_offsets, "raw": pulses.samples.astype(np.float32), "model": model,
            "echo_offsets": result.echo_offsets, "echo_time_ps": result.position * spacing[owner],
            "echo_amplitude": result.amplitude, "echo_fwhm_ps": result.fwhm * spacing[owner],
            "echo_reject": result.reject}


class Geolocate(beam.DoFn):
    """Place every echo along its beam and build the output tables of one range."""

    def __init__(self, with_views: bool, names: InputNames = InputNames({}, {})):
        self.with_views, self.names = with_views, names
        self.kept = Metrics.counter(NAMESPACE, "echoes_kept")
        self.spurious = Metrics.counter(NAMESPACE, "echoes_spurious")

    def process(self, element):
        if isinstance(element, RejectedPulse):
            yield element
            return
        pulses, config, start, result = element
        xyz = echo_positions(pulses, result)
        name = self.names.name(pulses.source_file)
        echoes, table = pulse_tables(name, pulses, result, config, xyz, result.status == 0)
        cloud = decomposed_echoes(pulses, result, xyz)
        n_kept = int((result.reject == 0).sum())
        self.kept.inc(n_kept)
        self.spurious.inc(int(result.reject.size - n_kept))
        yield DecomposedBatch(name, pulses.source_file, start, echoes, table, cloud,
                              _waveform_views(pulses, result) if self.with_views else None)


# ---------------------------------------------------------------- sinks

@dataclasses.dataclass
class WriteTables(beam.PTransform):
    """Echo and pulse tables as Parquet part files, one per range, under echoes/ and pulses/."""

    output: str
    names: InputNames = InputNames({}, {})

    def expand(self, batches):
        def write(batch: DecomposedBatch):
            name = f"{self.names.stem(batch.source_file)}-{batch.range_start:012d}"
            write_part(batch.echoes, Path(self.output) / "echoes", name)
            write_part(batch.pulses, Path(self.output) / "pulses", name)
            return batch.source_file, batch.echoes.num_rows

        return batches | "WriteParts" >> beam.Map(write)


def _concat_cloud(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    cloud = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    # a deterministic order whatever the order ranges arrived in: time, then pulse, then return
    order = np.lexsort((cloud["return_number"], cloud["pulse_id"], cloud["gps_time"]))
    return {k: v[order] for k, v in cloud.items()}


@dataclasses.dataclass
class WritePerFile(beam.PTransform):
    """Per input file: las/<name>.las (or .laz) and mcap/<name>.mcap. Holds one file's kept echoes at a time."""

    output: str
    formats: frozenset[str]
    laz: bool = False
    names: InputNames = InputNames({}, {})

    def expand(self, batches):
        def key(batch: DecomposedBatch):
            return batch.source_file, (batch.source_path, batch.cloud, batch.views)

        def write(item):
            name, parts = item
            parts = list(parts)
            cloud = _concat_cloud([p[1] for p in parts])
            stem = self.names.stem(name)
            if "las" in self.formats:
                suffix = ".laz" if self.laz else ".las"
                write_point_cloud(Path(self.output) / "las" / f"{stem}{suffix}", parts[0][0], cloud)
            if "mcap" in self.formats:
                write_mcap(Path(self.output) / "mcap" / f"{stem}.mcap", cloud, [p[2] for p in parts])
            return name

        return batches | "KeyByFile" >> beam.Map(key) | "GroupByFile" >> beam.GroupByKey() | "Write" >> beam.Map(write)


@dataclasses.dataclass
class WriteRejected(beam.PTransform):
    """rejected/<name>.parquet: source_file, pulse_id, stage, reason, sorted."""

    output: str
    names: InputNames = InputNames({}, {})

    def expand(self, rejected):
        def write(item):
            name, rows = item
            rows = sorted(rows, key=lambda r: (r.pulse_id, r.stage))
            import pyarrow as pa
            table = pa.table({c: [getattr(r, c) for r in rows] for c in REJECTED_SCHEMA.names}, schema=REJECTED_SCHEMA)
            write_part(table, Path(self.output) / "rejected", self.names.stem(name))
            return name, len(rows)

        return (rejected | "KeyByFile" >> beam.Map(lambda r: (r.source_file, r))
                | "GroupByFile" >> beam.GroupByKey() | "Write" >> beam.Map(write))


@dataclasses.dataclass
class DecomposeFlight(beam.PTransform):
    """The whole dataflow, from file patterns to written outputs."""

    config: DecompositionConfig
    output: str
    formats: frozenset[str]
    points_per_range: int = 5000
    limit: int | None = None
    laz: bool = False
    names: InputNames = InputNames({}, {})  # each input's name and output stem (pipeline.outputs)

    def expand(self, paths):
        batches = (paths
                   | "PlanRanges" >> PlanRanges(self.config, self.points_per_range, self.limit, self.names)
                   | "Reshuffle" >> beam.Reshuffle()
                   | "ReadPulses" >> beam.ParDo(ReadPulses(self.names))
                   | "Decompose" >> beam.ParDo(Decompose(self.config, self.names))
                   | "Geolocate" >> beam.ParDo(Geolocate("mcap" in self.formats, self.names)))
        decomposed = batches | "Decomposed" >> beam.Filter(lambda e: isinstance(e, DecomposedBatch))
        rejected = batches | "Rejected" >> beam.Filter(lambda e: isinstance(e, RejectedPulse))
        written = [rejected | "WriteRejected" >> WriteRejected(self.output, self.names)]
        if "parquet" in self.formats:
            written.append(decomposed | "WriteTables" >> WriteTables(self.output, self.names))
        if self.formats & {"las", "mcap"}:
            written.append(decomposed | "WritePerFile" >> WritePerFile(self.output, self.formats, self.laz, self.names))
        return (tuple(written) | "AllWritten" >> beam.Flatten()
                | "Done" >> beam.combiners.Count.Globally())
