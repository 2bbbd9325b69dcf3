"""Tiles: a partition of the grid's cells, and terrains that meet across a tile's edge (no seam)."""

import numpy as np

from fwcore.grid import Grid
from fwcore.terrain.tiles import Tile, tile_terrain, tiles_over


def test_tiles_partition_the_grid():
    grid = Grid.covering(0, 0, 249.5, 99.5, 1.0)
    tiles = tiles_over(grid, 100.0, 20.0)
    assert len(tiles) == 3
    covered = np.zeros((grid.height, grid.width), int)
    for t in tiles:
        covered[t.row0:t.row1, t.col0:t.col1] += 1
    assert (covered == 1).all()
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 250, 1000), rng.uniform(0, 100, 1000)
    assert sum(t.in_core(x, y).sum() for t in tiles) == 1000


def test_two_tiles_terrains_meet_across_their_edge():
    """Each tile's terrain is computed a few cells past its core's edge, into its neighbour; where both say
    something, they differ by no more than 5 cm (here: the same, since both see the same ground there)."""
    rng = np.random.default_rng(4)
    n = 60_000
    x, y = rng.uniform(0, 200, n), rng.uniform(0, 100, n)
    ground = 80 + 0.1 * x + 2 * np.sin(x / 13) * np.cos(y / 17) + rng.normal(0, 0.03, n)
    tree = rng.random(n) < 0.4
    xs = np.concatenate([x, x[tree]])
    ys = np.concatenate([y, y[tree]])
    zs = np.concatenate([ground, ground[tree] + rng.uniform(5, 20, tree.sum())])
    pulse = np.concatenate([np.arange(n), np.flatnonzero(tree)])
    echo = np.concatenate([np.where(tree, 1, 0), np.zeros(tree.sum(), int)])
    grid = Grid.covering(0, 0, 199.9, 99.9, 1.0)
    # the left tile's core 0-100 m and 5 cells into the right one; the right tile's core 100-200 m
    left, right = Tile(grid, 0, 100, 0, 105, 20.0), Tile(grid, 0, 100, 100, 200, 20.0)
    terrains = []
    for t in (left, right):
        inside = t.in_buffered(xs, ys)
        terrains.append(tile_terrain(t, xs[inside], ys[inside], zs[inside], pulse[inside], echo[inside]).dtm)
    across = terrains[0][:, 100:105] - terrains[1][:, 0:5]
    assert np.abs(across).max() <= 0.05
