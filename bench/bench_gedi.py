"""GEDI benchmark: NASA's own L2A and L2B against this project's metrics, and a full-size granule's throughput.

    python bench/bench_gedi.py [--l1b GEDI01_B_*.h5] [--shots 100000] [--beams 8] [--workdir DIR]

(1) Runs `fwl run` on the L1B granule (the bundled one by default; L2A and L2B found beside it by orbit), joins
every shot to L2A and L2B by shot number and prints, on L2A's quality_flag 1 shots, the median and 90th
percentile of |dRH25|, |dRH50|, |dRH75|, |dRH98| and |dground|, cover and PAI against L2B, L2B's formulas on
L2B's own rv and rg, and how the decomposition's kept echoes compare with L2A's modes. (2) Writes a granule of
`beams` x `shots` shots in GEDI's layout (fwcore.studies.gedi_granule), runs `fwl run` on it (DirectRunner, 2
workers, Parquet and LAS) and prints shots/s per core end to end and the peak RSS of the run's processes.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import pyarrow.dataset as ds

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import PeakMemory  # noqa: E402

from fwcore.engine.config import DecompositionConfig, Model  # noqa: E402
from fwcore.metrics.canopy import canopy_cover, gap_probability, plant_area_index  # noqa: E402
from fwcore.studies.gedi_granule import BEAMS, write_granule  # noqa: E402

GEDI = Path(__file__).resolve().parents[1] / "examples" / "data" / "gedi"
L1B = GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"


def _beside(l1b: Path, product: str) -> Path:
    parts = l1b.name.split("_")
    return sorted(l1b.parent.glob(f"GEDI02_{product}_{parts[2]}_{parts[3]}_*.h5"))[0]


def _product(path: Path, fields: tuple[str, ...]) -> dict[str, np.ndarray]:
    out: dict[str, list] = {"shot": []}
    with h5py.File(path) as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            out["shot"].append(f[beam]["shot_number"][:].astype(np.int64))
            for k in fields:
                out.setdefault(k, []).append(f[beam][k][:])
    return {k: np.concatenate(v) for k, v in out.items()}


def _row(name: str, d: np.ndarray) -> str:
    d = np.abs(d[np.isfinite(d)])
    return f"{name:10} {np.median(d):8.3f} {np.percentile(d, 90):8.3f} {d.max():8.3f} {d.size:6d}"


def against_nasa(l1b: Path, work: Path, config: DecompositionConfig) -> None:
    from pipeline.run import run

    run([str(l1b)], work / "nasa", config, ("parquet",), points_per_range=2000, watch=False)
    pulses = ds.dataset(str(work / "nasa" / "pulses"), format="parquet").to_table().to_pandas().set_index("pulse_id")
    echoes = ds.dataset(str(work / "nasa" / "echoes"), format="parquet").to_table().to_pandas()
    l2a = _product(_beside(l1b, "A"), ("rh", "elev_lowestmode", "quality_flag", "geolocation/elevs_allmodes_a1",
                                       "geolocation/num_detectedmodes_a1"))
    l2b = _product(_beside(l1b, "B"), ("cover", "pai", "rv", "rg", "rhov", "rhog", "rossg", "omega", "pgap_theta",
                                       "geolocation/local_beam_elevation"))
    good = (l2a["quality_flag"] == 1) & np.isin(l2a["shot"], pulses.index)
    ours = pulses.loc[l2a["shot"][good]]
    rh = np.stack(ours.rh.to_numpy())
    print(f"{good.sum()} quality_flag 1 shots of {len(l2a['shot'])} in L2A; {len(pulses)} decomposed")
    print(f"{'':10} {'median':>8} {'p90':>8} {'max':>8} {'shots':>6}   (m; target median <= 0.02, p90 <= 0.10)")
    for k in (25, 50, 75, 98):
        print(_row(f"RH{k}", rh[:, k] - l2a["rh"][good, k]))
    print(_row("ground", ours.ground_z.to_numpy() - l2a["elev_lowestmode"][good]))
    b = {s: i for i, s in enumerate(l2b["shot"])}
    ib = np.array([b[s] for s in l2a["shot"][good]])
    print(_row("cover", ours.cover.to_numpy() - l2b["cover"][ib]) + "   (target median <= 0.01)")
    print(_row("PAI", ours.pai.to_numpy() - l2b["pai"][ib]) + "   (target median <= 0.02)")
    cz = np.abs(np.sin(l2b["geolocation/local_beam_elevation"].astype(float)))
    pgap = gap_probability(l2b["rv"], l2b["rg"], l2b["rhov"] / l2b["rhog"])
    print(f"L2B's formulas on L2B's rv, rg: max |dPgap| {np.abs(pgap - l2b['pgap_theta']).max():.1e}, "
          f"|dcover| {np.abs(canopy_cover(pgap, cz) - l2b['cover']).max():.1e}, "
          f"|dPAI| {np.abs(plant_area_index(pgap, cz, l2b['rossg'], l2b['omega']) - l2b['pai']).max():.1e}")
    # the decomposition's kept echoes against L2A's modes (algorithm 1's elevations of every detected mode)
    kept = echoes[echoes.kept]
    by_shot = kept.groupby("pulse_id").z.apply(np.asarray)
    counts, nearest, lowest = [], [], []
    for shot, n, modes in zip(l2a["shot"][good], l2a["geolocation/num_detectedmodes_a1"][good],
                              l2a["geolocation/elevs_allmodes_a1"][good]):
        z = by_shot.get(shot, np.zeros(0))
        counts.append((int(n), z.size))
        if z.size:
            nearest += [np.abs(z - m).min() for m in modes[:n]]
            lowest.append(z.min() - modes[:n].min())
    counts = np.array(counts)
    print(f"modes: L2A {counts[:, 0].mean():.2f} a shot, our kept echoes {counts[:, 1].mean():.2f}; same count in "
          f"{np.mean(counts[:, 0] == counts[:, 1]):.0%} of shots; each L2A mode's nearest echo median "
          f"{np.median(nearest):.2f} m; lowest echo - lowest mode median {np.median(lowest):+.2f} m")


def full_granule(work: Path, beams: int, shots: int, config: DecompositionConfig) -> None:
    from pipeline.run import run

    path = work / "GEDI01_B_2026001000000_O99999_T00001_02_003_01.h5"
    began = time.perf_counter()
    write_granule(path, shots, seed=2026, beams=BEAMS[:beams])
    print(f"\nwrote {beams} beams x {shots} shots ({path.stat().st_size / 1e9:.2f} GB) in "
          f"{time.perf_counter() - began:.0f} s")
    with PeakMemory() as memory:
        began = time.perf_counter()
        summary = run([str(path)], work / "full", config, ("parquet", "las"), points_per_range=5000,
                      watch=False)
        seconds = time.perf_counter() - began
    counts = summary["counts"]
    print(f"fwl run (DirectRunner, 2 workers, parquet+las): {counts['pulses_read']} shots read, "
          f"{counts['pulses_decomposed']} decomposed, {counts['pulses_rejected']} rejected in {seconds:.0f} s: "
          f"{counts['pulses_read'] / seconds / 2:.0f} shots/s per core; peak RSS {memory.peak / 2**20:.0f} MiB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--l1b", type=Path, default=L1B)
    parser.add_argument("--beams", type=int, default=8)
    parser.add_argument("--shots", type=int, default=100_000, help="per beam (0: skip the full granule)")
    parser.add_argument("--model", choices=[m.value for m in Model], default=Model.AUTO.value)
    parser.add_argument("--workdir", default=None)
    args = parser.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-gedi-"))
    config = DecompositionConfig(model=Model(args.model))
    against_nasa(args.l1b, work, config)
    if args.shots:
        full_granule(work, args.beams, args.shots, config)


if __name__ == "__main__":
    main()
