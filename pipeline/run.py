"""Build and run the pipeline; summarise what it wrote in run.json."""

from __future__ import annotations

import glob
import json
import platform
import shutil
import time
from importlib import metadata
from pathlib import Path

import apache_beam as beam
import pyarrow.dataset as ds
from apache_beam.options.pipeline_options import PipelineOptions

import fwcore
from fwcore.config import DecompositionConfig
from pipeline.transforms import NAMESPACE, DecomposeFlight

FORMATS = frozenset({"parquet", "las", "mcap"})
OUTPUT_DIRS = ("echoes", "pulses", "rejected", "las", "mcap")
DEFAULT_RUNNER_ARGS = ["--runner=DirectRunner", "--direct_num_workers=2", "--direct_running_mode=multi_processing"]
BUNDLED_SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"


def beam_options(beam_args: list[str]) -> PipelineOptions:
    """The user's Beam options; the DirectRunner with 2 worker processes unless a runner is named."""
    args = list(beam_args)
    if not any(a.startswith("--runner") for a in args):
        args = DEFAULT_RUNNER_ARGS + args
    options = PipelineOptions(args)
    # the workers import fwcore and pipeline from the installed package
    options.view_as(beam.options.pipeline_options.SetupOptions).save_main_session = False
    return options


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


def run(inputs: list[str], output: str | Path, config: DecompositionConfig, formats=("parquet", "las", "mcap"),
        limit: int | None = None, points_per_range: int = 5000, laz: bool = False,
        beam_args: list[str] | None = None) -> dict:
    """Decompose every pulse of the inputs into DIR's outputs; return (and write) the run summary."""
    formats = frozenset(formats)
    unknown = formats - FORMATS
    if unknown:
        raise ValueError(f"unknown output formats {sorted(unknown)}; choose from {sorted(FORMATS)}")
    output = Path(output).resolve()
    for name in OUTPUT_DIRS:  # a previous run's parts would be counted as this run's
        shutil.rmtree(output / name, ignore_errors=True)
    output.mkdir(parents=True, exist_ok=True)
    inputs = [str(Path(i).resolve()) if Path(i).exists() else i for i in (inputs or [str(BUNDLED_SAMPLE)])]
    for pattern in inputs:  # local patterns are checked here, so a typo is an error and not an empty run
        if "://" not in pattern and not glob.glob(pattern):
            raise FileNotFoundError(f"{pattern}: no file matches this input")
    options = beam_options(beam_args or [])
    began = time.perf_counter()
    pipeline = beam.Pipeline(options=options)
    (pipeline | "Inputs" >> beam.Create(inputs)
     | "DecomposeFlight" >> DecomposeFlight(config, str(output), formats, points_per_range, limit, laz))
    result = pipeline.run()
    result.wait_until_finish()
    seconds = time.perf_counter() - began
    counts = count_outputs(output)
    summary = {
        "inputs": inputs,
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
    }
    (output / "run.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    return summary
