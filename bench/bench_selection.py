"""Model-order selection on long forest waveforms: the engine's rate with and without it, one thread.

    python bench/bench_selection.py [--save kept.pkl | --reference kept.pkl] [--tall-shots 200]

The four files of docs/benchmarks.md's long-waveform table, as `fwl run` hands them to the engine (the file's
system pulse and `--model auto` choice, GEDI's and LVIS's noise set aside by pulses.signal_windows): the bundled
GEDI L1B's real (savanna) beams, a GEDI granule of simulated tall forest (bench_long.repeat_gedi), the shared LVIS
clip and the Mondah tropical-forest shots. Per file, after compilation, the fastest of 3 runs: shots/s a thread
with the default and with the selection off, and with the default per CPU-second of the thread (`cpu`, the
fastest of 5: other jobs' load on a shared machine slows the wall clock, not these), model evaluations (Jacobians)
a shot, echoes dropped and added a shot, kept echoes a shot. `--save` writes every shot's kept echo positions;
`--reference` reads such a file (another checkout's, run with its PYTHONPATH) and prints the share of its kept echoes
this run keeps within 0.1 and 1 sample.
Run it under the benchmark lock, once per checkout, to compare two in one locked run.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_long import GEDI_L1B, repeat_gedi  # noqa: E402

from fwcore.engine.config import DecompositionConfig  # noqa: E402
from fwcore.engine.decompose import decompose_batch  # noqa: E402
from fwcore.instrument.measure import file_system_pulse  # noqa: E402
from fwcore.io import read_pulses  # noqa: E402
from fwcore.pulses import pulse_waveforms  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "examples" / "data"
LVIS_CLIP = DATA / "lvis" / "lvis_level1_clip_shared.h5"
LVIS_MONDAH = DATA / "lvis" / "LVIS_Mondah_level1b.SPLIT.8.h5"


def fastest(run, repeats: int = 3, clock=time.perf_counter):
    """(the last result, the fastest of `repeats` runs' seconds on `clock`)."""
    best, result = float("inf"), None
    for _ in range(repeats):
        start = clock()
        result = run()
        best = min(best, clock() - start)
    return result, best


def kept_positions(result) -> list[np.ndarray]:
    """Each shot's kept echo positions (samples)."""
    return [result.waveform(i).position[result.waveform(i).kept] for i in range(len(result.per_waveform))]


def within(reference: list[np.ndarray], kept: list[np.ndarray], tolerance: float) -> float:
    """Share of the reference's kept echoes that `kept` holds within `tolerance` samples."""
    same = sum(int(np.sum(np.abs(b[None, :] - a[:, None]).min(axis=1) <= tolerance)) if b.size else 0
               for a, b in zip(reference, kept))
    return same / max(sum(a.size for a in reference), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--save", type=Path, default=None)
    parser.add_argument("--reference", type=Path, default=None)
    parser.add_argument("--tall-shots", type=int, default=200)
    args = parser.parse_args()
    tall = Path(tempfile.mkdtemp(prefix="bench_selection_")) / "GEDI01_B_tall.h5"
    repeat_gedi(GEDI_L1B, tall, args.tall_shots, tall=True)
    files = {"GEDI savanna": GEDI_L1B, "GEDI tall": tall, "LVIS clip": LVIS_CLIP, "LVIS Mondah": LVIS_MONDAH}
    reference = pickle.loads(args.reference.read_bytes()) if args.reference else {}
    saved = {}
    config = DecompositionConfig()
    print(f"{'file':13} {'shots':>5} {'model':>11} {'shots/s':>8} {'cpu':>7} {'no select':>9} {'nfev/shot':>9} "
          f"{'dropped':>7} {'added':>5} {'kept':>5} {'ref<0.1':>7} {'ref<1':>6}")
    for name, path in files.items():
        pulses = read_pulses(path)
        system = file_system_pulse(path, len(pulses), config)
        batch = pulse_waveforms(pulses, 0)
        off = config.replace(select_echoes=False)
        for c in (config, off):
            decompose_batch(batch, c, system, threads=1)  # compiled outside the timed runs
        result, seconds = fastest(lambda: decompose_batch(batch, config, system, threads=1))
        _, seconds_off = fastest(lambda: decompose_batch(batch, off, system, threads=1))
        # the thread's CPU seconds: on a shared machine other jobs' load slows the wall clock, not these
        _, cpu = fastest(lambda: decompose_batch(batch, config, system, threads=1), 5, time.thread_time)
        kept = kept_positions(result)
        saved[name] = kept
        per = result.per_waveform
        agree = ((f"{within(reference[name], kept, 0.1):7.3f} {within(reference[name], kept, 1.0):6.3f}")
                 if name in reference else f"{'-':>7} {'-':>6}")
        print(f"{name:13} {len(batch):5d} {system.echo_model(config.model).value:>11} {len(batch) / seconds:8.1f} "
              f"{len(batch) / cpu:7.1f} {len(batch) / seconds_off:9.1f} {per['nfev'].mean():9.1f} "
              f"{per['n_echoes_dropped'].mean():7.2f} {per['n_echoes_added'].mean():5.2f} "
              f"{sum(k.size for k in kept) / len(batch):5.2f} {agree}", flush=True)
    if args.save:
        args.save.write_bytes(pickle.dumps(saved))


if __name__ == "__main__":
    main()
