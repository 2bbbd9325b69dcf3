"""CPU-microseconds a pulse of a range's work outside the engine (pipeline.stages without Beam), in one process,
for this checkout and, with --against, another one (main) in turn in the same session.

    python bench/bench_range_cpu.py LINE.las [--limit 20000] [--repeats 3] [--against ../main] [--rounds 2]

Each checkout's process plans the file (5,000 points a range), reads and decomposes every range once (the engine,
not counted), then repeats each range's read, geolocate (with radiometry, metrics, tables) and write (Parquet,
LAS, MCAP parts: every default output) `--repeats` times; a stage's figure is its least CPU time over the repeats
(time.process_time: every thread of the process), divided by the pulses. The last line of each says the digests
of the tables and the LAS parts (bench/output_hash.py's), which must match between checkouts. With --against the
checkouts alternate for `--rounds` rounds, so that both see the same load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

ONE = r"""
import json, pickle, sys, tempfile, time, types
from pathlib import Path
sys.path.insert(0, str(Path.cwd()))
import pipeline.timing as timing
timing.time = types.SimpleNamespace(perf_counter=time.process_time, time=time.time)  # the laps in CPU seconds
from bench.output_hash import las_digest, table_digest
from fwcore.engine.config import DecompositionConfig
from pipeline import stages
from pipeline.options import DEFAULT_FORMATS
from pipeline.plan import plan_file

path, limit, repeats = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
config, formats = DecompositionConfig(), frozenset(DEFAULT_FORMATS)
tasks = plan_file(path, Path(path).name, Path(path).stem, config, 5000, limit)
decomposed = [pickle.dumps(stages.decompose_range(stages.read_range(t)[0], config)[0]) for t in tasks]
best = {}
for r in range(repeats + 1):  # the first warms the caches: not counted
    out, laps = Path(tempfile.mkdtemp(prefix="fwl-range-cpu-")), timing.Laps()
    settings = stages.RangeSettings(str(out), config, formats)
    for task, held in zip(tasks, decomposed):
        with laps("read"):
            stages.read_range(task)
        held = pickle.loads(held)  # geolocate filters the echoes in place: a fresh range each repeat
        geolocated = stages.geolocate_range(held, settings.radiometry, "mcap" in formats, laps)
        stages.write_range(geolocated, str(out), formats, False, laps)
    for stage, seconds in laps.seconds.items() if r else ():
        best[stage] = min(best.get(stage, float("inf")), seconds)
pulses = sum(len(pickle.loads(d).pulses) for d in decomposed)
digests = {"echoes": table_digest(sorted((out / "echoes").glob("*.parquet"))),
           "pulses": table_digest(sorted((out / "pulses").glob("*.parquet"))),
           "las": las_digest(sorted(out.rglob("*.las")))}
print(json.dumps({"pulses": pulses, "seconds": best, "digests": digests}))
"""


def measure(root: Path, line: str, limit: int, repeats: int) -> dict:
    """One checkout's figures, in its own process with its own code."""
    done = subprocess.run([sys.executable, "-c", ONE, line, str(limit), str(repeats)], cwd=root, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(root)})
    if done.returncode:
        raise SystemExit(f"{root}: exit {done.returncode}\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def show(name: str, found: dict) -> None:
    us = {s: 1e6 * v / found["pulses"] for s, v in found["seconds"].items()}
    print(f"{name}: {found['pulses']} pulses, outside the engine {sum(us.values()):.1f} CPU-us a pulse")
    print("  " + ", ".join(f"{s} {v:.1f}" for s, v in us.items()))
    print("  digests " + " ".join(f"{k}={v}" for k, v in found["digests"].items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("line", help="a full-waveform file (the RIEGL-like line, the Leica sample)")
    parser.add_argument("--limit", type=int, default=20_000, help="pulses read from it")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--against", default=None, help="another checkout (main), measured in turn")
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    checkouts = {"this": ROOT, **({"against": Path(args.against).resolve()} if args.against else {})}
    for round_ in range(args.rounds):
        for name, root in (reversed(checkouts.items()) if round_ % 2 else checkouts.items()):
            print(f"[{os.getloadavg()[0]:.2f} load] ", end="")
            show(f"{name} ({root.name}), round {round_ + 1}", measure(root, args.line, args.limit, args.repeats))


if __name__ == "__main__":
    main()
