"""Build and run the pipeline; summarise what it wrote in run.json."""

from __future__ import annotations

import json
import platform
import shutil
import time
from importlib import metadata
from pathlib import Path

import apache_beam as beam
import pyarrow as pa
import pyarrow.dataset as ds

import fwcore
from fwcore.config import DecompositionConfig
from pipeline.options import FORMATS, check_beam_args, is_dask
from pipeline.plan import match_inputs, plan_inputs, planned_pulses
from pipeline.progress import ProgressBar, watched_logs
from pipeline.sinks import write_part
from pipeline.tables import REJECTED_SCHEMA
from pipeline.transforms import NAMESPACE, PARTS, DecomposeFlight

OUTPUT_DIRS = ("echoes", "pulses", "rejected", "las", "mcap", PARTS)
BUNDLED_SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"


def _rows(directory: Path, columns: list[str] | None = None):
    files = sorted(directory.glob("*.parquet"))
    return ds.dataset(files, format="parquet").to_table(columns=columns) if files else None


def count_outputs(output: Path) -> dict[str, int]:
    """Counts read back from what was written, so that they add up by construction of the files."""
    pulses = _rows(output / "pulses", ["pulse_id"])
    echoes = _rows(output / "echoes", ["kept"])
    rejected = _rows(output / "rejected", ["pulse_id", "stage"])
    decomposed = pulses.num_rows if pulses is not None else 0
    stages = rejected.column("stage").to_pylist() if rejected is not None else []
    pulse_rejects = sum(1 for s in stages if s != "open")
    kept = sum(echoes.column("kept").to_pylist()) if echoes is not None else 0
    return {
        "pulses_read": decomposed + pulse_rejects,
        "pulses_decomposed": decomposed,
        "pulses_rejected": pulse_rejects,
        "files_rejected": sum(1 for s in stages if s == "open"),
        "echoes_kept": kept,
        "echoes_spurious": (echoes.num_rows if echoes is not None else 0) - kept,
    }


def _metric_counts(result) -> dict[str, int]:
    try:
        counters = result.metrics().query(beam.metrics.MetricsFilter().with_namespace(NAMESPACE))["counters"]
    except Exception:  # some runners (Dask) do not report metrics
        return {}
    return {c.key.metric.name: int(c.committed if c.committed is not None else c.attempted) for c in counters}


def _write_file_rejections(output: Path, rejected: list) -> None:
    for r in rejected:
        table = pa.table({c: [getattr(r, c)] for c in REJECTED_SCHEMA.names}, schema=REJECTED_SCHEMA)
        write_part(table, output / "rejected", r.stem)


def _runner_name(options) -> str:
    runner = options.view_as(beam.options.pipeline_options.StandardOptions).runner
    name = runner.rsplit(".", 1)[-1] if isinstance(runner, str) else type(runner).__name__
    if name == "DirectRunner":
        workers = options.view_as(beam.options.pipeline_options.DirectOptions).direct_num_workers
        return f"DirectRunner, {workers} workers"
    return name


def run(inputs: list[str], output: str | Path, config: DecompositionConfig, formats=FORMATS,
        limit: int | None = None, points_per_range: int = 5000, laz: bool = False,
        beam_args: list[str] | None = None, verbose: bool = False, watch: bool = True) -> dict:
    """Decompose every pulse of the inputs into DIR's outputs; return (and write) the run summary.

    With `watch`, print a start line and draw a progress bar on the terminal; logs go to DIR/logs/.
    """
    formats = frozenset(formats)
    unknown = formats - set(FORMATS)
    if unknown:
        raise ValueError(f"unknown output formats {sorted(unknown)}; choose from {sorted(FORMATS)}")
    if points_per_range < 1 or (limit is not None and limit < 1):
        raise ValueError("--points-per-range and --limit must be at least 1")
    options = check_beam_args(beam_args or [])  # a mistyped option stops here, before anything is touched
    paths = match_inputs(inputs or [str(BUNDLED_SAMPLE)])
    output = Path(output).resolve()
    for name in OUTPUT_DIRS:  # a previous run's parts would be counted as this run's
        shutil.rmtree(output / name, ignore_errors=True)
    output.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    with watched_logs(output, verbose) as (say, terminal):
        tasks, file_rejections = plan_inputs(paths, config, points_per_range, limit)
        _write_file_rejections(output, file_rejections)
        total = sum(planned_pulses(t) for t in tasks)
        dask = is_dask(options)
        if dask:  # one bag partition per range, so the scheduler balances ranges over workers
            from apache_beam.runners.dask.dask_runner import DaskOptions
            bags = options.view_as(DaskOptions)
            if bags.npartitions is None and bags.partition_size is None:
                bags.npartitions = max(1, len(tasks))
        if watch:
            rejected = f", {len(file_rejections)} rejected" if file_rejections else ""
            say.write(f"fwl run: {len(paths)} file(s){rejected}, {total:,} pulses in {len(tasks)} ranges -> {output} "
                      f"({', '.join(sorted(formats))}); {config.optimizer.value}/{config.model.value}; "
                      f"{_runner_name(options)}; logs in {output / 'logs'}\n")
            say.flush()
        result = None
        if tasks:
            pipeline = beam.Pipeline(options=options)
            (pipeline | "Ranges" >> beam.Create(tasks)
             | "DecomposeFlight" >> DecomposeFlight(config, str(output), formats, laz, spread=not dask))
            bar = ProgressBar(output / PARTS, total, terminal, interactive=None if watch else False,
                              line_every=60.0 if watch else float("inf"))
            with bar:
                result = pipeline.run()
                result.wait_until_finish()
    shutil.rmtree(output / PARTS, ignore_errors=True)
    seconds = time.perf_counter() - began
    counts = count_outputs(output)
    summary = {
        "inputs": paths,
        "output": str(output),
        "formats": sorted(formats),
        "limit": limit,
        "points_per_range": points_per_range,
        "ranges": len(tasks),
        "config": config.to_dict(),
        "beam_options": options.get_all_options(drop_default=True),
        "versions": {"fwlidar": fwcore.__version__, "python": platform.python_version(),
                     **{p: metadata.version(p) for p in ("apache-beam", "numba", "numpy", "laspy", "pyarrow")}},
        "counts": counts,
        "metrics": _metric_counts(result) if result is not None else {},
        "seconds": round(seconds, 3),
        "pulses_per_second": round(counts["pulses_read"] / seconds, 2) if seconds > 0 else None,
    }
    (output / "run.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    return summary
