"""Scale benchmark: simulated flights of growing size through `fwl run`, pulses/s and peak memory.

    python bench/bench_scale.py [--sizes 100000,1000000] [--preset fast] [--optimizer none] [--dask 100000]
                                [--workdir DIR]

For each size, `fwl simulate` writes a flight (not timed with the run), then
`fwl run` decomposes it in a fresh process on the DirectRunner with 2 workers
(parquet and LAS outputs); "sim MiB" is the simulator's peak RSS (it writes the flight
one chunk of pulses at a time). Throughput is pulses over the run's wall time,
start-up included; "steady" is pulses over the time from the first range's
end to the last's (start-up, planning and assembly left out, so sizes compare);
peak memory is the largest sum of RSS over the run's
process and all its children (Beam's workers; with --dask, the cluster's
worker processes too), sampled every 0.2 s. --dask N adds the run of size N
on Beam's Dask runner against a local distributed cluster of 2 workers
(its start-up is printed on its own line and not counted in the run).
A short untimed run first fills numba's cache; run it on a checkout that
does not change meanwhile: a kernel whose source changed recompiles in every
worker process (~40 s each on this machine), which is not throughput.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import PeakMemory, Sampler  # noqa: E402


def fwl(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pipeline.cli", *args], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)


class RangeEnds(Sampler):
    """When each range's progress mark appears under the run's parts/ folder, and its pulses."""

    every = 0.1

    def __init__(self, marks: Path):
        super().__init__()
        self.marks, self.seen = marks, {}

    def sample(self):
        try:
            names = [n for n in os.listdir(self.marks) if n.endswith(".json") and n not in self.seen]
        except FileNotFoundError:
            names = []
        for name in names:
            try:
                self.seen[name] = (time.perf_counter(), int(json.loads((self.marks / name).read_text())["pulses"]))
            except (OSError, ValueError):  # being written: next time
                pass

    def steady_rate(self) -> float:
        """Pulses of all ranges but the first over the time between the first's end and the last's."""
        ends = sorted(self.seen.values())
        if len(ends) < 2 or ends[-1][0] <= ends[0][0]:
            return float("nan")
        return sum(n for _, n in ends[1:]) / (ends[-1][0] - ends[0][0])


def timed_run(las: Path, out: Path, method: list[str], extra: list[str]) -> tuple[float, float, float]:
    with PeakMemory() as memory, RangeEnds(out / "parts") as ends:
        start = time.perf_counter()
        fwl("run", str(las), "--output", str(out), "--formats", "parquet,las", *method, *extra)
        seconds = time.perf_counter() - start
    return seconds, ends.steady_rate(), memory.peak / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="100000,1000000")
    parser.add_argument("--preset", default="fast", help="decomposition preset (fast: LM; paper: MDE)")
    parser.add_argument("--optimizer", help="replaces the preset's optimizer (none: the pipeline without a fit)")
    parser.add_argument("--dask", type=int, default=100000, help="size also run on the Dask runner (0: none)")
    parser.add_argument("--workdir", default=None)
    args = parser.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-scale-"))
    method = ["--preset", args.preset] + (["--optimizer", args.optimizer] if args.optimizer else [])
    label = args.preset + (f"/{args.optimizer}" if args.optimizer else "")
    print(f"{'pulses':>9} {'runner':10} {'preset':7} {'simulate s':>10} {'sim MiB':>8} {'run s':>8} {'pulses/s':>9} "
          f"{'steady':>8} {'peak RSS MiB':>13}", flush=True)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    for n in sorted(set(sizes) | ({args.dask} if args.dask else set())):
        las = work / f"sim_{n}.las"
        with PeakMemory() as simulator:
            start = time.perf_counter()
            fwl("simulate", "--pulses", str(n), "--output", str(las), "--seed", "1")
            simulate = time.perf_counter() - start
        # untimed: numba's cache filled for this checkout, so that no timed run compiles
        fwl("run", str(las), "--output", str(work / "warm"), "--formats", "parquet,las", "--limit", "300", *method)
        runs = []
        if n in sizes:
            runs.append(("direct", []))
        if n == args.dask:
            runs.append(("dask", None))
        for runner, extra in runs:
            if extra is None:
                from distributed import LocalCluster
                start = time.perf_counter()
                with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
                    # the cluster stands for one already running: its start is reported, not counted in the run
                    print(f"# dask: local cluster of 2 worker processes started in {time.perf_counter() - start:.1f} s",
                          flush=True)
                    extra = ["--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                             f"--dask_client_address={c.scheduler_address}"]
                    seconds, steady, peak = timed_run(las, work / f"out_{runner}_{n}", method, extra)
            else:
                seconds, steady, peak = timed_run(las, work / f"out_{runner}_{n}", method, extra)
            print(f"{n:9d} {runner:10} {label:7} {simulate:10.1f} {simulator.peak / 2**20:8.0f} {seconds:8.1f} "
                  f"{n / seconds:9.1f} {steady:8.1f} {peak:13.0f}", flush=True)
        for f in work.glob(f"sim_{n}.*"):
            f.unlink()


if __name__ == "__main__":
    main()
