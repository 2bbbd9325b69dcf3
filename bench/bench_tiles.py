"""The maps on the runners: `fwl classify` then `fwl grid` (the forest's maps) of a synthetic run, timed on the
DirectRunner with 1 and 2 workers and on a local Dask cluster of 1 or 2 workers, at two sizes.

    python bench/bench_tiles.py [--sizes 2000000,20000000] [--cell 5] [--workdir DIR]
                                [--runners direct-1,direct-2,dask-1,dask-2] [--source DIR] [--no-warm] [--repeats 3]

The run is bench_grid.py's (echoes/ parts of every column along a 300 m swath, canopy up to 30 m). Each runner
gets its own copy of the run (fwl classify writes into it); each command runs in a fresh process, its wall time
start-up included. Peak memory is the largest sum of RSS over this process and all its children (the command,
Beam's workers, the Dask cluster's workers), sampled every 0.2 s. At the end the maps of every runner are
compared pixel for pixel (every band of every COG) and the classes column for column, with the first runner's.
The speed-up is over the same runner with 1 worker where it ran (and over direct-1 beside it), else over direct-1.
`--source DIR` takes the run from DIR (written there first, and kept, where DIR does not exist): a large run
written once, outside the benchmark's lock. The load average (1 minute) is read as each runner ends.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from bench_grid import write_run  # noqa: E402
from bench_pipeline import PeakMemory  # noqa: E402

DASK = "apache_beam.runners.dask.dask_runner.DaskRunner"


def fwl(*args: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline.cli", *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def maps_of(folder: Path) -> dict[str, str]:
    """Each map's pixels, every band, as a digest: a run's maps compared with another's without holding them."""
    import rasterio

    out = {}
    for tif in sorted(folder.glob("*.tif")):
        with rasterio.open(tif) as src:
            pixels = src.read()
            out[tif.name] = hashlib.sha256(pixels.tobytes()).hexdigest() if pixels.size else ""
    return out


def classes_of(run: Path) -> str:
    """The echo table's classes and heights, file by file, as a digest."""
    import pyarrow.parquet as pq

    digest = hashlib.sha256()
    for f in sorted((run / "echoes").glob("*.parquet")):
        digest.update(pq.read_table(f, columns=["classification", "height"]).to_pandas().to_numpy(float).tobytes())
    return digest.hexdigest()


def one(source: Path, work: Path, name: str, cell: float, runner: list[str]) -> dict:
    run = work / name / "run"
    shutil.copytree(source, run)
    with PeakMemory() as memory:
        classify = fwl("classify", str(run), *runner)
        grid = fwl("grid", str(run), "--cell", str(cell), "--output", str(work / name / "maps"), "--crs",
                   "EPSG:25832", *runner)
    return {"classify": classify, "grid": grid, "peak": memory.peak / 2**20, "maps": maps_of(work / name / "maps"),
            "classes": classes_of(run)}


RUNNERS = {"direct-1": ["--direct_num_workers=1", "--direct_running_mode=multi_processing"],
           "direct-2": ["--direct_num_workers=2", "--direct_running_mode=multi_processing"], "dask-1": None,
           "dask-2": None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="2000000,20000000")
    parser.add_argument("--cell", type=float, default=5.0)
    parser.add_argument("--workdir")
    parser.add_argument("--runners", default=",".join(RUNNERS))
    parser.add_argument("--source", help="the run (one size): written here first where it does not exist; kept")
    parser.add_argument("--no-warm", action="store_true", help="no first fwl grid (numba's caches already written)")
    parser.add_argument("--repeats", type=int, default=1, help="the runners in turn this many times; then medians")
    args = parser.parse_args()
    names = args.runners.split(",")
    print(f"| echoes | runner | classify s | grid s | total s | speed-up | peak MiB | maps as {names[0]} | load |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: | --- | ---: |", flush=True)
    for size in (int(s) for s in args.sizes.split(",")):
        with tempfile.TemporaryDirectory(dir=args.workdir) as work:
            work = Path(work)
            source = Path(args.source) if args.source else work / "source"
            if not source.exists():
                write_run(source, size)
            if not args.no_warm:
                fwl("grid", str(source), "--cell", "50", "--output", str(work / "warm"), "--crs", "EPSG:25832")
            runs: dict[str, list[dict]] = {name: [] for name in names}
            for _ in range(args.repeats):  # the runners in turn: a change of the machine's load falls on each
                for name in names:
                    runner = RUNNERS[name]
                    if runner is None:
                        from distributed import LocalCluster

                        with LocalCluster(n_workers=int(name.split("-")[1]), threads_per_worker=1, processes=True,
                                          dashboard_address=None) as cluster:
                            r = one(source, work, name, args.cell,
                                    [f"--runner={DASK}", f"--dask_client_address={cluster.scheduler_address}"])
                    else:
                        r = one(source, work, name, args.cell, runner)
                    r["load"] = float(Path("/proc/loadavg").read_text().split()[0])
                    runs[name].append(r)
                    _row(size, name, r, runs, names[0])
                    shutil.rmtree(work / name)  # a copy of the run a runner: only one on the disk at a time
            if args.repeats > 1:
                medians = {name: {k: statistics.median(r[k] for r in rs) for k in ("classify", "grid", "peak", "load")}
                               | {"maps": rs[0]["maps"], "classes": rs[0]["classes"], "median": True}
                           for name, rs in runs.items()}
                for name in names:
                    _row(size, f"{name} (median of {args.repeats})", medians[name],
                         {k: [v] for k, v in medians.items()}, names[0])


def _row(size: int, name: str, r: dict, runs: dict[str, list[dict]], first: str) -> None:
    """A run's row: its speed-up over the same runner's 1-worker run (its latest, or its median; direct-1's where
    the runner had none), its maps against the first runner's."""
    total = r["classify"] + r["grid"]
    runner = name.split("-")[0]
    base = runs.get(f"{runner}-1") or runs.get("direct-1", [])
    speed = f"{(base[-1]['classify'] + base[-1]['grid']) / total:.2f}" if base else "-"
    if base and runs.get(f"{runner}-1") and runner != "direct" and runs.get("direct-1"):
        d = runs["direct-1"][-1]
        speed += f" ({(d['classify'] + d['grid']) / total:.2f} of direct-1)"
    same = r["maps"] == runs[first][0]["maps"] and r["classes"] == runs[first][0]["classes"] and all(r["maps"].values())
    print(f"| {size:,} | {name} | {r['classify']:.1f} | {r['grid']:.1f} | {total:.1f} | {speed} | "
          f"{r['peak']:.0f} | {same} | {r['load']:.1f} |", flush=True)

if __name__ == "__main__":
    main()
