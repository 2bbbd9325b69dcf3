"""Forest structure on a simulated forest (`fwl simulate --scene forest`) against its truth, and Sylva's chain.

    python bench/bench_forest.py [--pulses 100000] [--seed 11] [--workdir DIR] [--skip-sylva]

fwlidar: `fwl run --preset fast`, `fwl grid --classify --cell 1` (DTM, CHM, classes) and `--cell 5` (cover and
PAI of 5 m blocks), the run given the flight's trajectory (ranges). Sylva 0.3.0 (sylva-rs), its own chain with its defaults: sylva.waveform.decompose, then
sylva.ground.classify_ground_csf, make_dtm, normalize_height, make_chm, on the same flight; its DTM and CHM at
1 m on our grid's bounds. Ground F1: ours matches each kept echo to the truth's by pulse and time (1.5 ns);
Sylva's echoes carry no pulse id, so each is matched to the nearest true echo within 0.5 m in space. Cells
within 10 m of the swath's edge are left out.

"true_echoes": the same maps (pipeline.forest_maps.tile_forest_maps, tile by tile as `fwl grid` cuts them) from
the scene's own true echoes (SIM.truth.parquet: their classes from the truth, heights above the true terrain,
each at its centre), on the same cells: what the flight's sampling allows any decomposition.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def fwl(*args: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline.cli", *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def read_raster(path: Path):
    import rasterio

    from fwcore.studies.forest_evaluate import Raster

    with rasterio.open(path) as src:
        t = src.transform
        return Raster(src.read(1).astype(float), t.c, t.f, t.a)


def truth_rasters(las: Path) -> dict:
    from fwcore.studies.forest_truth import TRUTH_RASTERS, truth_raster_path

    return {name: read_raster(truth_raster_path(las, name)) for name in TRUTH_RASTERS}


def our_ground_scores(run: Path, truth_file: Path) -> dict:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from fwcore.studies.evaluate import match_echoes
    from fwcore.studies.forest_evaluate import ground_scores

    t = pq.read_table(truth_file, columns=["pulse_id", "time_ps", "surface"])
    e = pa.concat_tables([pq.read_table(f, columns=["pulse_id", "time_ps", "kept", "classification"])
                          for f in sorted((run / "echoes").glob("*.parquet"))])
    e = e.filter(e.column("kept"))
    ti, fi = match_echoes(t.column("pulse_id").to_numpy(), t.column("time_ps").to_numpy(),
                          e.column("pulse_id").to_numpy(), e.column("time_ps").to_numpy(), 1500.0)
    truth_ground = np.zeros(e.num_rows, bool)
    truth_ground[fi] = np.asarray(t.column("surface").to_pylist(), object)[ti] == "ground"
    return ground_scores(e.column("classification").to_numpy(zero_copy_only=False) == 2, truth_ground)


def sylva_cloud(las: Path):
    """Sylva's decomposition of the flight as its point cloud, and its seconds."""
    import sylva

    start = time.perf_counter()
    echoes = sylva.waveform.decompose(sylva.waveform.read(str(las)))
    return echoes.to_pointcloud(), time.perf_counter() - start


def sylva_chain(cloud, grid_dtm, truth_file: Path, **csf) -> dict:
    """Sylva's ground, DTM, heights and CHM from its cloud (`csf`: classify_ground_csf's settings, none: its
    defaults)."""
    import pyarrow.parquet as pq
    import sylva
    from scipy.spatial import cKDTree

    from fwcore.studies.forest_evaluate import Raster, ground_scores

    start = time.perf_counter()
    cloud = sylva.ground.classify_ground_csf(cloud, **csf)
    h, w = grid_dtm.values.shape
    bounds = (grid_dtm.west, grid_dtm.north - h * grid_dtm.cell, grid_dtm.west + w * grid_dtm.cell, grid_dtm.north)
    dtm = sylva.ground.make_dtm(cloud, resolution=1.0, bounds=bounds)
    cloud = sylva.ground.normalize_height(cloud, dtm)
    chm = sylva.ground.make_chm(cloud, resolution=1.0, bounds=bounds)
    chain_s = time.perf_counter() - start

    def north_up(r) -> Raster:
        return Raster(np.asarray(r.data, float)[::-1], r.xmin, r.ymin + r.data.shape[0] * r.resolution, r.resolution)

    t = pq.read_table(truth_file, columns=["x", "y", "z", "surface"])
    xyz = np.column_stack([t.column(c).to_numpy() for c in "xyz"])
    d, i = cKDTree(xyz).query(np.column_stack([cloud.x, cloud.y, cloud.z]), distance_upper_bound=0.5)
    surface = np.asarray(t.column("surface").to_pylist(), object)
    truth_ground = (d < 0.5) & (surface[np.minimum(i, len(surface) - 1)] == "ground")
    found = np.asarray(cloud.attrs["classification"]) == 2
    return {"dtm": north_up(dtm), "chm": north_up(chm), "ground": ground_scores(found, truth_ground),
            "chain_s": chain_s, "echoes": int(len(cloud.x))}


def footprint_accuracy(path: Path, seed: int, pulses: int) -> dict:
    """Footprints from the air against the same footprints drawn from the scene (vertical rays every 0.5 m)."""
    import pyarrow.parquet as pq

    from fwcore.studies.forest import ForestConfig, draw_forest, flight_bounds, forest_flight_scene
    from fwcore.studies.forest_truth import scene_footprint
    from fwcore.metrics.footprint import FootprintSensor, footprint_metrics, footprint_waveform

    fp = pq.read_table(path).to_pydict()
    drawn = draw_forest(flight_bounds(pulses, forest_flight_scene()), ForestConfig(), seed)
    s = FootprintSensor()
    d_ground, d_rh98, d_cover = [], [], []
    for x, y, ground, rh98, cover in zip(fp["x"], fp["y"], fp["ground_z"], fp["rh98"], fp["cover"]):
        truth = footprint_metrics(*footprint_waveform(*scene_footprint(drawn, x, y, s.radius_m), s), s)
        d_ground.append(ground - truth.get("ground_z", np.nan))
        d_rh98.append(rh98 - truth["rh"][98] if "rh" in truth else np.nan)
        d_cover.append(cover - truth.get("cover", np.nan))
    return {"footprints": len(d_ground), "footprint_median_abs_dground_m": float(np.nanmedian(np.abs(d_ground))),
            "footprint_median_abs_drh98_m": float(np.nanmedian(np.abs(d_rh98))),
            "footprint_median_abs_dcover": float(np.nanmedian(np.abs(d_cover)))}


def true_echo_maps(truth_file: Path, seed: int, pulses: int, like: "Raster", system_fwhm_ps: float = 0.0) -> dict:
    """The forest maps (chm, cover, pai) the scene's own true echoes give on the grid of `like` (a map of ours)."""
    import pyarrow.parquet as pq

    from fwcore.grid import Grid
    from fwcore.studies.forest import ForestConfig, draw_forest, flight_bounds, forest_flight_scene, terrain
    from fwcore.studies.forest_evaluate import Raster
    from fwcore.terrain.classes import BUILDING, GROUND, HIGH_VEGETATION, UNCLASSIFIED
    from fwcore.terrain.tiles import tiles_over
    from pipeline.forest_maps import ForestSettings, tile_forest_maps
    from pipeline.tiled import TileTask

    t = pq.read_table(truth_file, columns=["pulse_id", "x", "y", "z", "surface", "energy", "range_m"]).to_pydict()
    e = {k: np.asarray(v) for k, v in t.items() if k != "surface"}
    surface = np.asarray(t["surface"], object)
    drawn = draw_forest(flight_bounds(pulses, forest_flight_scene()), ForestConfig(), seed)
    e["height"] = e["z"] - terrain(e["x"], e["y"], drawn.config)
    e["classification"] = np.select([surface == "ground", surface == "vegetation", surface == "roof"],
                                    [GROUND, HIGH_VEGETATION, BUILDING], UNCLASSIFIED).astype(np.uint8)
    e["fwhm_ps"] = np.full(e["x"].size, np.nan)  # each echo's centre: the CHM of the highest true echo
    h, w = like.values.shape
    grid = Grid(like.west, like.north, like.cell, w, h)
    bins = int(np.ceil(np.nanmax(e["height"]))) + 2
    settings = ForestSettings(grid, bins, 1.0, system_fwhm_ps)
    out = {name: np.full((h, w), np.nan) for name in ("chm", "cover", "pai")}
    for k, tile in enumerate(tiles_over(grid)):
        inside = tile.in_buffered(e["x"], e["y"])
        if inside.any():
            maps = tile_forest_maps(TileTask("", k, tile), {c: v[inside] for c, v in e.items()}, settings)
            for name, values in out.items():
                values[tile.row0:tile.row1, tile.col0:tile.col1] = maps[name]
    return {name: Raster(values, like.west, like.north, like.cell) for name, values in out.items()}


def main() -> None:
    from fwcore.studies.forest_evaluate import Raster, block_mean, canopy_accuracy, terrain_accuracy

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pulses", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--workdir")
    parser.add_argument("--skip-sylva", action="store_true")
    args = parser.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="bench-forest-"))
    work.mkdir(parents=True, exist_ok=True)
    las, run = work / f"forest{args.seed}.las", work / f"run{args.seed}"
    seconds = {}
    if not las.exists():
        seconds["simulate"] = fwl("simulate", "--scene", "forest", "--pulses", str(args.pulses), "--seed",
                                  str(args.seed), "--output", str(las), "--overwrite")
    if not (run / "run.json").exists():
        # with the flight's trajectory: each echo's range, which the PAI's energies need (fwcore.terrain.beams)
        seconds["run"] = fwl("run", str(las), "--output", str(run), "--preset", "fast", "--formats", "parquet",
                             "--trajectory", str(las.with_suffix(".trajectory.csv")))
    seconds["classify"] = fwl("classify", str(run))
    seconds["grid 1 m"] = fwl("grid", str(run), "--cell", "1", "--output", str(work / f"grid{args.seed}-1m"))
    seconds["grid 5 m"] = fwl("grid", str(run), "--cell", "5", "--output", str(work / f"grid{args.seed}-5m"))
    truth = truth_rasters(las)
    g1, g5 = work / f"grid{args.seed}-1m", work / f"grid{args.seed}-5m"
    dtm, chm = read_raster(g1 / "dtm.tif"), read_raster(g1 / "chm.tif")
    ours = {"ground": our_ground_scores(run, las.with_name(las.stem + ".truth.parquet")),
            **terrain_accuracy(dtm, chm, truth["dtm"], truth["chm"], truth["roof"])}
    cover5, pai5 = read_raster(g5 / "cover.tif"), read_raster(g5 / "pai.tif")
    seen5 = read_raster(g5 / "count.tif").values > 0
    from scipy.ndimage import binary_erosion

    ours.update(canopy_accuracy(cover5, pai5, truth["pgap"], truth["pai"], truth["cover"],
                                binary_erosion(seen5, iterations=2)))
    # the clumping-corrected PAI (log-averaged over 1 m sub-cells) against the mean PAI, where it has a value
    corrected, mean_pai = read_raster(g5 / "pai_corrected.tif"), block_mean(truth["pai"], pai5)
    both = binary_erosion(seen5, iterations=2) & (mean_pai >= 0.5) & np.isfinite(corrected.values)
    ratio = (corrected.values - mean_pai)[both] / mean_pai[both]
    ours.update({"pai_corrected_median_relative_error": float(np.median(np.abs(ratio))),
                 "pai_corrected_median_bias": float(np.median(ratio)), "pai_corrected_blocks": int(both.sum())})
    # the same maps from the scene's own true echoes, on the same cells: what the sampling allows
    truth_file = las.with_name(las.stem + ".truth.parquet")
    true1, true5 = (true_echo_maps(truth_file, args.seed, args.pulses, like) for like in (chm, pai5))
    true_chm = Raster(np.where(np.isfinite(chm.values), true1["chm"].values, np.nan), chm.west, chm.north, chm.cell)
    true_echoes = {"chm_rmse_canopy_m": terrain_accuracy(dtm, true_chm, truth["dtm"], truth["chm"],
                                                         truth["roof"])["chm_rmse_canopy_m"],
                   **canopy_accuracy(true5["cover"], true5["pai"], truth["pgap"], truth["pai"], truth["cover"],
                                     binary_erosion(seen5, iterations=2))}
    ours["chm_rmse_over_true_echoes"] = ours["chm_rmse_canopy_m"] / true_echoes["chm_rmse_canopy_m"]
    seconds["footprints"] = fwl("footprints", str(run), "--spacing", "10", "--output",
                                str(work / f"footprints{args.seed}.parquet"))
    ours.update(footprint_accuracy(work / f"footprints{args.seed}.parquet", args.seed, args.pulses))
    report = {"pulses": args.pulses, "seed": args.seed, "seconds": seconds, "fwlidar": ours, "true_echoes": true_echoes}
    if not args.skip_sylva:
        cloud, decompose_s = sylva_cloud(las)
        report["sylva_decompose_s"] = decompose_s
        # its defaults (made for TLS), and the cloth of ours (1 m, 0.5 m threshold) for a fairer second look
        for label, csf in (("sylva", {}), ("sylva_our_cloth", {"cloth_resolution": 1.0, "class_threshold": 0.5})):
            s = sylva_chain(cloud, dtm, las.with_name(las.stem + ".truth.parquet"), **csf)
            # Sylva's rasters on our cells: the same cells left out (no echo, the swath's edge)
            report[label] = {"ground": s["ground"], "chain_s": s["chain_s"], **terrain_accuracy(
                Raster(np.where(np.isfinite(chm.values), _on(s["dtm"], dtm), np.nan), dtm.west, dtm.north, dtm.cell),
                Raster(np.where(np.isfinite(chm.values), _on(s["chm"], chm), np.nan), chm.west, chm.north, chm.cell),
                truth["dtm"], truth["chm"], truth["roof"])}
    print(json.dumps(report, indent=1))


def _on(source, target):
    from fwcore.studies.forest_evaluate import on_grid

    return on_grid(source, target)


if __name__ == "__main__":
    main()
