"""Biomass against NASA's L4A: the issue's target (agbd within 3 % median, 15 % 90th percentile of L4A on L4A's
quality shots) on a granule triple of one orbit.

    python bench/bench_biomass.py GEDI01_B_*.h5 GEDI04_A_*.h5 [--workdir DIR]

Runs `fwl run` on the L1B (its L2A beside it gives each shot's algorithm and land cover, hence its stratum),
joins the shots to L4A by shot number and prints, on L4A's l4_quality_flag 1 shots, the median and 90th
percentile of |agbd - L4A| / L4A against L4A's prediction of the algorithm the shot's RH came from
(agbd_prediction/agbd_aN, N our agbd_algorithm: L4A's rule, fwcore.metrics.l4a_algorithm), and against L4A's own
agbd (its own algorithm choice: where it is setting group 10 we measure algorithm 5); how often our
agbd_algorithm is L4A's selected_algorithm; with the same for the L4A models on L2A's own rh_aN (the models'
share of the difference: zero but for float32). Shots L4A predicts 0 (a negative agbd_t) are left out of the
relative figures and counted.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pyarrow.dataset as ds

from fwcore.io.gedi import l2a_beside
from fwcore.metrics.biomass import predict_agbd
from pipeline.cli import main


def _l4a(path: Path) -> dict[int, dict]:
    shots = {}
    with h5py.File(path, "r") as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            g, p = f[beam], f[beam]["agbd_prediction"]
            algorithms = sorted(int(k.removeprefix("agbd_a")) for k in p if k.startswith("agbd_a"))
            by = {a: p[f"agbd_a{a}"][:] for a in algorithms}
            for i, s in enumerate(g["shot_number"][:]):
                shots[int(s)] = {"agbd": float(g["agbd"][i]), "quality": int(g["l4_quality_flag"][i]),
                                 "algorithm": int(g["selected_algorithm"][i]),
                                 "stratum": g["predict_stratum"][i].decode(),
                                 "by": {a: float(v[i]) for a, v in by.items()}}
    return shots


def _l2a(path: Path) -> dict[int, dict]:
    shots = {}
    with h5py.File(path, "r") as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            g = f[beam]
            rh = {a: g[f"geolocation/rh_a{a}"][:] for a in range(1, 7) if f"geolocation/rh_a{a}" in g}
            for i, s in enumerate(g["shot_number"][:]):
                shots[int(s)] = {"algorithm": int(g["selected_algorithm"][i]),
                                 "rh": {a: v[i].astype(np.float64) for a, v in rh.items()}}
    return shots


def _say(name: str, ours: np.ndarray, theirs: np.ndarray) -> None:
    use = theirs > 0
    relative = np.abs(ours[use] - theirs[use]) / theirs[use]
    print(f"{name}: {use.sum()} shots (and {(~use).sum()} L4A predicts 0): median {np.median(relative):.2%}, "
          f"90th percentile {np.percentile(relative, 90):.2%} (target 3 % / 15 %)")


def main_(l1b: Path, l4a: Path, workdir: Path) -> None:
    out = workdir / "run"
    assert main(["run", str(l1b), "--output", str(out), "--formats", "parquet"]) in (0, 1)
    pulses = ds.dataset(str(out / "pulses"), format="parquet").to_table().to_pandas().set_index("pulse_id")
    nasa, l2a = _l4a(l4a), _l2a(l2a_beside(l1b))
    shots = [s for s, v in nasa.items() if v["quality"] == 1 and s in pulses.index and s in l2a
             and np.isfinite(pulses.at[s, "agbd"])]
    same = [s for s in shots if int(pulses.at[s, "agbd_algorithm"]) in nasa[s]["by"]]
    ours = pulses.loc[same, "agbd"].to_numpy()
    _say("ours against L4A's agbd_aN of our agbd_algorithm", ours,
         np.array([nasa[s]["by"][int(pulses.at[s, "agbd_algorithm"])] for s in same]))
    _say("ours against L4A's agbd (its own algorithm choice)", pulses.loc[shots, "agbd"].to_numpy(),
         np.array([nasa[s]["agbd"] for s in shots]))
    agree = np.mean([int(pulses.at[s, "agbd_algorithm"]) == nasa[s]["algorithm"] for s in shots])
    print(f"agbd_algorithm is L4A's selected_algorithm for {agree:.1%} of {len(shots)} shots (10: we measure 5)")
    same = [s for s in same if l2a[s]["algorithm"] in nasa[s]["by"]]
    rh = np.stack([l2a[s]["rh"][l2a[s]["algorithm"]] for s in same])
    models = predict_agbd(rh, np.array([nasa[s]["stratum"] for s in same], dtype=object)).agbd
    _say("the models on L2A's own RH against L4A's agbd_aN", models,
         np.array([nasa[s]["by"][l2a[s]["algorithm"]] for s in same]))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("l1b", type=Path)
    parser.add_argument("l4a", type=Path)
    parser.add_argument("--workdir", type=Path)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        main_(args.l1b, args.l4a, args.workdir or Path(tmp))
