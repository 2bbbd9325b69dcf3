"""`fwl grid RUN_DIR --cell METRES [--output DIR]`: maps of a run's kept echoes as Cloud Optimized GeoTIFFs,
by default in the run's own grid/ folder (where `fwl view` finds them; a new run into the folder removes them).

    highest.tif      the highest kept echo's z per cell (float64, NaN: no echo)
    lowest.tif       the lowest kept echo's z per cell
    count.tif        kept echoes per cell
    reflectance.tif  their mean reflectance (amplitude.tif, their mean amplitude, where the run has no radiometry)
    profile.tif      echo energy in height bins above the cell's lowest echo, one band a bin (NaN: no echo)
    rh98, rh50, cover, pai, ground .tif   for GEDI and LVIS runs, the mean of the shots' own metrics per cell
                     (pipeline.pulse_maps)
    dtm, dsm, chm, cover, pai, pavd, rh98, rh50 .tif   the forest's (pipeline.forest_maps), where the echoes
                     are classified (`fwl classify RUN`, or `fwl grid --classify`: pipeline.classify)
    agbd.tif, footprints_agbd.tif   the mean biomass (GEDI L4A's models) of the shots, of the footprints
                     fwl footprints --stratum simulated (pipeline.biomass_maps), where predicted
    survey.vpc       a QGIS virtual point cloud over the run's copc/ files (where it has them): the survey as one layer
    fwl-grid.json    what was gridded, how, and the files: the mark of the folder as fwl grid's

The echo table is read a record batch at a time (pyarrow), twice: the statistics, then the profile (its heights
are above each cell's lowest echo, known after the first pass). Only the grids are held: memory grows with
the cells and bins, not with the echoes. Where the forest's maps are made, their tiles make the statistics and
profile too, on the workers (pipeline.forest_maps.tile_statistics), and the driver reads no echo.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from fwcore.grid import CellStatistics, Grid, HeightProfile
from pipeline.biomass_maps import biomass_maps
from pipeline.layout import COPC, GRID_DIR, GRID_MARK, LOCK
from pipeline.echo_table import echo_bounds, echo_files, kept_batches, run_crs_wkt
from pipeline.outputs import OutputFolderError, read_run
from pipeline.pulse_maps import large_footprint_run, shot_metric_maps
from pipeline.tables import COLUMNS

MARK = GRID_MARK
DEFAULT_BIN_HEIGHT_M = 1.0
BLOCK = 256  # COG tiles, pixels a side
VPC_FILE = "survey.vpc"


def claim_output(output: Path) -> None:
    """The output folder: new, empty, or an earlier fwl grid's (its files are replaced); anything else is
    refused, untouched."""
    if output.exists() and not output.is_dir():
        raise OutputFolderError(f"{output}: exists and is not a folder")
    if output.is_dir() and any(p.name != LOCK for p in output.iterdir()):
        mark = output / MARK
        try:
            own = set(json.loads(mark.read_text())["files"]) | {MARK}
        except (OSError, ValueError, KeyError, TypeError):
            raise OutputFolderError(f"{output}: not empty and not an fwl grid output folder (no readable {MARK}); "
                                    f"choose a new or empty folder") from None
        foreign = sorted(p.name for p in output.iterdir() if p.name not in own | {LOCK}
                         and p.name.removesuffix(".tmp") not in own)
        if foreign:
            raise OutputFolderError(f"{output}: holds files fwl grid did not write: {', '.join(foreign[:5])}")
        for name in own:
            for path in (output / name, output / (name + ".tmp")):
                path.unlink(missing_ok=True)
    output.mkdir(parents=True, exist_ok=True)


def _write_cog(path: Path, bands: list[np.ndarray], grid: Grid, crs: str | None, dtype: str, nodata,
               descriptions: list[str], tags: dict[str, str]) -> None:
    """One Cloud Optimized GeoTIFF (GDAL's COG driver: tiled, overviews, IFDs before the data), atomically."""
    import rasterio
    from rasterio.transform import Affine

    tmp = path.with_name(path.name + ".tmp")
    with rasterio.open(tmp, "w", driver="COG", width=grid.width, height=grid.height, count=len(bands), dtype=dtype,
                       crs=crs, transform=Affine(*grid.transform()), nodata=nodata, BLOCKSIZE=BLOCK,
                       COMPRESS="DEFLATE", OVERVIEWS="AUTO", RESAMPLING="NEAREST") as out:
        for i, (band, text) in enumerate(zip(bands, descriptions), start=1):
            out.write(np.asarray(band, dtype=dtype), i)
            out.set_band_description(i, text)
        out.update_tags(**tags)
    tmp.replace(path)


def _statistics(files: list[Path], grid: Grid) -> CellStatistics:
    stats = CellStatistics(grid, ("reflectance", "amplitude"))
    for b in kept_batches(files, ["x", "y", "z", "amplitude", "reflectance"]):
        stats.add(b["x"], b["y"], b["z"], amplitude=b["amplitude"], reflectance=b["reflectance"])
    return stats


def _profile(files: list[Path], grid: Grid, stats: CellStatistics, bin_height: float) -> HeightProfile:
    highest, lowest = stats.heights()
    profile = HeightProfile(grid, lowest, bin_height, HeightProfile.bins_for(highest, lowest, bin_height))
    for b in kept_batches(files, ["x", "y", "z", "energy"]):
        profile.add(b["x"], b["y"], b["z"], b["energy"])
    return profile


def grid_run(run_dir: str | Path, cell: float, output: str | Path | None = None, crs: str | None = None,
             bin_height: float = DEFAULT_BIN_HEIGHT_M, classify: bool = False, beam_args: list[str] | None = None,
             resume: bool = False) -> dict:
    """The maps of a finished run's kept echoes into `output` (None: the run's grid/ folder; see the module);
    what was written, as in fwl-grid.json. `crs` (anything pyproj reads, e.g. EPSG:25832) names the CRS where
    the run's inputs name none or name it wrongly. Where the run's echoes are classified (`fwl classify`, or
    here with `classify`), the forest's maps too (pipeline.forest_maps), tile by tile on the runner `beam_args`
    names; `resume` keeps the tiles an interrupted call finished."""
    import pyproj

    run_dir = Path(run_dir)
    output = run_dir / GRID_DIR if output is None else Path(output)
    read_run(run_dir)  # a folder that is not a finished run is refused here
    files = echo_files(run_dir)
    wkt = pyproj.CRS.from_user_input(crs).to_wkt() if crs else run_crs_wkt(files)
    bounds = echo_bounds(files)
    if bounds is None:
        raise ValueError(f"{run_dir}: the run kept no echo with coordinates: nothing to map")
    grid = Grid.covering(*bounds, cell)
    HeightProfile(grid, np.zeros(0), bin_height, 1)  # the bin height checked before the folder is touched
    claim_output(output)
    forest, stats, profile = {}, None, None
    from pipeline.classify import classify_run, is_classified

    if classify and not is_classified(run_dir):
        classify_run(run_dir, beam_args=beam_args, resume=resume)
    if is_classified(run_dir):
        from pipeline.forest_maps import forest_maps

        files = echo_files(run_dir)
        forest, stats, profile = forest_maps(files, grid, run_dir, bin_height, COLUMNS["z"].unit,
                                             COLUMNS["energy"].unit, beam_args, resume)  # the statistics, tile by tile
    elif large_footprint_run(run_dir):  # GEDI, LVIS: each shot is a footprint's sample of the forest
        forest = shot_metric_maps(run_dir, grid)
    forest = {**forest, **biomass_maps(run_dir, grid)}  # agbd.tif, footprints_agbd.tif where predicted
    if stats is None:  # not classified: no tiles; the statistics a stream of the table
        stats = _statistics(files, grid)
        profile = _profile(files, grid, stats, bin_height)
    return _write_maps(output, run_dir, grid, wkt, stats, profile, bool(crs), forest)


def _write_maps(output: Path, run_dir: Path, grid: Grid, wkt: str | None, stats: CellStatistics,
                profile: HeightProfile, crs_given: bool, forest: dict | None = None) -> dict:
    highest, lowest = stats.heights()
    empty = stats.count == 0
    z_unit = COLUMNS["z"].unit
    has_reflectance = bool(stats.counts["reflectance"].any())
    value = "reflectance" if has_reflectance else "amplitude"
    maps = {
        "highest.tif": ([grid.raster(highest)], "float64", np.nan, [f"highest kept echo z [{z_unit}]"]),
        "lowest.tif": ([grid.raster(lowest)], "float64", np.nan, [f"lowest kept echo z [{z_unit}]"]),
        "count.tif": ([grid.raster(stats.count)], "uint32", None, ["kept echoes"]),
        f"{value}.tif": ([grid.raster(stats.mean(value))], "float32", np.nan,
                         [f"mean {value} [{COLUMNS[value].unit}]"]),
        "profile.tif": ([grid.raster(np.where(empty, np.float32(np.nan), profile.sums[:, k].astype(np.float32)))
                         for k in range(profile.bins)],
                        "float32", np.nan,
                        [f"energy [{COLUMNS['energy'].unit}] {lo:g}-{hi:g} m above the lowest echo"
                         if math.isfinite(hi) else f"energy [{COLUMNS['energy'].unit}] {lo:g} m and more above the "
                         "lowest echo" for lo, hi in profile.edges()]),
        **(forest or {}),
    }
    tags = {"SOFTWARE": "fwlidar fwl grid", "RUN": str(run_dir.resolve()), "CELL_M": f"{grid.cell:g}"}
    for name, (bands, dtype, nodata, descriptions) in maps.items():
        _write_cog(output / name, bands, grid, wkt, dtype, nodata, descriptions, tags)
    written = sorted(maps)
    copc = sorted((run_dir / COPC).glob("*.copc.laz"))
    if copc:  # the survey's point clouds as one QGIS layer
        from pipeline.vpc import write_vpc

        write_vpc(copc, output / VPC_FILE)
        written = sorted([*written, VPC_FILE])
    summary = {"run": str(run_dir.resolve()), "cell_m": grid.cell, "width": grid.width, "height": grid.height,
               "west": grid.west, "north": grid.north, "crs": wkt, "crs_source": "--crs" if crs_given else
               ("the run's echo table" if wkt else "none: the run's inputs name no CRS (give --crs)"),
               "echoes": int(stats.count.sum()), "cells_with_echoes": int((~empty).sum()),
               "mean_of": value, "bin_height_m": profile.bin_height, "bins": profile.bins,
               "files": written}
    tmp = output / (MARK + ".tmp")
    tmp.write_text(json.dumps(summary, indent=2) + "\n")
    tmp.replace(output / MARK)
    return summary
