"""fwl grid benchmark: a run's echo table of N echoes gridded, seconds and peak memory.

    python bench/bench_grid.py [--echoes 10000000] [--cell 1] [--workdir DIR] [--classify]

The run folder is synthetic but of the run's layout: run.json, and echoes/ parts of 50,000 echoes with every
column of the echo table (pipeline.tables.table_schema("echoes")), about 7% of them spurious (kept false),
along the flight of bench_copc.py (60 m/s, 300 m swath, canopy up to 30 m). `fwl grid` then runs in a fresh
process: the time is its wall time (imports included), the peak memory its maximum RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
PART_ECHOES = 50_000


def write_run(folder: Path, echoes: int) -> int:
    """A run folder whose echo table holds `echoes` rows; the kept echoes' count."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from bench_copc import PULSE_RATE_HZ, flight_echoes

    from pipeline.tables import table_schema

    schema = table_schema("echoes")
    rng = np.random.default_rng(3)
    (folder / "echoes").mkdir(parents=True)
    first, written, kept_total = 0, 0, 0
    while written < echoes:
        e = flight_echoes(first, PART_ECHOES // 2, rng)
        n = min(len(e["x"]), echoes - written)
        kept = rng.random(n) > 0.07
        values = {"x": e["x"][:n], "y": e["y"][:n], "z": e["z"][:n], "amplitude": e["amplitude"][:n],
                  "energy": e["echo_energy"][:n], "gps_time": e["gps_time"][:n], "kept": kept,
                  "echo_index": e["return_number"][:n] - 1, "echo_count": e["number_of_returns"][:n],
                  "pulse_id": np.round(e["gps_time"][:n] * PULSE_RATE_HZ).astype(np.int64)}  # a pulse's echoes share it
        columns = []
        for field in schema:
            if field.name in values:
                columns.append(pa.array(values[field.name], field.type))
            elif pa.types.is_string(field.type):
                columns.append(pa.array(np.full(n, "unavailable" if field.name == "radiometry" else "")))
            else:  # no geometry, no radiometry, no fit statistics: null, as a run without them writes
                columns.append(pa.nulls(n, field.type))
        pq.write_table(pa.table(columns, schema=schema), folder / "echoes" / f"flight-{first:012d}.parquet")
        first += PART_ECHOES // 2
        written += n
        kept_total += int(kept.sum())
    (folder / "run.json").write_text(json.dumps({"status": "complete", "counts": {"echoes_kept": kept_total}}))
    return kept_total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--echoes", type=int, default=10_000_000)
    parser.add_argument("--cell", type=float, default=1.0)
    parser.add_argument("--workdir")
    parser.add_argument("--classify", action="store_true",
                        help="fwl classify the run first (measured alone), so that fwl grid writes the forest's maps")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.workdir) as work:
        work = Path(work)
        began = time.perf_counter()
        kept = write_run(work / "run", args.echoes)
        size = sum(p.stat().st_size for p in (work / "run" / "echoes").glob("*.parquet")) / 2**20
        print(f"echo table: {args.echoes:,} echoes ({kept:,} kept), {size:.0f} MiB in "
              f"{len(list((work / 'run' / 'echoes').glob('*.parquet')))} parts, written in "
              f"{time.perf_counter() - began:.0f} s", flush=True)
        if args.classify:  # the forest's maps need the classes: fwl classify first, measured alone
            seconds, peak = _measured(["classify", str(work / "run")])
            print(f"fwl classify: {kept:,} kept echoes in {seconds:.1f} s, peak {peak:.0f} MiB", flush=True)
        seconds, peak = _measured(["grid", str(work / "run"), "--cell", str(args.cell), "--output",
                                   str(work / "maps"), "--crs", "EPSG:25832"])
        summary = json.loads((work / "maps" / "fwl-grid.json").read_text())
        assert summary["echoes"] == kept
        print("| echoes | kept | cell | cells | bins | s | kept echoes/s | peak MiB |")
        print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        print(f"| {args.echoes:,} | {kept:,} | {args.cell:g} m | {summary['width'] * summary['height']:,} | "
              f"{summary['bins']} | {seconds:.1f} | {kept / seconds:,.0f} | {peak:.0f} |")
        print(f"maps: {', '.join(summary['files'])}")


def _measured(args: list[str]) -> tuple[float, float]:
    """An fwl command in a fresh process: its wall seconds and peak memory (MiB, its maximum RSS)."""
    began = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "pipeline.cli", *args], env={**os.environ, "PYTHONPATH": str(ROOT)})
    _, status, usage = os.wait4(child.pid, 0)
    if status:
        raise RuntimeError(f"fwl {args[0]} failed")
    return time.perf_counter() - began, usage.ru_maxrss / 1024


if __name__ == "__main__":
    main()
