"""Maps of echoes: a raster grid over the ground and per-cell statistics accumulated batch by batch.

Pure numpy: the caller streams echoes (x, y, z and their values) in batches of any size; the statistics do
not depend on how the echoes were batched (sums, counts, minima and maxima). The vertical profile needs each
cell's lowest echo, so it is accumulated in a second stream, after the first has found the lowest echoes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class Grid:
    """Square cells of `cell` metres, rows from north to south: the GeoTIFF layout. The edges are multiples of
    the cell size, so that grids of the same cell size from different runs line up."""

    west: float
    north: float
    cell: float
    width: int
    height: int

    @classmethod
    def covering(cls, xmin: float, ymin: float, xmax: float, ymax: float, cell: float) -> "Grid":
        if not (cell > 0 and math.isfinite(cell)):
            raise ValueError(f"the cell size must be a positive number of metres, not {cell}")
        west, south = math.floor(xmin / cell) * cell, math.floor(ymin / cell) * cell
        # a point on the east or north edge of the last cell belongs to one more cell
        width = int(math.floor((xmax - west) / cell)) + 1
        height = int(math.floor((ymax - south) / cell)) + 1
        return cls(west, south + height * cell, cell, width, height)

    @property
    def cells(self) -> int:
        return self.width * self.height

    def index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Each point's cell as row * width + column; -1 outside the grid."""
        col = np.floor((np.asarray(x, float) - self.west) / self.cell)
        row = np.floor((self.north - np.asarray(y, float)) / self.cell)
        inside = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return np.where(inside, row * self.width + col, -1).astype(np.int64)

    def transform(self) -> tuple[float, float, float, float, float, float]:
        """The affine transform (a, b, c, d, e, f): x = a col + b row + c, y = d col + e row + f."""
        return (self.cell, 0.0, self.west, 0.0, -self.cell, self.north)

    def raster(self, values: np.ndarray) -> np.ndarray:
        return np.asarray(values).reshape(self.height, self.width)


class CellStatistics:
    """Per cell: echo count, highest and lowest z, and the mean of named values (NaN values left out)."""

    def __init__(self, grid: Grid, values: tuple[str, ...] = ()):
        self.grid = grid
        self.count = np.zeros(grid.cells, np.int64)
        self.highest = np.full(grid.cells, -np.inf)
        self.lowest = np.full(grid.cells, np.inf)
        self.sums = {name: np.zeros(grid.cells) for name in values}
        self.counts = {name: np.zeros(grid.cells, np.int64) for name in values}

    def add(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, **values: np.ndarray) -> None:
        cell = self.grid.index(x, y)
        inside = cell >= 0
        self.add_cells(cell[inside], np.asarray(z, float)[inside],
                       **{name: np.asarray(v, float)[inside] for name, v in values.items()})

    def add_cells(self, cell: np.ndarray, z: np.ndarray, **values: np.ndarray) -> None:
        """A batch of echoes by their cell (row * width + column, all in the grid): a tile's cells, counted by the
        whole grid's rule, add as the whole grid's would."""
        z = np.asarray(z, float)
        self.count += np.bincount(cell, minlength=self.grid.cells)
        np.maximum.at(self.highest, cell, z)
        np.minimum.at(self.lowest, cell, z)
        for name, v in values.items():
            v = np.asarray(v, float)
            found = ~np.isnan(v)
            self.sums[name] += np.bincount(cell[found], weights=v[found], minlength=self.grid.cells)
            self.counts[name] += np.bincount(cell[found], minlength=self.grid.cells)

    def mean(self, name: str) -> np.ndarray:
        """The mean of a value per cell; NaN where no echo had one."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.counts[name] > 0, self.sums[name] / self.counts[name], np.nan)

    def heights(self) -> tuple[np.ndarray, np.ndarray]:
        """(highest, lowest) per cell; NaN where the cell has no echo."""
        empty = self.count == 0
        return np.where(empty, np.nan, self.highest), np.where(empty, np.nan, self.lowest)


class HeightProfile:
    """Per cell, a value (echo energy) summed in height bins above the cell's lowest echo: bin k holds the
    echoes with k h <= z - lowest < (k + 1) h; the last bin also those above."""

    def __init__(self, grid: Grid, lowest: np.ndarray, bin_height: float, bins: int):
        if not (bin_height > 0 and math.isfinite(bin_height)):
            raise ValueError(f"the bin height must be a positive number of metres, not {bin_height}")
        self.grid, self.lowest, self.bin_height, self.bins = grid, lowest, bin_height, max(int(bins), 1)
        self.sums = np.zeros((grid.cells, self.bins))

    @staticmethod
    def bins_for(highest: np.ndarray, lowest: np.ndarray, bin_height: float) -> int:
        """Enough bins for the tallest cell."""
        tallest = np.nanmax(highest - lowest) if np.isfinite(highest - lowest).any() else 0.0
        return int(math.floor(tallest / bin_height)) + 1

    def add(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, value: np.ndarray) -> None:
        cell = self.grid.index(x, y)
        inside = cell >= 0
        self.add_cells(cell[inside], np.asarray(z, float)[inside], np.asarray(value, float)[inside])

    def add_cells(self, cell: np.ndarray, z: np.ndarray, value: np.ndarray) -> None:
        """Echoes by their cell (row * width + column, all in the grid), as CellStatistics.add_cells."""
        height = np.asarray(z, float) - self.lowest[cell]
        k = np.clip(np.floor(height / self.bin_height), 0, self.bins - 1).astype(np.int64)
        np.add.at(self.sums, (cell, k), np.nan_to_num(np.asarray(value, float)))

    def edges(self) -> list[tuple[float, float]]:
        """Each bin's (from, to) height above the lowest echo, metres; the last is open above."""
        h = self.bin_height
        return [(k * h, (k + 1) * h if k < self.bins - 1 else math.inf) for k in range(self.bins)]
