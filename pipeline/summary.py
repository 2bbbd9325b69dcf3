"""run.json: what a run wrote, counted back from its files, beside what made it (settings, versions, each
input's plan) and what it cost (seconds, Beam's metrics).

    count_outputs(output, names)    totals and per-input counts read from echoes/, pulses/ and rejected/
    status_of(counts)               complete, partial or failed, and EXIT_CODES the exit code each means
    summarise(output, ...)          run.json, written last: the mark of a complete run

Exit codes of `fwl run` (see the README): 0 every pulse decomposed; 3 some inputs or pulses rejected,
the rest written; 4 nothing decomposed (every input or pulse rejected); 5 stopped by a fault of the machine
(a full disk, no permission, an I/O error, a lost mount, no memory: pipeline.faults), nothing rejected for it,
rerun with --resume once it is fixed; 2 a usage error (bad option, no such input, an output folder that holds
what is not ours, or that another command is writing), nothing touched; 130 interrupted.
"""

from __future__ import annotations

import dataclasses
import platform
from importlib import metadata
from pathlib import Path

import apache_beam as beam
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

import fwcore
from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import PulseOverrides
from fwcore.io.crs import crs_name
from fwcore.radiometry.equations import RadiometryConfig
from pipeline.layout import ECHOES, PULSES, REJECTED, file_rejected
from pipeline.outputs import list_outputs, read_manifest, with_system_pulse, write_run_json
from pipeline.plan import FilePlan, planned_pulses
from pipeline.rejections import write_empty_rejected
from pipeline.transforms import NAMESPACE

EXIT_OK, EXIT_USAGE, EXIT_PARTIAL, EXIT_NOTHING_DONE, EXIT_MACHINE, EXIT_INTERRUPTED = 0, 2, 3, 4, 5, 130
COUNTS = ("pulses_read", "pulses_decomposed", "pulses_rejected", "files_rejected", "problems", "echoes_kept",
          "echoes_spurious")


def _counts_by_input(directory: Path, columns: list[str], aggregations: list[tuple], derive=None) -> dict[str, dict]:
    """Per input file, the counts and sums of `aggregations` over the tables in `directory`, one table (a
    range's part) at a time: a survey's echo tables, tens of millions of rows, need not fit in memory
    together (read as one dataset, 10M pulses' counts took 1.5 GB; a dataset keeps every part's metadata)."""
    totals: dict[str, dict] = {}
    for path in sorted(directory.glob("*.parquet")):
        table = pq.read_table(path, columns=columns)
        if not table.num_rows:
            continue
        table = derive(table) if derive else table
        for row in table.group_by("source_file").aggregate(aggregations).to_pylist():
            into = totals.setdefault(row.pop("source_file"), {})
            for key, value in row.items():
                into[key] = into.get(key, 0) + int(value or 0)
    return totals


def _rejection_kinds(rejected: pa.Table) -> pa.Table:
    is_file = pc.equal(rejected.column("stage"), "open")
    is_pulse = pc.and_(pc.invert(is_file), pc.greater_equal(rejected.column("pulse_id"), 0))
    return rejected.append_column("is_file", is_file).append_column("is_pulse", is_pulse)


def count_outputs(output: Path, names: list[str],
                  counted: dict[str, dict] | None = None) -> tuple[dict[str, int], dict[str, dict[str, int]]]:
    """Totals and per-input counts read back from what was written, so that they add up by construction.

    A rejected row is a file (stage open), a pulse (pulse_id >= 0), or a problem: a range that failed
    as a whole, or point records the header promises and the file lacks (pulse_id -1). A run that wrote no
    tables (--formats las or mcap) gives `counted`: per input, the pulses decomposed and the echoes its ranges'
    marks counted (pipeline.marks.counts_from_marks), in place of the pulses/ and echoes/ tables'.
    """
    per_pulses = _counts_by_input(output / PULSES, ["source_file"], [("source_file", "count")])
    per_echoes = _counts_by_input(output / ECHOES, ["source_file", "kept"], [("kept", "count"), ("kept", "sum")])
    for name, c in (counted or {}).items():  # the marks' counts, in the tables' terms
        per_pulses[name] = {"source_file_count": c["pulses_decomposed"]}
        per_echoes[name] = {"kept_sum": c["echoes_kept"], "kept_count": c["echoes_kept"] + c["echoes_spurious"]}
    per_rejected = _counts_by_input(output / REJECTED, ["source_file", "stage", "pulse_id"],
                                    [("is_file", "count"), ("is_file", "sum"), ("is_pulse", "sum")], _rejection_kinds)
    per_input = {}
    for name in names:
        decomposed = per_pulses.get(name, {}).get("source_file_count", 0)
        rows = per_rejected.get(name, {})
        files_rejected = int(rows.get("is_file_sum") or 0)
        pulse_rejects = int(rows.get("is_pulse_sum") or 0)
        problems = rows.get("is_file_count", 0) - files_rejected - pulse_rejects
        echo_rows = per_echoes.get(name, {})
        kept = int(echo_rows.get("kept_sum") or 0)
        per_input[name] = {"pulses_read": decomposed + pulse_rejects, "pulses_decomposed": decomposed,
                           "pulses_rejected": pulse_rejects, "files_rejected": files_rejected, "problems": problems,
                           "echoes_kept": kept, "echoes_spurious": echo_rows.get("kept_count", 0) - kept}
    totals = {k: sum(c[k] for c in per_input.values()) for k in COUNTS}
    return totals, per_input


def whole_file_reasons(output: Path, entries: list[dict], per_input: dict[str, dict]) -> dict[str, str]:
    """Per input rejected whole, the first reason its rejected/ rows give (stage open), for run.json and the
    terminal."""
    reasons = {}
    for e in entries:
        if per_input[e["name"]]["files_rejected"]:
            rows = pq.read_table(file_rejected(output, e["stem"]), columns=["stage", "reason"])
            said = [r for s, r in zip(rows.column("stage").to_pylist(), rows.column("reason").to_pylist())
                    if s == "open"]
            if said:
                reasons[e["name"]] = said[0]
    return reasons


def _metric_counts(result) -> dict[str, int]:
    """Beam's counters summed over the steps that increment them (several stages reject pulses)."""
    try:
        counters = result.metrics().query(beam.metrics.MetricsFilter().with_namespace(NAMESPACE))["counters"]
    except Exception:  # some runners (Dask) do not report metrics
        return {}
    totals: dict[str, int] = {}
    for c in counters:
        value = c.committed if c.committed is not None else c.attempted
        totals[c.key.metric.name] = totals.get(c.key.metric.name, 0) + int(value or 0)
    return totals


def beam_metrics(result, files_rejected: int) -> dict[str, int]:
    """Beam's counters, and the files this call's plans rejected (empty where the runner reports none)."""
    metrics = _metric_counts(result) if result is not None else {}
    return {**metrics, "files_rejected": files_rejected} if metrics else {}


def status_of(counts: dict[str, int]) -> str:
    """complete: nothing rejected; partial: some inputs or pulses rejected; failed: nothing decomposed."""
    if not counts["pulses_rejected"] and not counts["files_rejected"] and not counts["problems"]:
        return "complete"
    return "partial" if counts["pulses_decomposed"] else "failed"


EXIT_CODES = {"complete": EXIT_OK, "partial": EXIT_PARTIAL, "failed": EXIT_NOTHING_DONE}


@dataclasses.dataclass(frozen=True)
class JobsDone:
    """What a run's jobs did, for run.json: ranges planned and reused, Beam's metrics, each input's plan."""

    ranges: int | None
    ranges_reused: int | None
    metrics: dict[str, int]
    planned: dict[str, dict]  # input path -> what its plan measured (planned_of), and its radiometry
    calibration: dict | None = None  # C_cal found on a reference patch, how many returns, their spread
    pulses_processed: int | None = None  # the pulses of the ranges this call ran (not those reused): its rate


def planned_of(plan: FilePlan) -> dict:
    """What a file's plan measured of what the file does not record (fwcore.instrument.measure), for run.json."""
    s = plan.source
    if s is None:
        return {}
    # the pulses its plan found (its packet keys): counted apart from what the ranges wrote, which must add up to it
    return {"pulses_planned": sum(planned_pulses(t) for t in plan.tasks),
            "system_pulse": s.pulse.to_dict(),  # the file's pulse, one record: SystemPulse.from_dict reads it back
            "crs": {"name": crs_name(s.crs_wkt), "source": s.crs_source or None, "wkt": s.crs_wkt},
            "metric_settings": s.metric_settings, "metric_settings_source": s.metric_settings_source or None}


def summarise(output: Path, formats: frozenset[str], limit: int | None, points_per_range: int,
              config: DecompositionConfig, options, seconds: float, jobs: JobsDone, taken: str,
              radiometry: RadiometryConfig = RadiometryConfig(), not_taken: list[tuple[str, str]] = (),
              crs: str | None = None, overrides: PulseOverrides = PulseOverrides(),
              pulse_metrics: str = "echoes") -> dict:
    """run.json: the counts read back from what was written, over every input of the folder (each said done
    or not: fwl watch's folder may hold an interrupted batch's); Beam's metrics of this call's jobs (the
    ranges it ran, not those reused or added earlier)."""
    entries = read_manifest(output)["inputs"]
    write_empty_rejected(output, [e["stem"] for e in entries])
    calibration = jobs.calibration or next((c for e in entries if (c := e.get("planned", {}).get("calibration"))),
                                           None)
    if calibration and not radiometry.calibrated:  # found on the reference patch: what the ranges used
        radiometry = dataclasses.replace(radiometry, calibration_constant=calibration["constant"],
                                         calibration_source=calibration["source"])
    counted = ({e["name"]: c for e in entries if (c := e.get("planned", {}).get("ranges_counted"))}
               if "parquet" not in formats else None)
    counts, per_input = count_outputs(output, [e["name"] for e in entries], counted)
    processed = counts["pulses_read"] if jobs.pulses_processed is None else jobs.pulses_processed
    # a match given as an input that holds none makes the run partial; the counts stay the files'
    status = "partial" if not_taken and status_of(counts) == "complete" else status_of(counts)
    reasons = whole_file_reasons(output, entries, per_input)
    summary = {
        "status": status,
        "exit_code": EXIT_CODES[status],
        "inputs": [{"path": e["path"], "name": e["name"], "output_stem": e["stem"], "done": bool(e.get("done")),
                    "counts": per_input[e["name"]],
                    **({"rejected_because": reasons[e["name"]]} if e["name"] in reasons else {}),
                    **with_system_pulse(e.get("planned", {}))} for e in entries],
        "not_inputs": [{"path": match, "reason": why} for match, why in not_taken],
        "output": str(output),
        "formats": sorted(formats),
        "limit": limit,
        "points_per_range": points_per_range,
        "crs": crs,  # --crs as given (each input's CRS, and where it came from, under inputs)
        "ranges": jobs.ranges,
        "ranges_reused": jobs.ranges_reused,
        "taken": taken,
        "config": config.to_dict(),
        "pulse_metrics": pulse_metrics,  # a small footprint's forest metrics: from its echoes, or "full"
        "overrides": overrides.to_dict(),  # what was given of every file's pulse (each file's own: inputs[])
        "radiometry": {**radiometry.to_dict(), "calibration": calibration,
                       "values": "calibrated" if radiometry.calibrated else "relative (C_cal = 1)"},
        "beam_options": options.get_all_options(drop_default=True),
        "versions": {"fwlidar": fwcore.__version__, "python": platform.python_version(),
                     **{p: metadata.version(p) for p in ("apache-beam", "numba", "numpy", "laspy", "pyarrow")}},
        "counts": counts,
        "metrics": jobs.metrics,
        "seconds": round(seconds, 3),
        # the pulses this call processed: not a resumed run's reused ranges, nor a watched folder's earlier inputs
        "pulses_processed": processed,
        "pulses_per_second": round(processed / seconds, 2) if seconds > 0 else None,
        "files": list_outputs(output),
    }
    write_run_json(output, summary)
    return summary
