"""Engine benchmark on the bundled real data: waveforms/s on 1 and 2 cores, fit error, peak memory.

    python bench/bench_engine.py [--repeat N]

Compilation happens in a warm-up call first and is not timed. Fit error is
the method's Eq. 9 (against the denoised samples); "raw" is the same sum
against the raw samples, the measure the published NEON peers are compared by.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from fwcore.config import PRESETS, DecompositionConfig
from fwcore.decompose import WaveformBatch, decompose_batch
from fwcore.io import read_pulses
from fwcore.neon import pulse_fwhm_ps, read_neon_csv
from fwcore.pulses import pulse_waveforms, system_pulse_fwhm_ps
from fwcore.rng import pulse_seed

DATA = Path(__file__).resolve().parents[1] / "examples" / "data"
SETTINGS = {
    "none": dict(optimizer="none"),
    "lm (50 iterations)": dict(optimizer="lm"),
    "fast preset (lm, 20 iterations)": PRESETS["fast"],
    "de (NP 100, G 100)": dict(optimizer="de", population=100, generations=100),
    "de (NP 60, G 480: MDE's evaluations)": dict(optimizer="de", population=60, generations=480),
    "mde (NP 60, G 80, k x t = 5)": dict(),
    "mde-lm": dict(optimizer="mde-lm"),
    "accurate preset (mde + pruning)": PRESETS["accurate"],
}


def neon_batch() -> tuple[WaveformBatch, DecompositionConfig]:
    w = read_neon_csv(DATA / "neon_harvard" / "return_waveforms.csv")
    fwhm = pulse_fwhm_ps(read_neon_csv(DATA / "neon_harvard" / "outgoing_pulses.csv"))
    batch = WaveformBatch.from_waveforms(w.samples, 1000.0, [pulse_seed(0, i) for i in w.waveform_id], w.valid)
    return batch, DecompositionConfig(system_pulse_fwhm_ps=fwhm)


def leica_batch() -> tuple[WaveformBatch, DecompositionConfig]:
    pulses = read_pulses(DATA / "leica_als" / "leica_a.las")
    # the pulse width as the pipeline measures it: from the file's single-return pulses
    return pulse_waveforms(pulses, 0), DecompositionConfig(system_pulse_fwhm_ps=system_pulse_fwhm_ps(pulses))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per setting (best is reported)")
    args = parser.parse_args()
    print(f"{'data':6} {'optimizer':38} {'wf/s 1 core':>11} {'wf/s 2 cores':>12} {'fit err':>8} "
          f"{'raw err':>8} {'RMSE':>6} {'R2':>7} {'evals/wf':>9}")
    for name, make in (("neon", neon_batch), ("leica", leica_batch)):
        batch, base = make()
        for label, changes in SETTINGS.items():
            config = base.replace(**changes)
            decompose_batch(WaveformBatch.from_waveforms([batch.samples[:batch.offsets[1]]], 1000.0, [1]), config)
            rates = {}
            for threads in (1, 2):
                best = np.inf
                for _ in range(args.repeat):
                    start = time.perf_counter()
                    result = decompose_batch(batch, config, threads=threads)
                    best = min(best, time.perf_counter() - start)
                rates[threads] = len(batch) / best
            print(f"{name:6} {label:38} {rates[1]:11.1f} {rates[2]:12.1f} {result.fit_error.mean():8.1f} "
                  f"{result.fit_error_raw.mean():8.1f} {result.rmse.mean():6.2f} {result.r2.mean():7.4f} "
                  f"{result.nfev.mean():9.0f}", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory (RSS): {peak:.0f} MiB")


if __name__ == "__main__":
    main()
