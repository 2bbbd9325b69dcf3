"""`fwl footprints RUN_DIR (--gedi L2A.h5 | --spacing METRES) [--stratum ENT_NAm] [--output FILE]`: what GEDI would record over a run,
as GeoParquet (default RUN_DIR/footprints.parquet).

Each footprint's waveform is built from the run's kept echoes around it (fwcore.metrics.footprint: their energy
on a common vertical axis, weighted by GEDI's Gaussian footprint, through GEDI's pulse) and measured as GEDI's
L2A and L2B measure theirs (fwcore.metrics). Footprints are centred on a granule's shots (their lowest mode's
latitude and longitude, in the run's CRS) or on a square grid of `spacing` over the run; a footprint centred
less than two sigmas (11 m) inside the echoes' extent is left out. Each footprint's biomass (agbd, agbd_se) is
GEDI L4A's prediction from its RH (fwcore.metrics.biomass), by --stratum or the L2A granule's land cover.

Memory: the echoes within reach of a band of footprints at a time (a band as tall as the footprint's reach).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.metrics.biomass import footprint_biomass
from fwcore.metrics.footprint import FootprintSensor, footprint_metrics, footprint_waveform
from pipeline.echo_table import echo_bounds, echo_files, kept_batches, run_crs_wkt
from pipeline.outputs import read_run

FOOTPRINTS_FILE = "footprints.parquet"
RH_COLUMNS = (0, 10, 25, 50, 75, 90, 95, 98, 100)
LOG = logging.getLogger("fwl")
INSIDE_SIGMAS = 2.0  # a footprint's centre at least this many of its sigmas inside the echoes' extent


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
                   sensor: FootprintSensor = FootprintSensor(), stratum: str | None = None) -> Path:
    """The footprints of a finished run (see the module) into `output`; its path. Each footprint's biomass by
    GEDI L4A's model of `stratum` (e.g. ENT_NAm), or of the stratum a version 002 L2A granule (`gedi`) names
    for its shot; none without either (agbd_reason)."""
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
    rows = _measure(files, shots["x"], shots["y"], sensor)
    output = run_dir / FOOTPRINTS_FILE if output is None else Path(output)
    _write(output, shots, rows, wkt, sensor, stratum)
    return output


def _measure(files: list[Path], cx: np.ndarray, cy: np.ndarray, sensor: FootprintSensor) -> list[dict]:
    """Each footprint's metrics, a band of footprints (by y) at a time."""
    from scipy.spatial import cKDTree

    reach = sensor.radius_m
    out: list[dict] = [{} for _ in range(cx.size)]
    if cx.size == 0:
        return out
    band = 4 * reach
    for low in np.arange(cy.min(), cy.max() + band, band):
        members = np.flatnonzero((cy >= low) & (cy < low + band))
        if not members.size:
            continue
        tree = cKDTree(np.column_stack([cx[members], cy[members]]))
        parts: list[list[np.ndarray]] = [[] for _ in members]
        for b in kept_batches(files, ["x", "y", "z", "energy"]):
            near = (b["y"] >= low - reach) & (b["y"] < low + band + reach)
            if not near.any():
                continue
            xyz = np.column_stack([b["x"][near], b["y"][near], b["z"][near], b["energy"][near]])
            hits = tree.query_ball_point(xyz[:, :2], reach)
            lengths = np.fromiter((len(h) for h in hits), np.int64, len(hits))
            if lengths.sum() == 0:
                continue
            echo = np.repeat(np.arange(len(hits)), lengths)
            owner = np.concatenate([np.asarray(h, np.int64) for h in hits if h])
            for k in np.unique(owner):
                parts[k].append(xyz[echo[owner == k]])
        for k, i in enumerate(members):
            if not parts[k]:
                out[i] = {"reason": "no echo in the footprint", "n_echoes": 0}
                continue
            e = np.concatenate(parts[k])
            samples, top = footprint_waveform(e[:, 0] - cx[i], e[:, 1] - cy[i], e[:, 2], e[:, 3], sensor)
            out[i] = {**footprint_metrics(samples, top, sensor), "n_echoes": int(len(e))}
    return out


def biomass_columns(rh: np.ndarray, shots: dict, stratum: str | None) -> dict[str, np.ndarray]:
    """Each footprint's agbd, agbd_se, agbd_stratum and agbd_reason (fwcore.metrics.biomass) from its RH."""
    found = footprint_biomass(rh, True, stratum, shots.get("pft_class"), shots.get("region_class"))
    return {"agbd": found.agbd, "agbd_se": found.agbd_se, "agbd_stratum": found.stratum, "agbd_reason": found.reason}


def _write(output: Path, shots: dict, rows: list[dict], wkt: str | None, sensor: FootprintSensor,
           stratum: str | None = None) -> None:
    from pipeline.tables import geo_metadata, wkb_points
    from fwcore.io.crs import crs_projjson

    n = len(rows)
    ground = np.array([r.get("ground_z", np.nan) for r in rows], float)
    rh = np.array([r["rh"] if "rh" in r else np.full(101, np.nan) for r in rows], float).reshape(n, 101)
    columns = {k: v for k, v in shots.items() if k not in ("x", "y", "pft_class", "region_class")}
    columns.update({"x": shots["x"], "y": shots["y"], "ground_z": ground})
    for k in RH_COLUMNS:
        columns[f"rh{k}"] = rh[:, k]
    for name in ("cover", "pai", "rv", "rg"):
        columns[name] = np.array([r.get(name, np.nan) for r in rows], float)
    columns["n_echoes"] = np.array([r.get("n_echoes", 0) for r in rows], np.int64)
    columns["reason"] = np.array([r.get("reason", "") for r in rows], object)
    columns.update(biomass_columns(rh, shots, stratum))
    table = pa.table({k: (pa.array(list(v), pa.string()) if np.asarray(v).dtype == object else v)
                      for k, v in columns.items()})
    table = table.append_column("rh", pa.array(list(rh), pa.list_(pa.float64())))
    for name in ("pai_z", "pavd_z"):
        table = table.append_column(name, pa.array([list(r[name]) if name in r else None for r in rows],
                                                   pa.list_(pa.float64())))
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
