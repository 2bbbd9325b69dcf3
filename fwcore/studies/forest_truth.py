"""The truth of a forest flight per cell, and the flight written with it (`fwl simulate --scene forest`).

Beside SIM.las and SIM.truth.parquet (the truth of every echo), 1 m GeoTIFFs in the flight's frame:
SIM.truth-dtm.tif (terrain z), SIM.truth-chm.tif (canopy height, 0 where open or roofed), SIM.truth-cover.tif
(the vertical projection of the crowns, 0..1), SIM.truth-pai.tif (plant area index, m2/m2), SIM.truth-pgap.tif
(the gap probability at nadir, exp(-G PAI) averaged over the cell: 1 - it is GEDI L2B's cover) and
SIM.truth-roof.tif (1 where a roof covers the cell).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from fwcore.studies.forest import (G_PROJECTION, STEP_M, TRACE_TOP_M, Forest, ForestConfig, draw_forest, flight_bounds,
                                   simulate_forest_chunks, terrain)
from fwcore.studies.forest_trace import trace_leaf_area
from fwcore.studies.simulate import SceneConfig, SensorConfig
from fwcore.studies.truth import WrittenFlight, write_flight

TRUTH_RASTERS = ("dtm", "chm", "cover", "pai", "pgap", "roof")


@dataclasses.dataclass(frozen=True)
class ForestTruth:
    """The forest per cell (rows north to south from `north`, columns east from `west`): terrain z, canopy
    height above it (0 where open or roofed), crown cover (0..1: the vertical projection of the crowns), plant
    area index (m2/m2), gap probability at nadir, and whether a roof covers the cell (1) or not (0)."""

    west: float
    north: float
    cell: float
    dtm: np.ndarray
    chm: np.ndarray
    cover: np.ndarray
    pai: np.ndarray
    pgap: np.ndarray
    roof: np.ndarray


def forest_truth(drawn: Forest, cell: float = 1.0, sub: int = 4) -> ForestTruth:
    """The truth rasters over the forest's bounds: the terrain at each cell's centre; over sub x sub vertical
    samples of the cell, the highest crown top (what a cell's highest echo approaches), the share within a
    crown, and their mean PAI."""
    xmin, ymin, xmax, ymax = drawn.bounds
    west, south = math.floor(xmin / cell) * cell, math.floor(ymin / cell) * cell
    width, height = int(math.ceil((xmax - west) / cell)), int(math.ceil((ymax - south) / cell))
    north = south + height * cell
    offsets = (np.arange(sub) + 0.5) / sub
    col = (np.arange(width)[None, :, None, None] + offsets[None, None, None, :]) * cell + west
    row = (np.arange(height)[:, None, None, None] + offsets[None, None, :, None]) * cell
    x = np.broadcast_to(col, (height, width, sub, sub)).ravel()
    y = np.broadcast_to(north - row, (height, width, sub, sub)).ravel()
    ground = terrain(x, y, drawn.config)
    hit = np.column_stack([x, y, ground])
    down = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    steps = int(round(TRACE_TOP_M / (STEP_M / 2)))
    lad, roof_up = trace_leaf_area(hit, down, STEP_M / 2, steps, drawn.index, drawn.buildings)
    pai = lad.sum(axis=1) * (STEP_M / 2)
    crowned = lad.max(axis=1) > 0
    top = np.where(crowned, (steps - np.argmax(lad[:, ::-1] > 0, axis=1)) * (STEP_M / 2), 0.0)
    shape = (height, width, sub * sub)
    cx = west + (np.arange(width) + 0.5) * cell
    cy = north - (np.arange(height) + 0.5) * cell
    dtm = terrain(cx[None, :], cy[:, None], drawn.config)
    roof = np.isfinite(roof_up).reshape(shape).mean(axis=2) > 0.5
    return ForestTruth(west, north, cell, dtm, np.where(roof, 0.0, top.reshape(shape).max(axis=2)),
                       crowned.reshape(shape).mean(axis=2), pai.reshape(shape).mean(axis=2),
                       np.exp(-G_PROJECTION * pai).reshape(shape).mean(axis=2), roof.astype(float))


def truth_raster_path(las_path: str | Path, name: str) -> Path:
    """sim.las, "dtm" -> sim.truth-dtm.tif"""
    las_path = Path(las_path)
    return las_path.with_name(f"{las_path.stem}.truth-{name}.tif")


def write_truth_rasters(las_path: str | Path, truth: ForestTruth, crs: str | None = None) -> list[Path]:
    """The truth's rasters as GeoTIFFs beside the flight (float32, NaN nodata)."""
    import rasterio
    from rasterio.transform import Affine

    written = []
    for name in TRUTH_RASTERS:
        values = getattr(truth, name).astype(np.float32)
        path = truth_raster_path(las_path, name)
        with rasterio.open(path, "w", driver="GTiff", width=values.shape[1], height=values.shape[0], count=1,
                           dtype="float32", crs=crs, nodata=np.nan, compress="deflate",
                           transform=Affine(truth.cell, 0.0, truth.west, 0.0, -truth.cell, truth.north)) as out:
            out.write(values, 1)
            out.update_tags(SOFTWARE="fwlidar fwl simulate --scene forest", TRUTH=name)
        written.append(path)
    return written


def read_truth_raster(las_path: str | Path, name: str) -> tuple[np.ndarray, tuple[float, float, float]]:
    """A truth raster and its (west, north, cell)."""
    import rasterio

    with rasterio.open(truth_raster_path(las_path, name)) as src:
        t = src.transform
        return src.read(1).astype(float), (t.c, t.f, t.a)


def write_forest_flight(output: str | Path, n_pulses: int, sensor: SensorConfig, scene: SceneConfig,
                        forest: ForestConfig, seed: int, layout: str = "las13-wdp") -> tuple[WrittenFlight, list[Path]]:
    """The forest flight, its truth table and its truth rasters."""
    output = Path(output)
    drawn = draw_forest(flight_bounds(n_pulses, scene), forest, seed)
    chunks = simulate_forest_chunks(n_pulses, sensor, scene, forest, seed, output.name, drawn)
    flight = write_flight(output, n_pulses, sensor, scene, seed, layout, chunks,
                          {"forest": dataclasses.asdict(forest)})
    return flight, write_truth_rasters(output, forest_truth(drawn))


def scene_footprint(drawn: Forest, x: float, y: float, radius: float, spacing: float = 0.5
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What a large footprint centred at (x, y) sees of the scene itself: vertical rays on a grid of `spacing`
    within `radius`, each step's intercepted share of the ray by Beer's law and what reaches the ground (or the
    roof), as (dx, dy, z, energy) with energies in the scene's proportions (reflectance x share): the truth a
    footprint built from the airborne echoes (fwcore.metrics.footprint) is measured against."""
    from fwcore.studies.forest import GROUND_REFLECTANCE, ROOF_REFLECTANCE, VEGETATION_REFLECTANCE

    offsets = np.arange(-radius, radius + spacing / 2, spacing)
    dx, dy = (a.ravel() for a in np.meshgrid(offsets, offsets))
    inside = dx ** 2 + dy ** 2 <= radius ** 2
    dx, dy = dx[inside], dy[inside]
    ground = terrain(x + dx, y + dy, drawn.config)
    steps = int(round(TRACE_TOP_M / STEP_M))
    lad, roof_up = trace_leaf_area(np.column_stack([x + dx, y + dy, ground]), np.tile([0.0, 0.0, -1.0], (dx.size, 1)),
                                   STEP_M, steps, drawn.index, drawn.buildings)
    q = 1.0 - np.exp(-G_PROJECTION * lad * STEP_M)
    from_top = q[:, ::-1]
    left = np.cumprod(1.0 - from_top, axis=1)
    share = (np.concatenate([np.ones((dx.size, 1)), left[:, :-1]], axis=1) * from_top)[:, ::-1]
    transmitted = left[:, -1]
    heights = (np.arange(steps) + 0.5) * STEP_M
    roofed = np.isfinite(roof_up)
    e = 0.05  # the ground's incidence at nadir: its normal by central differences
    gx = (terrain(x + dx + e, y + dy, drawn.config) - terrain(x + dx - e, y + dy, drawn.config)) / (2 * e)
    gy = (terrain(x + dx, y + dy + e, drawn.config) - terrain(x + dx, y + dy - e, drawn.config)) / (2 * e)
    cos_ground = 1.0 / np.sqrt(1.0 + gx ** 2 + gy ** 2)
    veg = share > 0
    rows = np.nonzero(veg)[0]
    out_dx = np.concatenate([dx[rows], dx])
    out_dy = np.concatenate([dy[rows], dy])
    out_z = np.concatenate([ground[rows] + heights[np.nonzero(veg)[1]],
                            np.where(roofed, ground + np.nan_to_num(roof_up), ground)])
    out_e = np.concatenate([VEGETATION_REFLECTANCE * share[veg],
                            np.where(roofed, ROOF_REFLECTANCE, GROUND_REFLECTANCE * cos_ground * transmitted)])
    return out_dx, out_dy, out_z, out_e
