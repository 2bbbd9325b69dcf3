"""Where `fwl run`'s time goes, stage by stage, against Sylva's read + decompose + write on the same file.

    python bench/bench_stages.py [--riegl FILE.las] [--pulses 95000] [--skip-dask] [--workdir DIR] [--checkout DIR]

A RIEGL-like flight line (`fwl simulate --system-response riegl --format las14-internal`, 95,000 pulses, made
once in the work folder unless --riegl gives a file) and the Leica sample, each through `fwl run` as a user
runs it (DirectRunner, 2 workers: threads of the command's process for inputs this size, pipeline.run.Jobs.threaded)
with every default output, `--preset fast`, and one output at a time. Each
run's split comes from the timing lines its workers wrote into logs/ (pipeline.timing): the plan, the runner's
start-up (the ranges handed to the ranges' job, or that job starting, to its first range), each range's read, decompose, geolocate, radiometry,
metrics, tables, sinks, and the files' assembly, with how long assembly ran after the last range ended; the
command's start to its first range, and from the jobs' start when the workers' harness was up, when their
DoFns were warm and when the first range began (the start-up's parts). The
engine's share is decompose over the workers' busy time (ranges, plan and assembly). Sylva (sylva-rs, 2 Rayon
threads): read the waveforms, decompose them, write the echoes as LAS. With Dask (a `distributed`
LocalCluster of 2 single-thread workers), the defaults again.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEICA = ROOT / "examples" / "data" / "leica_als" / "leica_a.las"
CHECKOUT = ROOT  # whose `fwl run` is measured (--checkout: another checkout's, by this script, interleaved)
sys.path.insert(0, str(ROOT))
from pipeline.timing import read_timings  # noqa: E402

STAGES = ("read", "decompose", "geolocate", "radiometry", "metrics", "tables", "cloud", "mcap views",
          "write echoes", "write pulses", "write las", "write mcap")
SYLVA = """
import os, sys, time
os.environ["RAYON_NUM_THREADS"] = "2"
began = time.perf_counter()
import sylva
path, out = sys.argv[1], sys.argv[2]
waveforms = sylva.waveform.read(path)
echoes = sylva.waveform.decompose(waveforms)
sylva.write(echoes.to_pointcloud(), out)
print(len(waveforms), time.perf_counter() - began)
"""
DASK = """
import sys
from distributed import LocalCluster
from fwcore.engine.config import DecompositionConfig
from pipeline.run import run
if __name__ == "__main__":
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    run([sys.argv[1]], sys.argv[2], DecompositionConfig(), watch=False,
        beam_args=["--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                   f"--dask_client_address={cluster.scheduler_address}"])
    cluster.close()
"""


def fwl_run(path: Path, out: Path, extra: list[str], script: str | None = None) -> dict:
    """One `fwl run` in its own process; its wall time, pulses, and the split its logs hold."""
    command = ([sys.executable, "-c", script, str(path), str(out)] if script else
               [sys.executable, "-m", "pipeline.cli", "run", str(path), "--output", str(out), *extra])
    began, started = time.perf_counter(), time.time()
    done = subprocess.run(command, cwd=CHECKOUT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(CHECKOUT)})
    wall = time.perf_counter() - began
    if done.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(command[:6])}: exit {done.returncode}\n{done.stderr[-3000:]}")
    pulses = json.loads((out / "run.json").read_text())["counts"]["pulses_read"]
    timings = split(read_timings(out / "logs"))
    # the command's start to its first range: imports, options, the plan and the workers' start together
    return {"wall": wall, "pulses": pulses, **timings, "to first range": timings["first range"] - started,
            "workers up": workers_up(out / "logs") - timings["jobs began"]}


HARNESS = re.compile(r'seconds: (\d+)\s+nanos: (\d+) \} message: "Python sdk harness starting')


def workers_up(logs: Path) -> float:
    """When the last of the DirectRunner's worker processes had its harness running (Unix s, from the lines the
    runner copies into driver.log); NaN where no worker process started (a run in the driver's process)."""
    text = (logs / "driver.log").read_text(errors="replace") if (logs / "driver.log").is_file() else ""
    found = [int(m.group(1)) + int(m.group(2)) * 1e-9 for m in HARNESS.finditer(text)]
    return max(found) if found else float("nan")


def split(timings: list[dict]) -> dict:
    """Seconds per stage over all ranges, the plan, start-up, assembly and how much of it came after the ranges."""
    ranges = [t for t in timings if t["kind"] == "range"]
    stages = {s: sum(t["seconds"].get(s, 0.0) for t in ranges) for s in STAGES}
    plan = sum(t["seconds"]["plan"] for t in timings if t["kind"] == "plan")
    assemble = [t for t in timings if t["kind"] == "assemble"]
    jobs = next((t for t in timings if t["kind"] == "jobs"), {"seconds": {}, "began": float("nan")})
    setups = [t for t in timings if t["kind"] == "setup"]
    job_began = jobs["seconds"].get("ranges job began")
    last_range = max((t["ended"] for t in ranges), default=0.0)
    first_range = min((t["began"] for t in ranges), default=0.0)
    assembly = sum(t["seconds"]["assemble"] for t in assemble)
    after = max((t["ended"] for t in assemble), default=last_range) - last_range
    busy = sum(stages.values()) + plan + assembly
    return {"stages": stages, "plan": plan, "plan job": jobs["seconds"].get("plan job", 0.0),
            "startup": (first_range - job_began) if job_began else float("nan"),
            "ranges job": jobs["seconds"].get("ranges job", 0.0), "files job": jobs["seconds"].get("files job", 0.0),
            "assembly": assembly, "after last range": max(after, 0.0), "busy": busy, "first range": first_range,
            "jobs began": jobs["began"], "first range after jobs began": first_range - jobs["began"],
            "workers warm": max((t["ended"] for t in setups), default=float("nan")) - jobs["began"],
            "engine share": stages["decompose"] / busy if busy else float("nan"), "ranges": len(ranges)}


def sylva(path: Path, work: Path) -> dict:
    done = subprocess.run([sys.executable, "-c", SYLVA, str(path), str(work / "sylva.las")], capture_output=True,
                          text=True, check=True)
    n, seconds = done.stdout.split()
    return {"wall": float(seconds), "pulses": int(n)}


def show(name: str, runs: dict[str, dict], reference: dict | None) -> None:
    print(f"\n== {name}")
    head = f"{'':22}" + "".join(f"{k:>14}" for k in runs)
    print(head)

    def row(label, get, fmt="{:14.2f}"):
        print(f"{label:22}" + "".join(fmt.format(get(r)) if r else f"{'':>14}" for r in runs.values()))

    row("wall s", lambda r: r["wall"])
    row("pulses/s", lambda r: r["pulses"] / r["wall"], "{:14.0f}")
    if reference:
        row("x Sylva", lambda r: r["pulses"] / r["wall"] / (reference["pulses"] / reference["wall"]), "{:14.3f}")
    row("plan (job) s", lambda r: r.get("plan job", float("nan")))
    row("  plan in worker s", lambda r: r.get("plan", float("nan")))
    row("start-up s", lambda r: r.get("startup", float("nan")))
    row("command to 1st range s", lambda r: r.get("to first range", float("nan")))
    # from the jobs' start (after the command's imports and options): the workers' harness, their DoFns warmed
    row("  workers up s", lambda r: r.get("workers up", float("nan")))
    row("  workers warm s", lambda r: r.get("workers warm", float("nan")))
    row("  first range s", lambda r: r.get("first range after jobs began", float("nan")))
    row("ranges job s", lambda r: r.get("ranges job", float("nan")))
    for stage in STAGES:
        row(f"  {stage} s", lambda r, s=stage: r["stages"][s] if "stages" in r else float("nan"))
    row("assembly s", lambda r: r.get("assembly", float("nan")))
    row("  after last range s", lambda r: r.get("after last range", float("nan")))
    row("files job s", lambda r: r.get("files job", float("nan")))
    row("engine share", lambda r: r.get("engine share", float("nan")), "{:14.0%}")
    row("outside engine us/p", lambda r: 1e6 * (r["busy"] - r["stages"]["decompose"]) / r["pulses"]
        if "busy" in r else float("nan"), "{:14.0f}")
    row("engine us/pulse", lambda r: 1e6 * r["stages"]["decompose"] / r["pulses"] if "stages" in r
        else float("nan"), "{:14.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--riegl", default=None, help="a RIEGL-like LAS 1.4 flight line (default: simulated)")
    parser.add_argument("--pulses", type=int, default=95_000)
    parser.add_argument("--skip-dask", action="store_true")
    parser.add_argument("--cases", default="defaults,fast,parquet,las,mcap", help="which runs, comma-separated")
    parser.add_argument("--workdir", default=None)
    parser.add_argument("--checkout", default=None, help="measure this checkout's fwl run (default: this one's)")
    args = parser.parse_args()
    global CHECKOUT
    CHECKOUT = Path(args.checkout).resolve() if args.checkout else ROOT
    work = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-stages-"))
    riegl = Path(args.riegl) if args.riegl else work / "riegl_line.las"
    if not riegl.exists():
        subprocess.run([sys.executable, "-m", "pipeline.cli", "simulate", "--pulses", str(args.pulses), "--output",
                        str(riegl), "--format", "las14-internal", "--sensor-response", "riegl", "--seed", "3"],
                       cwd=ROOT, check=True, capture_output=True)
    # numba's cache (a checkout compiles its own) and the OS's file cache warm for every run below
    fwl_run(LEICA, work / "warm", [])
    fwl_run(riegl, work / "warm-riegl", ["--limit", "3000", "--formats", "parquet,las,mcap"])
    cases = {"defaults": [], "fast": ["--preset", "fast"], "parquet": ["--formats", "parquet"],
             "las": ["--formats", "las"], "mcap": ["--formats", "mcap"]}
    cases = {name: extra for name, extra in cases.items() if name in args.cases.split(",")}
    for name, path in (("RIEGL-like", riegl), ("Leica", LEICA)):
        reference = sylva(path, work)
        runs = {name_: fwl_run(path, work / f"{path.stem}-{name_}", extra) for name_, extra in cases.items()}
        if not args.skip_dask and name == "RIEGL-like":
            runs["dask"] = fwl_run(path, work / f"{path.stem}-dask", [], DASK)
        print(f"\nSylva {reference['pulses']} pulses in {reference['wall']:.2f} s: "
              f"{reference['pulses'] / reference['wall']:,.0f} pulses/s (read, decompose, write LAS; 2 threads)")
        show(f"{name}: {path.name}", runs, reference)
        if "mcap" in runs:
            print(f"MCAP alone / Parquet alone: {runs['mcap']['wall'] / runs['parquet']['wall']:.2f}x")


if __name__ == "__main__":
    main()
