"""A range's work as plain functions, without Beam: the ranges job's one DoFn (transforms.RangeStages) calls
`run_range`, and tests call each stage on arrays.

    read_range(task)              -> PulseRange (or None: nothing readable) + Rejections of unreadable pulses
    decompose_range(item, ...)    -> DecomposedRange + Rejections of pulses not decomposed
    geolocate_range(item, ...)    -> GeolocatedRange: positions, echoes under the ground filtered, radiometry,
                                     the range's tables
    write_range(item, ...)        -> RangePart: the Parquet parts, and the LAS and MCAP parts under parts/
    run_range(task, settings)     -> RangeOutcome: all four in turn; a stage that fails rejects the range
                                     (every pulse it still holds) with the stage and the reason, unless the
                                     machine failed (pipeline.faults): then MachineFault, and nothing rejected
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.io.formats import GEDI_L1B, LVIS_L1B, format_of
from fwcore.metrics.echo_column import FROM_ECHOES, FROM_WAVEFORM, pulse_column_metrics
from fwcore.metrics.biomass import LARGE_FOOTPRINT_FORMATS, ShotBiomass, predict_agbd, shot_strata
from fwcore.metrics.algorithms import AlgorithmPlan
from fwcore.metrics.pulses import batch_metrics
from fwcore.metrics.waveform import WaveformMetrics
from fwcore.radiometry.flight import file_radiometry, range_radiometry
from fwcore.instrument.pulse import SystemPulse, nominal_pulse
from fwcore.io import read_pulses
from fwcore.io.crs import horizontal_metres
from fwcore.io.writer import write_point_cloud
from fwcore.plausibility import CELL_M, filter_under_ground
from fwcore.pulses import decomposed_echoes, echo_positions, pulse_waveforms
from fwcore.radiometry.equations import RadiometryConfig
from fwcore.engine.records import STATUS_REASONS, WaveformBatch, fitted_model
from pipeline.forest_settings import ForestSettings
from pipeline.copc import has_point_cloud_parts
from pipeline.faults import READING, WRITING, MachineFault, machine_fault
from pipeline.geoparquet import write_echo_part
from pipeline.layout import ECHOES, LAS, MCAP, PULSES, part_paths
from pipeline.plan import planned_pulses
from pipeline.records import DecomposedRange, GeolocatedRange, PulseRange, RangePart, ReadTask, Rejection
from pipeline.sinks import remove_parts, write_mcap, write_part
from pipeline.tables import pulse_tables
from pipeline.timing import Laps, log_timing

LOG = logging.getLogger("fwl")
@dataclasses.dataclass(frozen=True)
class RangeSettings:
    """What every range of a run shares: one object, from the driver to the DoFn to these functions."""

    output: str
    config: DecompositionConfig
    formats: frozenset[str]
    radiometry: RadiometryConfig = RadiometryConfig()
    forest: ForestSettings = ForestSettings()  # --stratum, --pulse-metrics (--l2a-algorithms is the plan's)


@dataclasses.dataclass
class RangeOutcome:
    """What a range gave: its part (None when nothing was written), its Rejections, and its counts."""

    part: RangePart | None = None
    rejected: list[Rejection] = dataclasses.field(default_factory=list)
    pulses_read: int = 0
    pulses_decomposed: int = 0
    echoes_kept: int = 0
    echoes_spurious: int = 0

    @property
    def pulses_rejected(self) -> int:
        return sum(1 for r in self.rejected if r.pulse_id >= 0)

    @property
    def problems(self) -> int:  # a range lost whole, or point records the file lacks
        return sum(1 for r in self.rejected if r.pulse_id < 0)


def _rejections(task: ReadTask, pulse_ids, stage: str, reason: str) -> list[Rejection]:
    s = task.source
    return [Rejection(s.name, s.stem, task.start, int(p), stage, reason) for p in pulse_ids]


# ---------------------------------------------------------------- the four stages

def read_range(task: ReadTask) -> tuple[PulseRange | None, list[Rejection]]:
    """A range's pulses; a pulse whose packet cannot be read is a Rejection (pulse_id -1: the file's problems)."""
    pulses = read_pulses(task.point_range)
    rejected = [Rejection(task.source.name, task.source.stem, task.start, int(pulse_id), "read", reason)
                for pulse_id, reason in pulses.rejected]
    return (PulseRange(task, pulses) if len(pulses) else None), rejected


def warm_up(config: DecompositionConfig, pulse: SystemPulse = nominal_pulse()) -> None:
    """Compile the engine's kernels once per worker (from numba's cache when warm)."""
    warm = WaveformBatch.from_waveforms([np.r_[np.zeros(8), 50.0, 100.0, 50.0, np.zeros(8)]], 1000.0, [0])
    decompose_batch(warm, config.replace(generations=1), pulse, threads=1)


def decompose_range(item: PulseRange, config: DecompositionConfig) -> tuple[DecomposedRange, list[Rejection]]:
    """The batched engine, one call a range, with the file's system pulse; a pulse the engine cannot decompose
    (no valid sample, non-finite samples) is a Rejection."""
    source = item.task.source
    began = time.perf_counter()
    # one thread per worker: the workers are the parallelism; results do not depend on it
    result = decompose_batch(pulse_waveforms(item.pulses, config.seed), config, source.pulse, threads=1)
    ok = result.status == 0
    rejected = [Rejection(source.name, source.stem, item.task.start, int(item.pulses.pulse_id[i]), "decompose",
                          STATUS_REASONS[result.status[i]]) for i in np.flatnonzero(~ok)]
    LOG.info("%s points %d+: %d pulses decomposed, %d rejected, %.1f pulses/s", source.name, item.task.start,
             ok.sum(), (~ok).sum(), len(item.pulses) / max(time.perf_counter() - began, 1e-9))
    return DecomposedRange(item.task, item.pulses, config, result), rejected


def waveform_views(pulses, result, model: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """What the MCAP sink needs per pulse, as compact arrays (JSON is made one message at a time when writing);
    `model` the fitted model at every sample where the caller has it (fitted_model)."""
    owner = result.echo_waveform
    spacing = pulses.sample_spacing_ps
    return {"pulse_id": pulses.pulse_id, "gps_time": pulses.gps_time, "sample_spacing_ps": spacing,
            "sample_offsets": pulses.sample_offsets, "raw": pulses.samples.astype(np.float32),
            "model": (fitted_model(result, pulses.sample_offsets) if model is None else model).astype(np.float32),
            "echo_offsets": result.echo_offsets, "echo_time_ps": result.position * spacing[owner],
            "echo_amplitude": result.amplitude, "echo_fwhm_ps": result.fwhm * spacing[owner],
            "echo_reject": result.reject}


def large_footprint(source) -> bool:
    """Whether an input's pulses are large footprints (GEDI, LVIS): their metrics are NASA's, whatever was asked."""
    return format_of(source.path) in (GEDI_L1B, LVIS_L1B)


def range_metrics(item: DecomposedRange, xyz, pulse_metrics: str = FROM_ECHOES):
    """Every pulse's forest metrics, and GEDI's L2A algorithms (each shot's, and every algorithm's with
    --l2a-algorithms all; None elsewhere): a large footprint's (and any with `pulse_metrics` FROM_WAVEFORM) GEDI
    L2A/L2B's on its waveform (fwcore.metrics.algorithms for GEDI, fwcore.metrics.pulses), a small footprint's from
    its echoes (fwcore.metrics.echo_column)."""
    pulses, result, source = item.pulses, item.result, item.task.source
    if source.metric_settings:  # GEDI: each shot's L2A algorithm
        return AlgorithmPlan.from_dict(source.metric_settings).metrics(pulses, result, source.pulse)
    if pulse_metrics == FROM_WAVEFORM or large_footprint(source):
        return batch_metrics(pulses, result, source.pulse), None, None
    return pulse_column_metrics(pulses, result, xyz), None, None


def range_biomass(item: DecomposedRange, metrics: WaveformMetrics, algorithms: np.ndarray | None,
                  every: dict | None, stratum: str | None) -> ShotBiomass:
    """Each large footprint's L4A biomass by its stratum (fwcore.metrics.biomass: the L2A land cover's, else
    `stratum`); GEDI: from the RH of the algorithm L4A would take (AlgorithmPlan.l4a_rh), not L2A's selected."""
    pulses, source = item.pulses, item.task.source
    names, reasons = shot_strata(len(pulses), format_of(source.path).name in LARGE_FOOTPRINT_FORMATS, stratum,
                                 pulses.pft_class, pulses.region_class)
    if not source.metric_settings or algorithms is None or not (names != "").any():
        return predict_agbd(metrics.rh, names, reasons)
    plan = AlgorithmPlan.from_dict(source.metric_settings)  # GEDI: the file's L2A algorithms
    rh, algorithm = plan.l4a_rh(pulses, item.result, source.pulse, names, metrics, algorithms, every)
    return dataclasses.replace(predict_agbd(rh, names, reasons), algorithm=algorithm)


def geolocate_range(item: DecomposedRange, radiometry: RadiometryConfig, with_views: bool,
                    laps: Laps | None = None, stratum: str | None = None,
                    pulse_metrics: str = FROM_ECHOES) -> GeolocatedRange:
    """Every echo placed along its beam (those far under the ground filtered: fwcore.plausibility), its range
    and radiometry computed, every pulse's forest metrics (range_metrics) and, for large footprints, biomass
    (fwcore.metrics.biomass: the L2A land cover's stratum, else `stratum`), the range's tables built; each
    step's time into `laps`."""
    laps = laps or Laps()
    pulses, result, source = item.pulses, item.result, item.task.source
    with laps("geolocate"):
        xyz = echo_positions(pulses, result, source.pulse.range_offset_ps)
        # no kept echo far under the ground its neighbours see: filtered as under_ground, before anything counts it
        filter_under_ground(pulses, result, xyz, CELL_M / horizontal_metres(source.crs_wkt))
    with laps("radiometry"):
        file = file_radiometry(source.path, source.adjusted_standard_gps_time, radiometry)
        columns = range_radiometry(pulses, result, xyz, source.pulse.range_offset_ps, file, radiometry)
    with laps("metrics"):
        metrics, algorithms, every = range_metrics(item, xyz, pulse_metrics)
    with laps("biomass"):
        biomass = range_biomass(item, metrics, algorithms, every, stratum)
    with laps("tables"):
        model = fitted_model(result, pulses.sample_offsets)  # once, for the echoes' widths and the MCAP views
        echoes, table = pulse_tables(source.name, pulses, result, item.config, source.pulse, xyz,
                                     result.status == 0, columns, source.crs_wkt, metrics, algorithms, every, biomass,
                                     model)
    with laps("cloud"):
        cloud = decomposed_echoes(pulses, result, xyz)
        kept = result.reject == 0
        cloud.update({name: values[kept] for name, values in columns.items()})
    with laps("mcap views"):
        views = waveform_views(pulses, result, model) if with_views else None
    return GeolocatedRange(item.task, echoes, table, cloud, views)


def write_range(item: GeolocatedRange, output: str, formats: frozenset[str], calibrated: bool,
                laps: Laps | None = None) -> RangePart:
    """The range's Parquet parts, and its LAS and MCAP parts under parts/: all of them or none; each sink's
    time into `laps`."""
    task, paths, laps = item.task, part_paths(output, item.task), laps or Laps()
    writing = paths[ECHOES]  # the part being written, named by a fault of the machine
    try:
        if "parquet" in formats:
            with laps("write echoes"):
                write_echo_part(item.echoes, paths[ECHOES].parent, paths[ECHOES].stem)
            writing = paths[PULSES]
            with laps("write pulses"):
                write_part(item.pulses, paths[PULSES].parent, paths[PULSES].stem)
        if has_point_cloud_parts(formats):
            writing = paths[LAS]
            with laps("write las"):
                write_point_cloud(paths[LAS], task.source.path, item.cloud, calibrated, task.source.crs_wkt)
        if "mcap" in formats:
            writing = paths[MCAP]
            with laps("write mcap"):
                write_mcap(paths[MCAP], item.cloud, item.views, task.source.adjusted_standard_gps_time,
                           task.source.crs_wkt)
    except Exception as err:
        remove_parts(list(paths.values()))  # a range is written whole or not at all
        fault = machine_fault(err, WRITING, writing, task.label)
        if fault is None or fault is err:
            raise
        raise fault from err
    return RangePart(task.source.stem, task.source.path, task.start,
                     str(paths[LAS]) if has_point_cloud_parts(formats) else "",
                     str(paths[MCAP]) if "mcap" in formats else "", task.source.adjusted_standard_gps_time)


# ---------------------------------------------------------------- a range, all four

def reject_range(task: ReadTask, held, stage: str, reason: str) -> list[Rejection]:
    """Every pulse a failed range still held as a Rejection (those already rejected are not again); one
    Rejection for the range when its pulses are not known yet."""
    where = f"points {task.point_range.start}-{task.point_range.stop}"
    if isinstance(held, PulseRange):
        ids = held.pulses.pulse_id
    elif isinstance(held, DecomposedRange):
        ids = held.pulses.pulse_id[held.result.status == 0]
    elif isinstance(held, GeolocatedRange):
        ids = held.pulses.column("pulse_id").to_numpy()
    else:
        return [Rejection(task.source.name, task.source.stem, task.start, -1, stage,
                          f"{where} ({planned_pulses(task)} pulses): {reason}")]
    return _rejections(task, ids, stage, f"{where}: {reason}")


def run_range(task: ReadTask, settings: RangeSettings) -> RangeOutcome:
    """One range through read, decompose, geolocate and write; an exception in a stage rejects what the range
    still holds, with the stage and the reason, and the other ranges go on."""
    outcome, held, stage, laps = RangeOutcome(), task, "read", Laps()
    try:
        with laps("read"):
            held, rejected = read_range(task)
        outcome.rejected += rejected
        outcome.pulses_read = (len(held.pulses) if held else 0) + sum(1 for r in rejected if r.pulse_id >= 0)
        if held is None:  # nothing left to decompose: the range ends here
            return outcome
        stage = "decompose"
        with laps("decompose"):
            held, rejected = decompose_range(held, settings.config)
        outcome.rejected += rejected
        stage = "geolocate"
        held = geolocate_range(held, settings.radiometry, "mcap" in settings.formats, laps, settings.forest.stratum,
                               settings.forest.pulse_metrics)
        stage = "write"
        outcome.part = write_range(held, settings.output, settings.formats, settings.radiometry.calibrated, laps)
    except MachineFault as fault:  # the machine's, not the pulses': the range fails, nothing is rejected
        LOG.error("%s: %s stopped: %s", task.label, stage, fault.said())
        raise
    except Exception as err:  # noqa: BLE001  any failure of one range must not stop the others
        fault = machine_fault(err, WRITING if stage == "write" else READING,
                              settings.output if stage == "write" else task.source.path, task.label)
        if fault is not None:
            LOG.error("%s: %s stopped: %s", task.label, stage, fault.said())
            raise fault from err
        LOG.error("%s: %s failed: %s: %s", task.label, stage, type(err).__name__, err)
        LOG.debug("%s: %s failed", task.label, stage, exc_info=True)
        outcome.rejected += reject_range(task, None if held is task else held, stage, f"{type(err).__name__}: {err}")
        return outcome
    kept = int(np.count_nonzero(held.echoes.column("kept").to_numpy(zero_copy_only=False)))
    outcome.pulses_decomposed, outcome.echoes_kept = held.pulses.num_rows, kept
    outcome.echoes_spurious = held.echoes.num_rows - kept
    log_timing("range", task.label, laps, pulses=outcome.pulses_decomposed)
    return outcome
