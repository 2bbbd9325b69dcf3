"""The forest's maps of `fwl grid` from a classified run (pipeline.classify): terrain, surface and canopy
height, and what the waveforms' energy above and below the ground says of the canopy (GEDI L2B's definitions
over each cell's echoes, fwcore.metrics.canopy).

    dtm.tif    the terrain: the ground echoes triangulated tile by tile with an overlap, at cell centres
    dsm.tif    the highest kept echo's top (as chm.tif's: a hard target's is its z)
    chm.tif    the highest vegetation echo's top above the terrain (fwcore.terrain.canopy_height: its centre plus
               half the depth its widening beyond the system pulse implies; 0: echoes, none of them vegetation)
    cover.tif  cos(zenith) (1 - Pgap), Pgap = 1 - rv / (rv + rhov/rhog rg): rv the energy of the vegetation
               echoes, rg of the ground echoes (zenith 0: the echo table does not carry the beam's angle)
    pai.tif    GEDI L2B's effective PAI, -ln(Pgap) / (rossg omega), omega 1 (NaN where no ground was seen)
    pai_corrected.tif  the clumping-corrected PAI: the mean over 1 m sub-cells of -ln(Pgap_sub) / rossg, where
               each sub-cell has MIN_SUB_PULSES pulses (cells of 2 m and more; NaN elsewhere)
    pavd.tif   plant area volume density, a band a bin of --bin-height above the terrain
    rh98.tif, rh50.tif  the height above the terrain under which 98 % / 50 % of the cell's echo energy lies

Tile by tile on the runner's workers (pipeline.tiled): each tile's task reads its kept echoes (core and margin)
from the echo table's row groups whose bounds meet them, computes its maps and fwl grid's statistics and profile
(forest_tile: a plain function) into its result under the run's .forest-maps/ folder, and the driver pastes each
tile's core windows into the maps. No echo is read in the driver.
Memory: a tile's echoes a worker; the maps in the driver (a float per cell per map, the PAVD's bins per cell).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import shutil
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fwcore.grid import CellStatistics, Grid, HeightProfile
from fwcore.metrics.canopy import gap_probability, plant_area_index
from fwcore.terrain.beams import beam_positions, pulse_interception_heights, range_normalised
from fwcore.terrain.canopy_height import echo_tops
from fwcore.terrain.classes import BUILDING, GROUND, VEGETATION
from fwcore.terrain.dtm import interpolate
from fwcore.terrain.profile import cover_and_pai, plant_area_density, relative_heights
from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M, tiles_over
from pipeline.echo_table import column_max
from pipeline.tiled import (IN_PROCESS_ECHOES, TileTask, mark_tile, read_tile, result_path, run_tiles, start_work,
                            table_parts, tile_results, tile_tasks)

SPILL_DIR = ".forest-maps"
PROFILE_TOP_M = 80.0  # the profiles' bins reach the tallest echo, at most this far above the terrain
MAP_COLUMNS = ("x", "y", "z", "classification", "height", "energy", "fwhm_ps", "pulse_id", "range_m")
FLOAT32 = ("chm", "cover", "pai", "pai_corrected", "rh98", "rh50")  # as the maps are written
SUB_CELL_M = 1.0  # the clumping correction's sub-cells
MIN_SUB_PULSES = 4  # pulses a sub-cell needs for its own gap probability
STATISTICS = ("reflectance", "amplitude")  # fwl grid's means per cell (pipeline.grid), beside its counts and heights


def run_system_fwhm_ps(run_dir: Path) -> float:
    """The system pulse's FWHM the run measured (run.json's inputs; their median where several): what an echo's
    width is compared with; 0 (no correction) where the run records none."""
    from pipeline.outputs import read_run, recorded_pulse

    pulses = [recorded_pulse(i) for i in read_run(run_dir).get("inputs", [])]
    widths = [float(p.fwhm_ps) for p in pulses if p is not None and p.fwhm_ps]
    return float(np.median(widths)) if widths else 0.0


@dataclasses.dataclass(frozen=True)
class ForestSettings:
    """What every tile's maps need beside its echoes: the profiles' bins, the system pulse, the sub-cells."""

    grid: Grid
    bins: int
    bin_height: float
    system_fwhm_ps: float
    sub_cell_m: float = SUB_CELL_M


def _cells(task: TileTask, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The echoes in the tile's core, and their cell in the core (row-major over its rows and columns): by the
    whole grid's cell rule, so that tiles meet without a gap or a double."""
    t, g = task.tile, task.tile.grid
    cell = g.index(x, y)
    row, col = cell // g.width, cell % g.width
    core = (cell >= 0) & (row >= t.row0) & (row < t.row1) & (col >= t.col0) & (col < t.col1)
    return core, (row[core] - t.row0) * (t.col1 - t.col0) + (col[core] - t.col0)


def forest_tile(task: TileTask, settings: ForestSettings) -> None:
    """A tile's forest maps, on a worker, from its echoes (core and margin: the terrain's triangulation reaches
    past the core's edge) read from the echo table's row groups that meet them, into its result file (the core's
    windows of each map, and of fwl grid's statistics and profile: tile_statistics), then its mark."""
    e = read_tile(task, (*MAP_COLUMNS, *STATISTICS))
    if e:
        tmp = result_path(task, ".tmp.npz")
        np.savez(tmp, **tile_forest_maps(task, {c: e[c] for c in MAP_COLUMNS}, settings),
                 **tile_statistics(task, e, settings.bin_height))
        tmp.replace(result_path(task, ".npz"))
    mark_tile(task)


def tile_forest_maps(task: TileTask, e: dict[str, np.ndarray], s: ForestSettings) -> dict[str, np.ndarray]:
    """The maps of the module over the tile's core cells, (rows, cols[, bins]) arrays."""
    t = task.tile
    shape = (t.row1 - t.row0, t.col1 - t.col0)
    n = shape[0] * shape[1]
    ground = e["classification"] == GROUND
    cx, cy = t.centres()
    dtm = interpolate(e["x"][ground], e["y"][ground], e["z"][ground], cx, cy)
    # a pulse's canopy and ground energies together, where its beam crosses the canopy (fwcore.terrain.beams):
    # at its own leaves' mean height; a gap's pulse at its neighbours'
    canopy_energy = np.nan_to_num(range_normalised(e["energy"], e["range_m"]))
    at = pulse_interception_heights(e["pulse_id"], e["x"], e["y"], e["z"], e["height"], canopy_energy,
                                    np.isin(e["classification"], VEGETATION))
    bx, by = beam_positions(e["pulse_id"], e["x"], e["y"], e["z"], e["height"], at)
    gap = _gap_sums(task, e, bx, by, canopy_energy, n, s)
    core, c = _cells(task, e["x"], e["y"])
    e = {k: v[core] for k, v in e.items()}
    code, h, energy = e["classification"], e["height"], np.nan_to_num(e["energy"])
    veg = np.isin(code, VEGETATION)
    seen = np.bincount(c, minlength=n) > 0
    dsm, chm = np.full(n, -np.inf), np.full(n, -np.inf)
    np.maximum.at(dsm, c, echo_tops(e["z"], e["fwhm_ps"], s.system_fwhm_ps))
    np.maximum.at(chm, c[veg], echo_tops(h[veg], e["fwhm_ps"][veg], s.system_fwhm_ps))
    bottom = -s.bin_height  # one bin below the terrain: the ground's own energy
    k = np.clip(np.floor((np.nan_to_num(h, nan=bottom) - bottom) / s.bin_height), 0, s.bins - 1).astype(np.int64)
    profiled = ~(code == BUILDING) & np.isfinite(h)
    profile = np.bincount(c[profiled] * s.bins + k[profiled], weights=energy[profiled],
                          minlength=n * s.bins).reshape(n, s.bins)  # every echo's energy where it lies, for RH
    rv, rg, canopy = gap["rv"], gap["rg"], gap["canopy"]
    cover, pai = cover_and_pai(rv, rg)
    pavd = plant_area_density(canopy[:, 1:], rv, rg, s.bin_height)  # from the terrain up
    chm = np.where(seen, np.maximum(np.where(np.isfinite(chm), chm, 0.0), 0.0), np.nan)
    maps = {"dsm": np.where(seen, dsm, np.nan), "chm": chm, "cover": cover,
            "pai": np.where(np.isfinite(pai), pai, np.nan),
            "pai_corrected": gap["pai_corrected"],
            "pavd": np.where(np.isfinite(pavd), pavd, np.nan).astype(np.float32),
            "rh98": relative_heights(profile, bottom, s.bin_height, 98),
            "rh50": relative_heights(profile, bottom, s.bin_height, 50)}
    return {"dtm": dtm, **{k: v.reshape(*shape, *v.shape[1:]) for k, v in maps.items()}}


def _gap_sums(task: TileTask, e: dict[str, np.ndarray], bx: np.ndarray, by: np.ndarray, energy: np.ndarray,
              n: int, s: ForestSettings) -> dict[str, np.ndarray]:
    """rv, rg and the canopy's energy profile per core cell, each pulse's echoes in the cell of its beam's
    position (bx, by); and the clumping-corrected PAI over the cells' sub-cells."""
    core, c = _cells(task, bx, by)
    code, h, energy = e["classification"][core], e["height"][core], energy[core]
    veg, ground = np.isin(code, VEGETATION), code == GROUND
    k = np.clip(np.floor((np.nan_to_num(h) + s.bin_height) / s.bin_height), 0, s.bins - 1).astype(np.int64)
    return {"rv": np.bincount(c[veg], weights=energy[veg], minlength=n),
            "rg": np.bincount(c[ground], weights=energy[ground], minlength=n),
            "canopy": np.bincount(c[veg] * s.bins + k[veg], weights=energy[veg],
                                  minlength=n * s.bins).reshape(n, s.bins),
            "pai_corrected": clumping_corrected_pai(bx[core], by[core], c, e["pulse_id"][core], energy, veg, ground,
                                                    n, s)}


def clumping_corrected_pai(x: np.ndarray, y: np.ndarray, c: np.ndarray, pulse: np.ndarray, energy: np.ndarray,
                           veg: np.ndarray, ground: np.ndarray, n: int, s: ForestSettings) -> np.ndarray:
    """Per cell, the mean over its sub-cells of -ln(Pgap) / G (log-averaging, Lang and Xiang 1986): the clumping
    of crowns and gaps within the cell, which -ln(mean Pgap) hides, counted; NaN where a sub-cell has fewer than
    MIN_SUB_PULSES pulses, or the cell is not split (cells under two sub-cells wide). A sub-cell no pulse's
    energy reached the ground through is taken at half one pulse's gap, 1 / (2 n): the least it could show."""
    g = s.grid
    sub = int(round(g.cell / s.sub_cell_m))
    if sub < 2:
        return np.full(n, np.nan)
    col_f, row_f = (x - g.west) / g.cell, (g.north - y) / g.cell
    sc = np.clip(np.floor((col_f - np.floor(col_f)) * sub), 0, sub - 1).astype(np.int64)
    sr = np.clip(np.floor((row_f - np.floor(row_f)) * sub), 0, sub - 1).astype(np.int64)
    key = (c * sub + sr) * sub + sc
    m = n * sub * sub
    rv = np.bincount(key[veg], weights=energy[veg], minlength=m)
    rg = np.bincount(key[ground], weights=energy[ground], minlength=m)
    pairs = np.unique(np.column_stack([key, pulse]), axis=0)
    pulses = np.bincount(pairs[:, 0], minlength=m)
    pgap = np.maximum(gap_probability(rv, rg), 0.5 / np.maximum(pulses, 1))
    sub_pai = plant_area_index(pgap, 1.0).reshape(n, sub * sub)
    enough = (pulses >= MIN_SUB_PULSES).reshape(n, sub * sub).all(axis=1)
    return np.where(enough, sub_pai.mean(axis=1), np.nan)


def tile_statistics(task: TileTask, e: dict[str, np.ndarray], bin_height: float) -> dict[str, np.ndarray]:
    """fwl grid's statistics (fwcore.grid.CellStatistics) and energy profile over the tile's core cells, from its
    echoes in the table's order: each record batch ("batch") adds as the driver's stream of the table would, so
    that the pasted tiles are that stream's maps to the bit. The profile has the bins of the tile's tallest cell."""
    t = task.tile
    core, c = _cells(task, e["x"], e["y"])
    cells = Grid(0.0, 0.0, t.grid.cell, t.col1 - t.col0, t.row1 - t.row0)  # the core's cells, counted by c
    stats = CellStatistics(cells, STATISTICS)
    z, batch = e["z"][core], e["batch"][core]
    values = {k: e[k][core] for k in STATISTICS}
    edges = [0, *(np.flatnonzero(np.diff(batch)) + 1), batch.size]
    for lo, hi in zip(edges[:-1], edges[1:]):
        stats.add_cells(c[lo:hi], z[lo:hi], **{k: v[lo:hi] for k, v in values.items()})
    highest, lowest = stats.heights()
    profile = HeightProfile(cells, lowest, bin_height, HeightProfile.bins_for(highest, lowest, bin_height))
    profile.add_cells(c, z, e["energy"][core])
    return {"count": stats.count, "highest": stats.highest, "lowest": stats.lowest, "profile": profile.sums,
            **{f"sum_{k}": stats.sums[k] for k in STATISTICS}, **{f"n_{k}": stats.counts[k] for k in STATISTICS}}


class ForestMaps(NamedTuple):
    """forest_maps' result: the maps as pipeline.grid writes them, and its statistics and profile of every echo."""

    maps: dict
    statistics: CellStatistics
    profile: HeightProfile


def forest_maps(files: list[Path], grid: Grid, run_dir: Path, bin_height: float, z_unit: str,
                energy_unit: str, beam_args: list[str] | None = None, resume: bool = False,
                tile: float = DEFAULT_TILE_M, overlap: float = DEFAULT_OVERLAP_M) -> ForestMaps:
    """The maps of the module: name -> (bands, dtype, nodata, descriptions), as pipeline.grid writes them, with
    fwl grid's statistics and profile, assembled from the tiles' (no echo is read in the driver); the tiles on
    the runner `beam_args` names (pipeline.tiled), `resume` keeping those an interrupted call finished."""
    tallest = column_max(files, "height", default=0.0)
    bins = int(math.ceil(min(max(tallest, 0.0), PROFILE_TOP_M) / bin_height)) + 2  # the tallest echo's, the ground's
    settings = ForestSettings(grid, bins, bin_height, run_system_fwhm_ps(run_dir))
    folder = run_dir / SPILL_DIR
    parts = table_parts(files)
    tasks = tile_tasks(folder, tiles_over(grid, tile, overlap), parts)
    start_work(folder, {"settings": repr(settings), "tile_m": tile, "overlap_m": overlap,
                         "echo_files": [[f.name, f.stat().st_size] for f in files]}, resume)
    run_tiles(functools.partial(forest_tile, settings=settings), tasks, beam_args,
              small=sum(p.rows for p in parts) <= IN_PROCESS_ECHOES)
    maps = {name: np.full((grid.height, grid.width), np.nan, np.float32 if name in FLOAT32 else np.float64)
            for name in ("dtm", "dsm", "chm", "cover", "pai", "pai_corrected", "rh98", "rh50")}
    pavd = np.full((bins - 1, grid.height, grid.width), np.nan, np.float32)
    stats = CellStatistics(grid, STATISTICS)
    counted = {"count": stats.count, "highest": stats.highest, "lowest": stats.lowest,
               **{f"sum_{k}": stats.sums[k] for k in STATISTICS}, **{f"n_{k}": stats.counts[k] for k in STATISTICS}}
    for t, path in tile_results(tasks, ".npz"):
        window = (slice(t.tile.row0, t.tile.row1), slice(t.tile.col0, t.tile.col1))
        with np.load(path) as part:
            for name, values in maps.items():
                values[window] = part[name]
            pavd[(slice(None), *window)] = np.moveaxis(part["pavd"], -1, 0)
            for name, values in counted.items():
                grid.raster(values)[window] = part[name].reshape(t.tile.row1 - t.tile.row0, -1)
    highest, lowest = stats.heights()
    profile = HeightProfile(grid, lowest, bin_height, HeightProfile.bins_for(highest, lowest, bin_height))
    sums = profile.sums.reshape(grid.height, grid.width, profile.bins)
    for t, path in tile_results(tasks, ".npz"):
        with np.load(path) as part:
            shape = (t.tile.row1 - t.tile.row0, t.tile.col1 - t.tile.col0)
            tile_profile = part["profile"].reshape(*shape, -1)  # the tile's bins: its cells' echoes are all below
            sums[t.tile.row0:t.tile.row1, t.tile.col0:t.tile.col1, :tile_profile.shape[-1]] = tile_profile
    shutil.rmtree(folder, ignore_errors=True)  # kept until here: an interrupted call resumes from it
    return ForestMaps(_described(maps, pavd, bin_height, z_unit), stats, profile)


def _described(maps: dict[str, np.ndarray], pavd: np.ndarray, bin_height: float, z_unit: str) -> dict:
    edges = [(k * bin_height, (k + 1) * bin_height) for k in range(pavd.shape[0])]
    return {
        "dtm.tif": ([maps["dtm"]], "float64", np.nan, [f"terrain z [{z_unit}] from the ground echoes"]),
        "dsm.tif": ([maps["dsm"]], "float64", np.nan, [f"highest kept echo's top z [{z_unit}]"]),
        "chm.tif": ([maps["chm"]], "float32", np.nan, [f"highest vegetation echo's top above the terrain [{z_unit}]"]),
        "cover.tif": ([maps["cover"]], "float32", np.nan, ["canopy cover 1 - Pgap (GEDI L2B) from echo energies"]),
        "pai.tif": ([maps["pai"]], "float32", np.nan, ["effective plant area index -ln(mean Pgap) / (0.5 x 1) [m2/m2]"]),
        "pai_corrected.tif": ([maps["pai_corrected"]], "float32", np.nan,
                              ["clumping-corrected plant area index: the mean over sub-cells of -ln(Pgap) / 0.5 "
                               "[m2/m2]"]),
        "pavd.tif": (list(pavd), "float32", np.nan,
                     [f"plant area volume density [m2/m3] {lo:g}-{hi:g} m above the terrain" for lo, hi in edges]),
        "rh98.tif": ([maps["rh98"]], "float32", np.nan, [f"height under 98 % of the echo energy [{z_unit}]"]),
        "rh50.tif": ([maps["rh50"]], "float32", np.nan, [f"height under 50 % of the echo energy [{z_unit}]"]),
    }
