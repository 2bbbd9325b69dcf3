"""Box-query benchmark: how much of the echo table a query for a small box reads, and how fast DuckDB answers it.

    flock $LOCK python bench/bench_query.py [--pulses 200000] [--seed 7] [--workdir out/bench_query]
                                                          [--compact] [--sweep 512,1024,2048,4096,8192]

A simulated flight (`fwl simulate --pulses N --seed S`) run with `fwl run --preset fast --formats parquet` (both
skipped when their outputs are there). The box is the flight's centre, 10% x 10% of its extent (1% of its area).
Per layout of the echo table (the parts in pulse order, as before they were indexed; the run's parts; with
--compact, `fwl compact`'s tiles; with --sweep, the parts rewritten in row groups of each size):

    touched   the share of the row groups' bytes whose bbox statistics meet the box (what a reader must read)
    rows      the box query's rows (DuckDB, on the bbox columns) against a full scan's rows in the box: the same
    DuckDB    the box query's time over the full scan's (SELECT * of every echo), one thread, each the fastest of
              --repeat (other tenants' load only ever adds time)
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import duckdb
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.geoparquet import bytes_touched, centre_box, extent_of, row_groups, write_echo_part

KEY = ["source_file", "pulse_id", "echo_index"]


def fwl(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pipeline.cli", *args], check=True)


def flight_run(workdir: Path, pulses: int, seed: int) -> Path:
    """The simulated flight's run folder, made if missing."""
    las, run = workdir / f"flight{pulses}.las", workdir / f"run{pulses}"
    if not las.exists():
        fwl("simulate", "--pulses", str(pulses), "--seed", str(seed), "--output", str(las))
    if not (run / "run.json").exists():
        fwl("run", str(las), "--output", str(run), "--preset", "fast", "--formats", "parquet")
    return run


def _sql_files(files: list[Path]) -> str:
    return "read_parquet([" + ", ".join(f"'{f}'" for f in files) + "])"


def _timed(con, sql: str, repeat: int) -> tuple[float, pa.Table]:
    times, table = [], None
    for _ in range(repeat):
        began = time.perf_counter()
        table = con.sql(sql).to_arrow_table()
        times.append(time.perf_counter() - began)
    return min(times), table


def measure(files: list[Path], repeat: int) -> dict:
    """The box's touched share, its rows against a full scan's, and DuckDB's times."""
    groups = row_groups(files)
    box = centre_box(extent_of(groups))
    xmin, ymin, xmax, ymax = box
    con = duckdb.connect()
    con.execute("SET threads = 1")  # the same one core for both queries
    table = _sql_files(files)
    where = f"bbox.xmin <= {xmax!r} AND bbox.xmax >= {xmin!r} AND bbox.ymin <= {ymax!r} AND bbox.ymax >= {ymin!r}"
    con.execute(f"SELECT count(*) FROM {table}").fetchall()  # footers and page cache warm for both
    full_s, every = _timed(con, f"SELECT * FROM {table}", repeat)
    box_s, found = _timed(con, f"SELECT * FROM {table} WHERE {where}", repeat)
    x, y = every.column("x").to_numpy(), every.column("y").to_numpy()
    scanned = every.filter(pa.array((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)))
    order = [(k, "ascending") for k in KEY]
    same = found.sort_by(order).equals(scanned.sort_by(order))
    return {"files": len(files), "row_groups": len(groups), "echoes": every.num_rows,
            "bytes": sum(g.bytes for g in groups), "box": box, "touched": bytes_touched(files, box),
            "box_rows": found.num_rows, "same_rows": bool(same), "full_scan_s": full_s, "box_query_s": box_s,
            "time_share": box_s / full_s}


def rewritten(files: list[Path], out: Path, row_group_rows: int) -> list[Path]:
    """The parts as they are (each in Hilbert order) in row groups of another size."""
    shutil.rmtree(out, ignore_errors=True)
    return [write_echo_part(pq.read_table(f), out, f.stem, row_group_rows, sort=False) for f in files]


def in_pulse_order(files: list[Path], out: Path) -> list[Path]:
    """The parts as fwl run wrote them before they were indexed: rows in pulse order, one row group a part
    (pyarrow's default); their bbox statistics are those of x and y, which a reader could use all along."""
    shutil.rmtree(out, ignore_errors=True)
    order = [("gps_time", "ascending"), ("pulse_id", "ascending"), ("echo_index", "ascending")]
    return [write_echo_part(pq.read_table(f).sort_by(order), out, f.stem, 1 << 20, sort=False) for f in files]


def line(name: str, m: dict) -> str:
    return (f"| {name} | {m['files']} | {m['row_groups']} | {m['bytes'] / 1e6:.1f} | {100 * m['touched']:.2f}% | "
            f"{m['box_rows']:,} | {'yes' if m['same_rows'] else 'NO'} | {1000 * m['full_scan_s']:.0f} | "
            f"{1000 * m['box_query_s']:.0f} | {100 * m['time_share']:.1f}% |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pulses", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--workdir", type=Path, default=Path("out/bench_query"))
    parser.add_argument("--compact", action="store_true", help="also measure fwl compact's tiles")
    parser.add_argument("--sweep", default="", help="row group sizes to measure the parts in, e.g. 512,2048")
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    run = flight_run(args.workdir, args.pulses, args.seed)
    parts = sorted((run / "echoes").glob("*.parquet"))
    layouts = {"parts in pulse order (before)": measure(in_pulse_order(parts, args.workdir / "pulse_order"),
                                                        args.repeat),
               "fwl run's parts": measure(parts, args.repeat)}
    for size in [int(s) for s in args.sweep.split(",") if s]:
        layouts[f"parts, row groups of {size}"] = measure(rewritten(parts, args.workdir / f"rg{size}", size),
                                                          args.repeat)
    if args.compact:
        compacted = args.workdir / f"compacted{args.pulses}"
        shutil.rmtree(compacted, ignore_errors=True)
        shutil.copytree(run, compacted)
        began = time.perf_counter()
        fwl("compact", str(compacted))
        seconds = time.perf_counter() - began
        layouts[f"fwl compact's tiles ({seconds:.1f} s)"] = measure(sorted((compacted / "echoes").glob("*.parquet")),
                                                                    args.repeat)
    print("| layout | files | row groups | MB | touched | box rows | = full scan | full scan ms | box ms | "
          "box / full |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, m in layouts.items():
        print(line(name, m))
    (args.workdir / "bench_query.json").write_text(json.dumps(layouts, indent=2, default=float))
    assert all(m["same_rows"] for m in layouts.values()), "a box query's rows differ from the full scan's"
    np.testing.assert_array_less([m["touched"] for m in layouts.values()], 1.0)


if __name__ == "__main__":
    main()
