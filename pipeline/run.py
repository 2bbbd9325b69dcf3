"""Build and run the pipeline; summarise what it wrote in run.json.

    validate options and inputs -> take the output folder -> run -> count what was written -> run.json

Exit codes of `fwl run` (see the README): 0 every pulse decomposed; 3 some inputs or pulses rejected,
the rest written; 4 nothing decomposed (every input or pulse rejected); 2 a usage error (bad option,
no such input, an output folder that holds what is not ours), nothing touched; 130 interrupted.
"""

from __future__ import annotations

import platform
import time
from importlib import metadata
from pathlib import Path

import apache_beam as beam
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
from apache_beam.options.pipeline_options import PipelineOptions

import fwcore
from fwcore.config import DecompositionConfig
from pipeline.outputs import (IncompleteRunError, InputNames, OutputFolderError, expand_inputs, is_complete,
                              list_outputs, read_run, remove_partial_files, take_output_folder, write_run_json)
from pipeline.transforms import NAMESPACE, DecomposeFlight

__all__ = ["EXIT_INTERRUPTED", "EXIT_NOTHING_DONE", "EXIT_OK", "EXIT_PARTIAL", "EXIT_USAGE", "IncompleteRunError",
           "OutputFolderError", "is_complete", "read_run", "run"]

EXIT_OK, EXIT_USAGE, EXIT_PARTIAL, EXIT_NOTHING_DONE, EXIT_INTERRUPTED = 0, 2, 3, 4, 130
FORMATS = frozenset({"parquet", "las", "mcap"})
DEFAULT_RUNNER_ARGS = ["--runner=DirectRunner", "--direct_num_workers=2", "--direct_running_mode=multi_processing"]
BUNDLED_SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"
COUNTS = ("pulses_read", "pulses_decomposed", "pulses_rejected", "files_rejected", "echoes_kept", "echoes_spurious")


def beam_options(beam_args: list[str]) -> PipelineOptions:
    """The user's Beam options; the DirectRunner with 2 worker processes unless a runner is named."""
    args = list(beam_args)
    if not any(a.startswith("--runner") for a in args):
        args = DEFAULT_RUNNER_ARGS + args
    options = PipelineOptions(args)
    # the workers import fwcore and pipeline from the installed package
    options.view_as(beam.options.pipeline_options.SetupOptions).save_main_session = False
    return options


def _table(directory: Path, columns: list[str]) -> pa.Table | None:
    files = sorted(directory.glob("*.parquet"))
    return ds.dataset(files, format="parquet").to_table(columns=columns) if files else None


def _counts_by_input(table: pa.Table | None, aggregations: list[tuple]) -> dict[str, dict]:
    if table is None or not table.num_rows:
        return {}
    grouped = table.group_by("source_file").aggregate(aggregations).to_pylist()
    return {row.pop("source_file"): row for row in grouped}


def count_outputs(output: Path, names: list[str]) -> tuple[dict[str, int], dict[str, dict[str, int]]]:
    """Totals and per-input counts read back from what was written, so that they add up by construction."""
    pulses = _table(output / "pulses", ["source_file"])
    echoes = _table(output / "echoes", ["source_file", "kept"])
    rejected = _table(output / "rejected", ["source_file", "stage"])
    if rejected is not None:
        rejected = rejected.append_column("is_file", pc.equal(rejected.column("stage"), "open"))
    per_pulses = _counts_by_input(pulses, [("source_file", "count")])
    per_echoes = _counts_by_input(echoes, [("kept", "count"), ("kept", "sum")])
    per_rejected = _counts_by_input(rejected, [("is_file", "count"), ("is_file", "sum")])
    per_input = {}
    for name in names:
        decomposed = per_pulses.get(name, {}).get("source_file_count", 0)
        rows = per_rejected.get(name, {})
        files_rejected = int(rows.get("is_file_sum") or 0)
        pulse_rejects = rows.get("is_file_count", 0) - files_rejected
        echo_rows = per_echoes.get(name, {})
        kept = int(echo_rows.get("kept_sum") or 0)
        per_input[name] = {"pulses_read": decomposed + pulse_rejects, "pulses_decomposed": decomposed,
                           "pulses_rejected": pulse_rejects, "files_rejected": files_rejected,
                           "echoes_kept": kept, "echoes_spurious": echo_rows.get("kept_count", 0) - kept}
    totals = {k: sum(c[k] for c in per_input.values()) for k in COUNTS}
    return totals, per_input


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


def status_of(counts: dict[str, int]) -> str:
    """complete: nothing rejected; partial: some inputs or pulses rejected; failed: nothing decomposed."""
    if not counts["pulses_rejected"] and not counts["files_rejected"]:
        return "complete"
    return "partial" if counts["pulses_decomposed"] else "failed"


EXIT_CODES = {"complete": EXIT_OK, "partial": EXIT_PARTIAL, "failed": EXIT_NOTHING_DONE}


def check_run_arguments(formats, limit: int | None, points_per_range: int) -> frozenset[str]:
    formats = frozenset(formats)
    unknown = formats - FORMATS
    if unknown or not formats:
        raise ValueError(f"unknown output formats {sorted(unknown)}; choose from {sorted(FORMATS)}" if unknown
                         else f"no output format; choose from {sorted(FORMATS)}")
    if not isinstance(points_per_range, int) or points_per_range < 1:
        raise ValueError(f"--points-per-range must be a whole number >= 1, not {points_per_range}")
    if limit is not None and (not isinstance(limit, int) or limit < 1):
        raise ValueError(f"--limit must be a whole number >= 1, not {limit}")
    return formats


def run(inputs: list[str], output: str | Path, config: DecompositionConfig, formats=("parquet", "las", "mcap"),
        limit: int | None = None, points_per_range: int = 5000, laz: bool = False,
        beam_args: list[str] | None = None) -> dict:
    """Decompose every pulse of the inputs into DIR's outputs; return (and write) the run summary.

    Everything is checked before the output folder is touched; ValueError / FileNotFoundError
    (OutputFolderError for a folder holding what is not ours) then, and nothing is changed.
    """
    formats = check_run_arguments(formats, limit, points_per_range)
    output = Path(output).resolve()
    paths = expand_inputs(inputs or [str(BUNDLED_SAMPLE)])
    names = InputNames.of(paths)
    options = beam_options(beam_args or [])
    take_output_folder(output, names, paths)
    began = time.perf_counter()
    pipeline = beam.Pipeline(options=options)
    try:
        (pipeline | "Inputs" >> beam.Create(paths)
         | "DecomposeFlight" >> DecomposeFlight(config, str(output), formats, points_per_range, limit, laz, names))
        result = pipeline.run()
        result.wait_until_finish()
    finally:
        remove_partial_files(output)
    seconds = time.perf_counter() - began
    counts, per_input = count_outputs(output, [names.name(p) for p in paths])
    status = status_of(counts)
    summary = {
        "status": status,
        "exit_code": EXIT_CODES[status],
        "inputs": [{"path": p, "name": names.name(p), "output_stem": names.stem(names.name(p)),
                    "counts": per_input[names.name(p)]} for p in paths],
        "output": str(output),
        "formats": sorted(formats),
        "limit": limit,
        "points_per_range": points_per_range,
        "config": config.to_dict(),
        "beam_options": options.get_all_options(drop_default=True),
        "versions": {"fwlidar": fwcore.__version__, "python": platform.python_version(),
                     **{p: metadata.version(p) for p in ("apache-beam", "numba", "numpy", "laspy", "pyarrow")}},
        "counts": counts,
        "metrics": _metric_counts(result),
        "seconds": round(seconds, 3),
        "pulses_per_second": round(counts["pulses_read"] / seconds, 2) if seconds > 0 else None,
        "files": list_outputs(output),
    }
    write_run_json(output, summary)
    return summary
