"""`fwl footprints RUN_DIR (--gedi L2A.h5 | --spacing METRES) [--stratum ENT_NAm] [--output FILE]`: what GEDI would record over a run,
as GeoParquet (default RUN_DIR/footprints.parquet).

Each footprint's waveform is built from the run's kept echoes around it (fwcore.metrics.footprint: their energy
on a common vertical axis, weighted by GEDI's Gaussian footprint, through GEDI's pulse) and measured as GEDI's
L2A and L2B measure theirs (fwcore.metrics). Footprints are centred on a granule's shots (their lowest mode's
latitude and longitude, in the run's CRS) or on a square grid of `spacing` over the run; a footprint centred
less than two sigmas (11 m) inside the echoes' extent is left out. Each footprint's biomass (agbd, agbd_se) is
GEDI L4A's prediction from its RH (fwcore.metrics.biomass), by --stratum or the L2A granule's land cover.

Tile by tile on the runner's workers (pipeline.tiled): the driver spills the kept echoes into tiles of TILE_M with
a margin of the footprint's reach (under the run's .footprints/ folder); each tile measures the footprints centred
in its core (footprint_tile); the driver writes them in the footprints' order.
Memory: a tile's echoes a worker; the footprints' metrics in the driver.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.metrics.biomass import footprint_biomass
from fwcore.grid import Grid
from fwcore.metrics.footprint import FootprintSensor, footprint_metrics, footprint_waveform
from fwcore.terrain.tiles import tiles_over
from pipeline.echo_table import echo_bounds, echo_files, kept_batches, run_crs_wkt
from pipeline.outputs import read_run
from pipeline.tiled import (IN_PROCESS_ECHOES, TileTask, mark_tile, read_spill, result_path, run_tiles, spill,
                            spilled_echoes, start_spill, tile_results)

FOOTPRINTS_FILE = "footprints.parquet"
RH_COLUMNS = (0, 10, 25, 50, 75, 90, 95, 98, 100)
LOG = logging.getLogger("fwl")
INSIDE_SIGMAS = 2.0  # a footprint's centre at least this many of its sigmas inside the echoes' extent
SPILL_DIR = ".footprints"
TILE_M = 200.0  # a tile's core: its margin (the footprint's reach, 16 m for GEDI's) adds a third to its echoes


def grid_centres(bounds: tuple[float, float, float, float], spacing: float,
                 reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres on multiples of `spacing`, at least `reach` inside the bounds."""
    if not (spacing > 0 and math.isfinite(spacing)):
        raise ValueError(f"the spacing must be a positive number of metres, not {spacing}")
    xmin, ymin, xmax, ymax = bounds
    xs = np.arange(math.ceil((xmin + reach) / spacing), math.floor((xmax - reach) / spacing) + 1) * spacing
    ys = np.arange(math.ceil((ymin + reach) / spacing), math.floor((ymax - reach) / spacing) + 1) * spacing
    x, y = np.meshgrid(xs, ys)
    return x.ravel().astype(float), y.ravel().astype(float)


def gedi_shots(path: str | Path, crs_wkt: str) -> dict[str, np.ndarray]:
    """A GEDI L2A granule's shots: shot_number, beam and the lowest mode's position, in the run's CRS."""
    import h5py
    import pyproj

    numbers, beams, lon, lat, cover = [], [], [], [], []
    with h5py.File(path, "r") as f:
        for beam in sorted(k for k in f if k.startswith("BEAM")):
            g = f[beam]
            if "lat_lowestmode" not in g:
                continue
            numbers.append(np.asarray(g["shot_number"][:], np.int64))
            beams.append(np.full(numbers[-1].size, beam))
            lat.append(np.asarray(g["lat_lowestmode"][:], float))
            lon.append(np.asarray(g["lon_lowestmode"][:], float))
            land = g.get("land_cover_data")  # version 002: each shot's biomass stratum (fwcore.metrics.biomass)
            cover.append(np.stack([land["pft_class"][:], land["region_class"][:]], axis=1).astype(np.uint8)
                         if land is not None and "pft_class" in land and "region_class" in land else None)
    if not numbers:
        raise ValueError(f"{path}: no BEAM group with lat_lowestmode: not a GEDI L2A granule")
    to_run = pyproj.Transformer.from_crs("EPSG:4326", pyproj.CRS.from_wkt(crs_wkt), always_xy=True)
    x, y = to_run.transform(np.concatenate(lon), np.concatenate(lat))
    classes = ({"pft_class": np.concatenate(cover)[:, 0], "region_class": np.concatenate(cover)[:, 1]}
               if all(c is not None for c in cover) else {})
    return {"shot_number": np.concatenate(numbers), "beam": np.concatenate(beams), "x": np.asarray(x),
            "y": np.asarray(y), **classes}


def footprints_run(run_dir: str | Path, spacing: float | None = None, gedi: str | Path | None = None,
                   output: str | Path | None = None, crs: str | None = None,
                   sensor: FootprintSensor = FootprintSensor(), beam_args: list[str] | None = None,
                   resume: bool = False, stratum: str | None = None) -> Path:
    """The footprints of a finished run (see the module) into `output`; its path. The tiles run on the runner
    `beam_args` names (pipeline.tiled); `resume` keeps those an interrupted call finished. Each footprint's biomass by GEDI L4A's model of
    `stratum` (e.g. ENT_NAm), or of the stratum a version 002 L2A granule (`gedi`) names for its shot; none without
    either (agbd_reason)."""
    import pyproj

    run_dir = Path(run_dir)
    read_run(run_dir)
    files = echo_files(run_dir)
    bounds = echo_bounds(files)
    if bounds is None:
        raise ValueError(f"{run_dir}: the run kept no echo with coordinates")
    wkt = pyproj.CRS.from_user_input(crs).to_wkt() if crs else run_crs_wkt(files)
    reach = INSIDE_SIGMAS * sensor.sigma_m
    if (spacing is None) == (gedi is None):
        raise ValueError("give the footprints' centres: --gedi L2A.h5 or --spacing METRES (one of them)")
    if gedi is not None:
        if wkt is None:
            raise ValueError(f"{run_dir}: the run's inputs name no CRS: give --crs to place GEDI's shots")
        shots = gedi_shots(gedi, wkt)
        xmin, ymin, xmax, ymax = bounds
        inside = ((shots["x"] >= xmin + reach) & (shots["x"] <= xmax - reach) & (shots["y"] >= ymin + reach)
                  & (shots["y"] <= ymax - reach))
        shots = {k: v[inside] for k, v in shots.items()}
    else:
        x, y = grid_centres(bounds, spacing, reach)
        shots = {"x": x, "y": y}
    if not len(shots["x"]):
        xmin, ymin, xmax, ymax = bounds
        LOG.warning("%s: no footprint centre lies %.0f m (%g footprint sigmas) inside the echoes' extent of "
                    "%.0f x %.0f: give a smaller --spacing, or GEDI shots over the run", run_dir, reach,
                    INSIDE_SIGMAS, xmax - xmin, ymax - ymin)
    metrics = _measure(files, bounds, shots["x"], shots["y"], sensor, run_dir, beam_args, resume)
    output = run_dir / FOOTPRINTS_FILE if output is None else Path(output)
    _write(output, shots, metrics, wkt, sensor, stratum)
    return output


def _measure(files: list[Path], bounds: tuple[float, float, float, float], cx: np.ndarray, cy: np.ndarray,
             sensor: FootprintSensor, run_dir: Path, beam_args: list[str] | None, resume: bool) -> pa.Table:
    """Each footprint's metrics (a row each, in the footprints' order), tile by tile on the runner's workers: a
    tile's footprints are those centred in its core, its echoes those of its core and a margin of the
    footprint's reach (pipeline.tiled)."""
    grid = Grid.covering(*bounds, 1.0)
    folder = run_dir / SPILL_DIR
    tasks = [TileTask(str(folder), k, t) for k, t in enumerate(tiles_over(grid, TILE_M, sensor.radius_m))]
    if not start_spill(folder, {"centres": hashlib.sha256(np.column_stack([cx, cy]).tobytes()).hexdigest(),
                                "sensor": dataclasses.asdict(sensor),
                                "echo_files": [[f.name, f.stat().st_size] for f in files]}, resume):
        spill(kept_batches(files, ["x", "y", "z", "energy"]), tasks, ("x", "y", "z", "energy"))
    run_tiles(functools.partial(footprint_tile, cx=cx, cy=cy, sensor=sensor), tasks, beam_args,
              small=spilled_echoes(folder) <= IN_PROCESS_ECHOES)
    parts = [pq.read_table(path) for _, path in tile_results(tasks)]
    table = pa.concat_tables(parts) if parts else _metric_table(np.zeros(0, np.int64), [])
    table = table.take(np.argsort(table.column("index").to_numpy(), kind="stable"))
    shutil.rmtree(folder, ignore_errors=True)  # kept until here: an interrupted call resumes from it
    if table.num_rows != cx.size:
        raise RuntimeError(f"{run_dir}: {table.num_rows} of {cx.size} footprints measured")
    return table.drop_columns(["index"])


def footprint_tile(task: TileTask, cx: np.ndarray, cy: np.ndarray, sensor: FootprintSensor) -> None:
    """A tile's work, on a worker: the footprints centred in its core measured on its spilled echoes, into its
    result file (their index among all footprints, their metrics), then its mark."""
    from scipy.spatial import cKDTree

    members = np.flatnonzero(task.tile.in_core(cx, cy))
    if members.size:
        e = read_spill(task)
        rows: list[dict] = [{"reason": "no echo in the footprint", "n_echoes": 0} for _ in members]
        if e:
            hits = cKDTree(np.column_stack([e["x"], e["y"]])).query_ball_point(
                np.column_stack([cx[members], cy[members]]), sensor.radius_m)
            for k, (i, near) in enumerate(zip(members, hits)):
                if near:
                    near = np.sort(np.asarray(near, np.int64))  # the echoes in the spill's order, on every runner
                    samples, top = footprint_waveform(e["x"][near] - cx[i], e["y"][near] - cy[i], e["z"][near],
                                                      e["energy"][near], sensor)
                    rows[k] = {**footprint_metrics(samples, top, sensor), "n_echoes": int(near.size)}
        tmp = result_path(task).with_suffix(".tmp")
        pq.write_table(_metric_table(members, rows), tmp)
        tmp.replace(result_path(task))
    mark_tile(task)


def biomass_columns(rh: np.ndarray, shots: dict, stratum: str | None) -> dict[str, np.ndarray]:
    """Each footprint's agbd, agbd_se, agbd_stratum and agbd_reason (fwcore.metrics.biomass) from its RH."""
    found = footprint_biomass(rh, True, stratum, shots.get("pft_class"), shots.get("region_class"))
    return {"agbd": found.agbd, "agbd_se": found.agbd_se, "agbd_stratum": found.stratum, "agbd_reason": found.reason}


def _metric_table(index: np.ndarray, rows: list[dict]) -> pa.Table:
    """The footprints' metric columns, with their index among all footprints."""
    n = len(rows)
    rh = np.array([r["rh"] if "rh" in r else np.full(101, np.nan) for r in rows], float).reshape(n, 101)
    columns = {"index": np.asarray(index, np.int64),
               "ground_z": np.array([r.get("ground_z", np.nan) for r in rows], float)}
    for k in RH_COLUMNS:
        columns[f"rh{k}"] = rh[:, k]
    for name in ("cover", "pai", "rv", "rg"):
        columns[name] = np.array([r.get(name, np.nan) for r in rows], float)
    columns["n_echoes"] = np.array([r.get("n_echoes", 0) for r in rows], np.int64)
    table = pa.table(columns).append_column("reason", pa.array([r.get("reason", "") for r in rows], pa.string()))
    table = table.append_column("rh", pa.array(list(rh), pa.list_(pa.float64())))
    for name in ("pai_z", "pavd_z"):
        table = table.append_column(name, pa.array([list(r[name]) if name in r else None for r in rows],
                                                   pa.list_(pa.float64())))
    return table


def biomass_columns(rh: np.ndarray, shots: dict, stratum: str | None) -> dict[str, np.ndarray]:
    """Each footprint's agbd, agbd_se, agbd_stratum and agbd_reason (fwcore.metrics.biomass) from its RH."""
    found = footprint_biomass(rh, True, stratum, shots.get("pft_class"), shots.get("region_class"))
    return {"agbd": found.agbd, "agbd_se": found.agbd_se, "agbd_stratum": found.stratum, "agbd_reason": found.reason}


def _write(output: Path, shots: dict, metrics: pa.Table, wkt: str | None, sensor: FootprintSensor,
           stratum: str | None = None) -> None:
    from pipeline.tables import geo_metadata, wkb_points
    from fwcore.io.crs import crs_projjson

    ground = metrics.column("ground_z").to_numpy()
    rh = np.array([np.full(101, np.nan) if r is None else r for r in metrics.column("rh").to_pylist()],
                  float).reshape(metrics.num_rows, 101)
    columns = {k: v for k, v in shots.items() if k not in ("x", "y", "pft_class", "region_class")}
    columns.update({"x": shots["x"], "y": shots["y"]})
    # the biomass after the metrics: cheap, in the driver, from each footprint's RH (the shot's L2A land cover)
    biomass = biomass_columns(rh, shots, stratum)
    table = pa.table({k: (pa.array(list(v), pa.string()) if np.asarray(v).dtype.kind in "OU" else v)
                      for k, v in columns.items()})
    for name in metrics.column_names:
        table = table.append_column(metrics.schema.field(name), metrics.column(name))
    for name, values in biomass.items():
        table = table.append_column(name, pa.array(list(values), pa.string()) if values.dtype == object
                                    else pa.array(values))
    z = np.where(np.isfinite(ground), ground, 0.0)
    table = table.append_column("geometry", wkb_points(shots["x"], shots["y"], z))
    meta = geo_metadata(shots["x"], shots["y"], z, crs_projjson(wkt) if wkt else None, covering=False)
    meta[b"fwlidar.footprint"] = json.dumps({"sigma_m": sensor.sigma_m, "pulse_sigma_m": sensor.pulse_sigma_m,
                                             "sample_m": sensor.sample_m}).encode()
    table = table.replace_schema_metadata(meta)
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(output.name + ".tmp")
    pq.write_table(table, tmp)
    tmp.replace(output)
