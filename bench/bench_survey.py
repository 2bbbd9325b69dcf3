"""Survey operations benchmark: resume after a kill, a watched folder's latency, planning on workers, many files.

    python bench/bench_survey.py [--sections resume,watch,plan,many] [--resume-pulses 40000]
                                 [--files 200] [--file-pulses 5000] [--large 1000000] [--workdir DIR]

resume  A simulated flight through `fwl run` (default preset, DirectRunner with 2 workers, parquet and LAS),
        timed clean; then the same run killed (SIGKILL to its process group) once 30% of its ranges have
        left their marks, and `fwl run --resume` timed. Prints the ranges reused, the share of the work redone
        (ranges, pulses, and the resume's time over the clean run's) and whether the outputs equal the
        clean run's byte for byte (the tables' parts and the point cloud).
watch   `fwl watch --poll 1` (default preset) on an empty folder; three copies of the Leica sample (924 pulses)
        land one after another, each .las and then its .wdp; the latency is from the .wdp's copy ending to
        the output's run.json listing the file.
plan    FILES simulated files of FILE_PULSES pulses, planned (packet keys and system pulse) one after
        another on the driver, as runs did before, then by the plan job on a local Dask cluster of 2 worker
        processes (its start is not counted; each of its workers plans one file before the clock starts,
        as the driver does, so that loading numba's kernels is not counted on either side), once with
        distributed's default settings and once with deploy/dask-workers.yaml (the workers' housekeeping
        quieted).
many    `fwl run --preset fast --formats parquet,las` on the folder of those FILES files, and on one
        simulated file of LARGE pulses: pulses/s over the wall time and peak RSS (the largest sum over the
        run's process and its children, sampled every 0.2 s).

A short untimed run first fills numba's cache; run it on a checkout that does not change meanwhile.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import PeakMemory  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"
FWL = [sys.executable, "-m", "pipeline.cli"]


def fwl(*args: str) -> None:
    subprocess.run([*FWL, *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def simulate(path: Path, pulses: int, seed: int) -> Path:
    from fwcore.studies.simulate import SceneConfig, SensorConfig
    from fwcore.studies.truth import truth_path, write_flight
    path.parent.mkdir(parents=True, exist_ok=True)
    write_flight(path, pulses, SensorConfig(), SceneConfig(), seed)
    truth_path(path).unlink()  # the truth is not an input
    return path


def timed(*args: str) -> float:
    start = time.perf_counter()
    fwl(*args)
    return time.perf_counter() - start


def outputs(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.relative_to(folder).parts[0] in ("echoes", "pulses", "rejected", "las")}


# ---------------------------------------------------------------- resume

def bench_resume(work: Path, pulses: int) -> None:
    las = simulate(work / "resume" / "flight.las", pulses, seed=11)
    args = [str(las), "--points-per-range", "1000", "--formats", "parquet,las"]
    clean_s = timed("run", *args, "--output", str(work / "resume" / "clean"))
    killed = work / "resume" / "killed"
    run = subprocess.Popen([*FWL, "run", *args, "--output", str(killed)], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL, start_new_session=True)
    plan = killed / "parts" / "plans" / "flight.json"
    while not plan.is_file() and run.poll() is None:
        time.sleep(0.05)
    ranges = json.loads(plan.read_text())["ranges"]
    while len(list((killed / "parts").glob("*.json"))) < 0.3 * len(ranges) and run.poll() is None:
        time.sleep(0.02)
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()
    marked = {int(p.stem.rsplit("-", 1)[1]) for p in (killed / "parts").glob("*.json")}
    resume_s = timed("run", *args, "--output", str(killed), "--resume")
    reused = json.loads((killed / "run.json").read_text())["ranges_reused"]
    pulses_of = {r["start"]: r["max_pulses"] if r["max_pulses"] is not None else r["n_pulses"] for r in ranges}
    redone = 1 - sum(pulses_of[s] for s in marked) / sum(pulses_of.values())
    same = outputs(killed) == outputs(work / "resume" / "clean")
    print(f"resume: {pulses} pulses in {len(ranges)} ranges; killed with {len(marked)} ranges written "
          f"({len(marked) / len(ranges):.0%}); resumed reusing {reused}: redid {1 - reused / len(ranges):.0%} of the "
          f"ranges, {redone:.0%} of the pulses; clean {clean_s:.1f} s, resume {resume_s:.1f} s "
          f"({resume_s / clean_s:.2f} x); outputs identical to the clean run: {same}", flush=True)


# ---------------------------------------------------------------- watch

def bench_watch(work: Path, arrivals: int = 3) -> None:
    land, out = work / "watch" / "land", work / "watch" / "out"
    land.mkdir(parents=True)
    watcher = subprocess.Popen([*FWL, "watch", str(land), "--output", str(out), "--poll", "1"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    watcher.stdout.readline()  # its first line: watching
    latencies = []
    try:
        for k in range(arrivals):
            shutil.copy(SAMPLE, land / f"line_{k}.las")
            time.sleep(1.5)  # the .las alone: not complete
            shutil.copy(SAMPLE.with_suffix(".wdp"), land / f"line_{k}.wdp")
            complete = time.perf_counter()
            while True:
                try:
                    names = [i["name"] for i in json.loads((out / "run.json").read_text())["inputs"]]
                except (OSError, ValueError):
                    names = []
                if f"line_{k}.las" in names:
                    break
                time.sleep(0.1)
            latencies.append(time.perf_counter() - complete)
    finally:
        watcher.send_signal(signal.SIGINT)
        watcher.wait(timeout=120)
    print(f"watch: 924-pulse files, poll 1 s, default preset: done "
          f"{', '.join(f'{s:.1f}' for s in latencies)} s after each became complete (max {max(latencies):.1f} s)",
          flush=True)


# ---------------------------------------------------------------- plan

def quiet_workers() -> dict[str, object]:
    """deploy/dask-workers.yaml as dotted keys for dask.config.set: the workers' housekeeping quieted."""
    import yaml

    def flat(tree: dict, prefix: str = "") -> dict[str, object]:
        out = {}
        for key, value in tree.items():
            out.update(flat(value, f"{prefix}{key}.") if isinstance(value, dict) else {f"{prefix}{key}": value})
        return out

    return flat(yaml.safe_load((Path(__file__).resolve().parents[1] / "deploy" / "dask-workers.yaml").read_text()))


def small_files(work: Path, files: int, pulses: int) -> Path:
    folder = work / "files"
    if not folder.is_dir():
        folder.mkdir()
        start = time.perf_counter()
        for k in range(files):
            simulate(folder / f"line_{k:03d}.las", pulses, seed=100 + k)
        print(f"# simulated {files} files of {pulses} pulses in {time.perf_counter() - start:.0f} s", flush=True)
    return folder


def bench_plan(work: Path, files: int, pulses: int) -> None:
    import apache_beam as beam
    import dask
    from distributed import Client, LocalCluster

    from fwcore.engine.config import DecompositionConfig
    from pipeline.options import check_beam_args
    from pipeline.outputs import InputNames, expand_inputs
    from pipeline.plan import inputs_to_plan, plan_input, read_plans
    from pipeline.run import Jobs
    from pipeline.transforms import PlanFiles

    paths = expand_inputs([str(small_files(work, files, pulses))])
    inputs = inputs_to_plan(paths, InputNames.of(paths))
    config = DecompositionConfig()
    plan_input(inputs[0], config, 5000)  # numba's kernels loaded in this process
    start = time.perf_counter()
    on_driver = {i.path: plan_input(i, config, 5000) for i in inputs}
    driver_s = time.perf_counter() - start
    for label, settings in (("default", {}), ("quiet workers", quiet_workers())):
        with dask.config.set(settings), LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                     dashboard_address=None) as cluster:
            jobs = Jobs(check_beam_args(["--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                                         f"--dask_client_address={cluster.scheduler_address}"]))
            with Client(cluster.scheduler_address) as client:  # each worker loads numba's kernels before the clock
                client.run(plan_input, inputs[0], config, 5000)
            out = work / f"plan_dask_{label.replace(' ', '_')}"
            shutil.rmtree(out, ignore_errors=True)
            start = time.perf_counter()
            jobs.run(len(inputs), lambda p: p | beam.Create(inputs) | PlanFiles(str(out), config, 5000, spread=False))
            dask_s = time.perf_counter() - start
        same = read_plans(out, inputs) == on_driver
        print(f"plan: {files} files of {pulses} pulses: driver alone {driver_s:.1f} s, Dask job on 2 workers "
              f"({label}) {dask_s:.1f} s ({driver_s / dask_s:.2f} x faster); the same plans: {same}", flush=True)


# ---------------------------------------------------------------- many files against one

def bench_many(work: Path, files: int, pulses: int, large: int) -> None:
    folder = small_files(work, files, pulses)
    big = simulate(work / "large" / "large.las", large, seed=7) if not (work / "large" / "large.las").exists() \
        else work / "large" / "large.las"
    rows = []
    for label, source, n in ((f"{files} files x {pulses}", folder, files * pulses), (f"1 file x {large}", big, large)):
        with PeakMemory() as memory:
            seconds = timed("run", str(source), "--output", str(work / f"many_{n}_{label[0]}"), "--preset", "fast",
                            "--formats", "parquet,las")
        rows.append((label, n, seconds, memory.peak / 2**20))
    print(f"{'many':22} {'pulses':>9} {'run s':>8} {'pulses/s':>9} {'peak RSS MiB':>13}")
    for label, n, seconds, peak in rows:
        print(f"{label:22} {n:9d} {seconds:8.1f} {n / seconds:9.1f} {peak:13.0f}")
    (_, n0, s0, m0), (_, n1, s1, m1) = rows
    print(f"many files / one file: throughput {n0 / s0 / (n1 / s1):.2f} x, peak RSS {m0 / m1:.2f} x", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default="resume,watch,plan,many")
    parser.add_argument("--resume-pulses", type=int, default=40000)
    parser.add_argument("--files", type=int, default=200)
    parser.add_argument("--file-pulses", type=int, default=5000)
    parser.add_argument("--large", type=int, default=1_000_000)
    parser.add_argument("--workdir", default=None)
    args = parser.parse_args()
    logging.getLogger("distributed").setLevel(logging.WARNING)  # the local cluster's chatter
    work = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-survey-"))
    work.mkdir(parents=True, exist_ok=True)
    sections = args.sections.split(",")
    # untimed: numba's cache filled for this checkout, so that no timed run compiles
    fwl("run", str(SAMPLE), "--output", str(work / "warm"), "--limit", "300")
    fwl("run", str(SAMPLE), "--output", str(work / "warm_fast"), "--limit", "300", "--preset", "fast")
    print(f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {os.getloadavg()[0]:.1f}, "
          f"work in {work}", flush=True)
    if "resume" in sections:
        bench_resume(work, args.resume_pulses)
    if "watch" in sections:
        bench_watch(work)
    if "plan" in sections:
        bench_plan(work, args.files, args.file_pulses)
    if "many" in sections:
        bench_many(work, args.files, args.file_pulses, args.large)


if __name__ == "__main__":
    main()
