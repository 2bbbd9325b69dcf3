"""The forest's maps of `fwl grid` from a classified run (pipeline.classify): terrain, surface and canopy
height, and what the waveforms' energy above and below the ground says of the canopy (GEDI L2B's definitions
over each cell's echoes, fwcore.metrics.canopy).

    dtm.tif    the terrain: the ground echoes triangulated tile by tile with an overlap, at cell centres
    dsm.tif    the highest kept echo's top (as chm.tif's: a hard target's is its z)
    chm.tif    the highest vegetation echo's top above the terrain (fwcore.terrain.canopy_height: its centre plus
               half the depth its widening beyond the system pulse implies; 0: echoes, none of them vegetation)
    cover.tif  cos(zenith) (1 - Pgap), Pgap = 1 - rv / (rv + rhov/rhog rg): rv the energy of the vegetation
               echoes, rg of the ground echoes (zenith 0: the echo table does not carry the beam's angle)
    pai.tif    -ln(Pgap) / (rossg omega) (NaN where no ground was seen: saturated)
    pavd.tif   plant area volume density, a band a bin of --bin-height above the terrain
    rh98.tif, rh50.tif  the height above the terrain under which 98 % / 50 % of the cell's echo energy lies

Memory: the grids (a float per cell per map, and the two profiles' bins per cell, float32, as many as the tallest
echo needs), one tile's ground echoes.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from fwcore.grid import Grid, HeightProfile
from fwcore.terrain.canopy_height import echo_tops
from fwcore.terrain.classes import BUILDING, GROUND, VEGETATION
from fwcore.terrain.dtm import interpolate
from fwcore.terrain.profile import cover_and_pai, plant_area_density, relative_heights
from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M, tiles_over
from pipeline.echo_table import kept_batches

SPILL_DIR = ".forest-maps"
ROWS_AT_ONCE = 100_000
PROFILE_TOP_M = 80.0  # the profiles' bins reach the tallest echo, at most this far above the terrain


def run_system_fwhm_ps(run_dir: Path) -> float:
    """The system pulse's FWHM the run measured (run.json's inputs; their median where several): what an echo's
    width is compared with; 0 (no correction) where the run records none."""
    from pipeline.outputs import read_run, recorded_pulse

    pulses = [recorded_pulse(i) for i in read_run(run_dir).get("inputs", [])]
    widths = [float(p.fwhm_ps) for p in pulses if p is not None and p.fwhm_ps]
    return float(np.median(widths)) if widths else 0.0


def tiled_dtm(files: list[Path], grid: Grid, run_dir: Path, tile: float = DEFAULT_TILE_M,
              overlap: float = DEFAULT_OVERLAP_M) -> np.ndarray:
    """The terrain at the grid's cell centres from the ground echoes, tile by tile (spilled per tile under the
    run's .forest-maps/ folder, removed at the end)."""
    import pyarrow as pa

    tiles = tiles_over(grid, tile, overlap)
    boxes = np.array([t.buffered for t in tiles])
    folder = run_dir / SPILL_DIR
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    dtm = np.full((grid.height, grid.width), np.nan)
    writers: dict[int, pq.ParquetWriter] = {}
    try:
        for b in kept_batches(files, ["x", "y", "z", "classification"]):
            g = b["classification"] == GROUND
            x, y, z = b["x"][g], b["y"][g], b["z"][g]
            if not x.size:
                continue
            near = np.flatnonzero((boxes[:, 0] <= x.max()) & (boxes[:, 2] > x.min()) & (boxes[:, 1] <= y.max())
                                  & (boxes[:, 3] > y.min()))
            for k in near:
                inside = tiles[k].in_buffered(x, y)
                if inside.any():
                    table = pa.table({"x": x[inside], "y": y[inside], "z": z[inside]})
                    if k not in writers:
                        writers[k] = pq.ParquetWriter(folder / f"tile-{k}.parquet", table.schema)
                    writers[k].write_table(table)
        for w in writers.values():
            w.close()
        writers.clear()
        for k, t in enumerate(tiles):
            path = folder / f"tile-{k}.parquet"
            if not path.exists():
                continue
            e = pq.read_table(path)
            cx, cy = t.centres()
            dtm[t.row0:t.row1, t.col0:t.col1] = interpolate(*(e.column(c).to_numpy() for c in "xyz"), cx, cy)
            path.unlink()
    finally:
        for w in writers.values():
            w.close()
        shutil.rmtree(folder, ignore_errors=True)
    return dtm


def forest_maps(files: list[Path], grid: Grid, run_dir: Path, bin_height: float, z_unit: str,
                energy_unit: str) -> dict:
    """The maps of the module: name -> (bands, dtype, nodata, descriptions), as pipeline.grid writes them."""
    dtm = tiled_dtm(files, grid, run_dir)
    cells = grid.cells
    dsm, chm = np.full(cells, -np.inf), np.full(cells, -np.inf)
    seen = np.zeros(cells, bool)
    rv, rg = np.zeros(cells), np.zeros(cells)
    tallest = max((float(np.nanmax(b["height"])) for b in kept_batches(files, ["x", "y", "height"])
                   if np.isfinite(b["height"]).any()), default=0.0)
    bins = int(math.ceil(min(max(tallest, 0.0), PROFILE_TOP_M) / bin_height)) + 2  # the tallest echo's, and the ground's
    bottom = -bin_height  # one bin below the terrain: the ground's own energy
    energy = HeightProfile(grid, np.full(cells, bottom), bin_height, bins)  # every echo's, for RH
    canopy = HeightProfile(grid, np.full(cells, bottom), bin_height, bins)  # the vegetation's, for PAVD
    energy.sums, canopy.sums = energy.sums.astype(np.float32), canopy.sums.astype(np.float32)  # half the memory
    system_fwhm = run_system_fwhm_ps(run_dir)
    for b in kept_batches(files, ["x", "y", "z", "classification", "height", "energy", "fwhm_ps"]):
        cell = grid.index(b["x"], b["y"])
        inside = cell >= 0
        c = cell[inside]
        code, h = b["classification"][inside], b["height"][inside]
        e = np.nan_to_num(b["energy"][inside])
        seen[c] = True
        np.maximum.at(dsm, c, echo_tops(b["z"][inside], b["fwhm_ps"][inside], system_fwhm))
        veg = np.isin(code, VEGETATION)
        np.maximum.at(chm, c[veg], echo_tops(h[veg], b["fwhm_ps"][inside][veg], system_fwhm))
        rv += np.bincount(c[veg], weights=e[veg], minlength=cells)
        ground = code == GROUND
        rg += np.bincount(c[ground], weights=e[ground], minlength=cells)
        canopy_echo = ~(code == BUILDING) & np.isfinite(h)
        x, y = b["x"][inside], b["y"][inside]
        energy.add(x[canopy_echo], y[canopy_echo], h[canopy_echo], e[canopy_echo])
        canopy.add(x[veg], y[veg], h[veg], e[veg])
    dsm = np.where(seen, dsm, np.nan)
    chm = np.where(seen, np.maximum(np.where(np.isfinite(chm), chm, 0.0), 0.0), np.nan)
    cover, pai = cover_and_pai(rv, rg)
    pai = np.where(np.isfinite(pai), pai, np.nan)
    pavd = np.empty((cells, bins - 1), np.float32)
    rh = {k: np.empty(cells) for k in (98, 50)}
    for lo in range(0, cells, ROWS_AT_ONCE):  # the profiles' float64 arithmetic a slice of cells at a time
        part = slice(lo, lo + ROWS_AT_ONCE)
        p = plant_area_density(canopy.sums[part, 1:], rv[part], rg[part], bin_height)  # from the terrain up
        pavd[part] = np.where(np.isfinite(p), p, np.nan)
        for k in rh:
            rh[k][part] = relative_heights(energy.sums[part], bottom, bin_height, k)
    r = grid.raster
    edges = [(k * bin_height, (k + 1) * bin_height) for k in range(bins - 1)]
    return {
        "dtm.tif": ([r(dtm.ravel())], "float64", np.nan, [f"terrain z [{z_unit}] from the ground echoes"]),
        "dsm.tif": ([r(dsm)], "float64", np.nan, [f"highest kept echo's top z [{z_unit}]"]),
        "chm.tif": ([r(chm)], "float32", np.nan, [f"highest vegetation echo's top above the terrain [{z_unit}]"]),
        "cover.tif": ([r(cover)], "float32", np.nan, ["canopy cover 1 - Pgap (GEDI L2B) from echo energies"]),
        "pai.tif": ([r(pai)], "float32", np.nan, ["plant area index -ln(Pgap) / (0.5 x 1) [m2/m2]"]),
        "pavd.tif": ([r(pavd[:, k]) for k in range(pavd.shape[1])], "float32", np.nan,
                     [f"plant area volume density [m2/m3] {lo:g}-{hi:g} m above the terrain" for lo, hi in edges]),
        "rh98.tif": ([r(rh[98])], "float32", np.nan, [f"height under 98 % of the echo energy [{z_unit}]"]),
        "rh50.tif": ([r(rh[50])], "float32", np.nan, [f"height under 50 % of the echo energy [{z_unit}]"]),
    }

