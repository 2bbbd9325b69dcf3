"""Small-run benchmark: what a small `fwl run` pays beyond its work (worker processes it does not need).

    python bench/bench_small.py [--repeats 2] [--workdir DIR]

Times `fwl run` (a new process each, as a user runs it; default runner and options, warm numba cache) on
the shared Leica sample as one range, the same as two ranges (--points-per-range 600), and the shared
leica_als/ folder (the same flight as .las and .laz), best of --repeats. Targets: the folder in at most 2x one
file, two ranges in at most 1.5x one range.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FOLDER = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als"
CASES = {"one file": [str(FOLDER / "leica_a.las")],
         "two ranges": [str(FOLDER / "leica_a.las"), "--points-per-range", "600"],
         "leica_als/ folder": [str(FOLDER)]}
TARGETS = {"two ranges": 1.5, "leica_als/ folder": 2.0}


def seconds(args: list[str], output: Path) -> float:
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", *args, "--output", str(output)],
                          capture_output=True, text=True)
    took = time.perf_counter() - began
    if done.returncode != 0:
        raise SystemExit(f"fwl run {' '.join(args)} failed ({done.returncode}): {done.stderr[-2000:]}")
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workdir", help="where the runs go (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.workdir or tmp)
        seconds(CASES["one file"], work / "warm")  # numba's cache and the OS's file cache, warm
        best = {name: min(seconds(case, work / f"{name.split()[0]}-{k}") for k in range(args.repeats))
                for name, case in CASES.items()}
    print(f"{'':20} {'seconds':>8} {'x one file':>11} {'target':>7}")
    for name, took in best.items():
        target = f"<= {TARGETS[name]:g}" if name in TARGETS else ""
        print(f"{name:20} {took:8.2f} {took / best['one file']:11.2f} {target:>7}")


if __name__ == "__main__":
    main()
