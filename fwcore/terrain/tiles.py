"""Tiles with an overlap: the terrain of a survey of any size, one tile in memory at a time, without seams.

A tile's core is a block of the map's cells; it is processed with the echoes of its core and of a margin of
`overlap` metres around it, and keeps the results of its core only. Near a core's edge the ground filter and
the interpolation see the same echoes from either side, so neighbouring tiles' terrains meet.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fwcore.grid import Grid
from fwcore.terrain.buildings import building_echoes
from fwcore.terrain.dtm import interpolate
from fwcore.terrain.ground import GroundConfig, classify_ground, last_echoes, low_noise

DEFAULT_TILE_M = 100.0
DEFAULT_OVERLAP_M = 20.0


@dataclasses.dataclass(frozen=True)
class Tile:
    """Rows row0..row1-1 and columns col0..col1-1 of a grid, and the margin around them (metres)."""

    grid: Grid
    row0: int
    row1: int
    col0: int
    col1: int
    overlap: float

    @property
    def core(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the core's cells."""
        g = self.grid
        return (g.west + self.col0 * g.cell, g.north - self.row1 * g.cell, g.west + self.col1 * g.cell,
                g.north - self.row0 * g.cell)

    @property
    def buffered(self) -> tuple[float, float, float, float]:
        xmin, ymin, xmax, ymax = self.core
        return (xmin - self.overlap, ymin - self.overlap, xmax + self.overlap, ymax + self.overlap)

    def in_core(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Points whose cell is the core's (the grid's cell rule: half-open cells)."""
        cell = self.grid.index(x, y)
        row, col = cell // self.grid.width, cell % self.grid.width
        return (cell >= 0) & (row >= self.row0) & (row < self.row1) & (col >= self.col0) & (col < self.col1)

    def in_buffered(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        xmin, ymin, xmax, ymax = self.buffered
        return (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """The core cells' centres, (rows, cols) arrays of x and y."""
        g = self.grid
        cx = g.west + (np.arange(self.col0, self.col1) + 0.5) * g.cell
        cy = g.north - (np.arange(self.row0, self.row1) + 0.5) * g.cell
        return np.broadcast_to(cx[None, :], (cy.size, cx.size)), np.broadcast_to(cy[:, None], (cy.size, cx.size))


def tiles_over(grid: Grid, tile: float = DEFAULT_TILE_M, overlap: float = DEFAULT_OVERLAP_M) -> list[Tile]:
    """The grid cut into tiles of about `tile` metres (a whole number of cells), each with `overlap` metres."""
    if not (tile > 0 and overlap >= 0):
        raise ValueError("the tile size must be positive and the overlap not negative (metres)")
    n = max(int(round(tile / grid.cell)), 1)
    return [Tile(grid, r, min(r + n, grid.height), c, min(c + n, grid.width), overlap)
            for r in range(0, grid.height, n) for c in range(0, grid.width, n)]


@dataclasses.dataclass(frozen=True)
class TileTerrain:
    """One tile's results: per echo given (core and margin) ground, building, low noise and height above the
    terrain; the terrain at the core's cell centres (rows, cols)."""

    ground: np.ndarray
    building: np.ndarray
    height: np.ndarray
    dtm: np.ndarray
    noise: np.ndarray


def tile_terrain(tile: Tile, x: np.ndarray, y: np.ndarray, z: np.ndarray, pulse: np.ndarray,
                 echo_index: np.ndarray, config: GroundConfig = GroundConfig()) -> TileTerrain:
    """Ground, roofs, heights and the terrain of a tile from its kept echoes (core and margin)."""
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    cx, cy = tile.centres()
    if x.size == 0:
        return TileTerrain(np.zeros(0, bool), np.zeros(0, bool), np.zeros(0), np.full(cx.shape, np.nan),
                           np.zeros(0, bool))
    last = last_echoes(pulse, echo_index)
    ground = classify_ground(x, y, z, last, config)
    g = np.flatnonzero(ground)
    # one triangulation for the echoes' heights and the cells' terrain
    surface = interpolate(x[g], y[g], z[g], np.concatenate([x, cx.ravel()]), np.concatenate([y, cy.ravel()]))
    height = z - surface[:x.size]
    _, owner, per_pulse = np.unique(np.asarray(pulse), return_inverse=True, return_counts=True)
    building = building_echoes(x, y, z, height, per_pulse[owner] == 1) & ~ground
    dtm = surface[x.size:].reshape(cx.shape)
    return TileTerrain(ground, building, height, dtm, low_noise(x, y, z) & ~ground)
