"""Long forest waveforms at survey speed: `fwl run` with defaults on LVIS and GEDI files of tall canopy.

    python bench/bench_long.py [--lvis L1B.h5] [--lvis-shots 6000] [--gedi-l1b L1B.h5]
        [--savanna-shots 15000,60000] [--tall-shots 12000] [--only lvis,tall,savanna] [--workdir DIR]

Builds, in NASA's layouts (h5py), (1) a real LVIS L1B file of tropical forest (the shared Mondah shots) repeated
to `lvis-shots` shots, (2) the bundled GEDI L1B's real beams repeated to `savanna-shots` shots, (3) a GEDI granule
of tall forest: the bundled granule's shots and transmitted pulses repeated to `tall-shots`, each received
waveform replaced by a simulated canopy of 15-60 m in 5-15 layers over the ground (1000-1400 samples, GEDI's
pulse); then runs `fwl run` on each (DirectRunner, 2 workers, defaults) and prints shots/s a core end to end, the
plan's seconds (the system pulse's measurement and the model choice), the workers' stage split (their timing
lines: plan, read, decompose, metrics, biomass, tables, sinks, assembly), the engine's model evaluations a shot and
the run's peak RSS.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import PeakMemory  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GEDI_L1B = ROOT / "examples" / "data" / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
PER_SHOT_SECONDS = 1e-3  # LVIS shots' TIME step in a repeated file


def repeat_lvis(source: Path, path: Path, shots: int) -> int:
    """An LVIS L1B of `shots` shots: the source's shots repeated, each copy with its own shot numbers and time."""
    with h5py.File(source) as f, h5py.File(path, "w") as out:
        n = f["SHOTNUMBER"].shape[0]
        index = np.arange(shots) % n
        copy = np.arange(shots) // n
        for key, data in f.items():
            if not isinstance(data, h5py.Dataset):  # ancillary_data: the file's, once
                f.copy(key, out)
                continue
            value = data[:][index]
            if key == "SHOTNUMBER":
                value = (value.astype(np.int64) + copy * 100_000).astype(data.dtype)
            elif key == "TIME":
                value = value + copy * n * PER_SHOT_SECONDS
            elif key.startswith("LON"):
                value = value + copy * 2e-4  # copies side by side, not on top of each other
            out.create_dataset(key, data=value)
    return shots


def _flat(group: h5py.Group, name: str, index: np.ndarray, replace: list | None = None) -> tuple:
    """A GEDI flat waveform array rebuilt for shots `index` (or `replace`'s waveforms): (samples, counts, starts)."""
    counts = group[f"{name[:2]}_sample_count"][:]
    starts = group[f"{name[:2]}_sample_start_index"][:].astype(np.int64) - 1
    flat = group[name][:]
    waves = replace if replace is not None else [flat[starts[i]:starts[i] + counts[i]] for i in index]
    count = np.array([w.size for w in waves], dtype=counts.dtype)
    start = (1 + np.r_[0, np.cumsum(count[:-1].astype(np.int64))]).astype(np.uint64)
    start[count == 0] = 0
    return np.concatenate(waves).astype(np.float32), count, start


def _tall_canopy(rng: np.random.Generator, tx: np.ndarray, noise_mean: float, noise_sd: float) -> np.ndarray:
    """A GEDI return of tall forest: 5-15 Gaussian layers over 15-60 m of canopy and the ground, each made of the
    shot's transmitted pulse (convolved with the layer's depth), on the digitizer's noise; 1000-1400 samples."""
    samples = int(rng.integers(1000, 1401))
    x = np.arange(samples, dtype=float)
    height = rng.uniform(15.0, 60.0) / 0.15  # samples
    ground = rng.uniform(0.6, 0.75) * samples
    pulse = np.clip(tx - np.median(tx[:20]), 0, None)
    pulse = pulse / max(pulse.sum(), 1e-9)
    wave = np.zeros(samples)
    wave[int(ground)] = rng.uniform(1500, 8000)
    for _ in range(int(rng.integers(5, 16))):
        centre = ground - rng.uniform(0.15, 1.0) * height
        wave += rng.uniform(60, 600) * np.exp(-0.5 * ((x - centre) / rng.uniform(2, 10)) ** 2) / 6.0
    signal = np.convolve(wave, pulse, mode="full")[int(np.argmax(pulse)):][:samples]
    return signal + noise_mean + rng.normal(0, noise_sd, samples)


def repeat_gedi(source: Path, path: Path, shots: int, tall: bool, seed: int = 0) -> int:
    """A GEDI L1B of `shots` shots spread over the source's beams: their shots repeated (shot numbers made
    unique), with simulated tall-forest returns instead of the real ones when `tall`."""
    rng = np.random.default_rng(seed)
    with h5py.File(source) as f, h5py.File(path, "w") as out:
        beams = [b for b in f if b.startswith("BEAM")]
        for b, beam in enumerate(beams):
            g = f[beam]
            n = g["shot_number"].shape[0]
            want = shots // len(beams) + (b < shots % len(beams))
            index = np.arange(want) % n
            copy = (np.arange(want) // n).astype(np.uint64)
            o = out.create_group(beam)
            replace = None
            if tall:
                tx, counts, starts = g["txwaveform"][:], g["tx_sample_count"][:], g["tx_sample_start_index"][:] - 1
                replace = [_tall_canopy(rng, tx[int(starts[i]):int(starts[i]) + int(counts[i])].astype(float),
                                        float(g["noise_mean_corrected"][i]), float(g["noise_stddev_corrected"][i]))
                           for i in index]
            for name in ("rxwaveform", "txwaveform"):
                flat, count, start = _flat(g, name, index, replace if name == "rxwaveform" else None)
                o[name], o[f"{name[:2]}_sample_count"], o[f"{name[:2]}_sample_start_index"] = flat, count, start

            def visit(key: str, data) -> None:
                if not isinstance(data, h5py.Dataset) or key in o:
                    return
                value = data[:]
                if value.ndim == 2 and value.shape[1] == n:
                    value = value[:, index]
                elif value.ndim >= 1 and value.shape[0] == n:
                    value = value[index]
                    if key.endswith("shot_number"):
                        value = value + copy * np.uint64(10**7)
                    if tall and key.endswith("lastbin") and key.startswith("geolocation/elevation"):
                        value = out_bin0(g, index) - (o["rx_sample_count"][:] - 1) * 0.1499
                o.create_dataset(key, data=value)
            g.visititems(visit)
        if "METADATA" in f:
            f.copy("METADATA", out)
    return shots


def out_bin0(group: h5py.Group, index: np.ndarray) -> np.ndarray:
    return group["geolocation/elevation_bin0"][:][index]


def run_fwl(path: Path, work: Path, model: str = "auto") -> dict:
    """`fwl run` with defaults (DirectRunner, 2 workers; `model` the echo model, auto by default) on `path`:
    shots/s a core, the run's stage timing, model evaluations a shot, peak RSS."""
    from fwcore.engine.config import DecompositionConfig
    from pipeline.run import run
    from pipeline.timing import read_timings

    out = work / f"run_{path.stem}_{model}"
    with PeakMemory() as memory:
        start = time.perf_counter()
        run([str(path)], out, DecompositionConfig(model=model), ("parquet", "las", "mcap"), points_per_range=5000,
            watch=False)
        seconds = time.perf_counter() - start
    summary = json.loads((out / "run.json").read_text())
    stages: dict[str, float] = {}  # the workers' split (pipeline.timing): the plan, each range's stages, assembly
    for line in read_timings(out / "logs"):
        for name, value in line["seconds"].items():
            stages[name] = round(stages.get(name, 0.0) + value, 2)
    counts = summary.get("counts", {})
    shots = counts.get("pulses_read") or counts.get("pulses")
    timing = summary.get("timing", {})
    return {"file": path.name, "model": model, "shots": shots, "seconds": round(seconds, 1),
            "shots_per_s_core": round(shots / seconds / 2, 1), "timing": timing,
            "stages": stages, "nfev_per_shot": summary.get("engine", {}).get("nfev_per_pulse"),
            "peak_rss_mib": round(memory.peak / 2**20)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lvis", type=Path, default=None, help="an LVIS L1B of tropical forest")
    parser.add_argument("--lvis-shots", type=int, default=6000)
    parser.add_argument("--gedi-l1b", type=Path, default=GEDI_L1B)
    parser.add_argument("--savanna-shots", default="15000,60000",
                        help="comma-separated sizes: memory is flat when 60,000's peak is within 1.25x of 15,000's")
    parser.add_argument("--tall-shots", type=int, default=12000)
    parser.add_argument("--only", default="lvis,tall,savanna")
    parser.add_argument("--workdir", type=Path, default=None)
    parser.add_argument("--model", default="auto", help="the echo model (LVIS's 303-shot forest file chose system)")
    args = parser.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_long_"))
    work.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(","))
    files = []
    if "lvis" in only and args.lvis is not None:
        files.append(work / "lvis_repeated.h5")
        repeat_lvis(args.lvis, files[-1], args.lvis_shots)
    if "tall" in only:
        files.append(work / "GEDI01_B_tall_repeated.h5")
        repeat_gedi(args.gedi_l1b, files[-1], args.tall_shots, tall=True)
    if "savanna" in only:
        for shots in map(int, args.savanna_shots.split(",")):
            files.append(work / f"GEDI01_B_savanna_{shots}.h5")
            repeat_gedi(args.gedi_l1b, files[-1], shots, tall=False)
    for path in files:
        print(json.dumps(run_fwl(path, work, args.model)), flush=True)


if __name__ == "__main__":
    main()
