"""Beams traced through a forest's crowns and buildings: the leaf area density met at each height step.

A numba kernel behind trace_leaf_area; crowns are found through TreeIndex, a grid of the trees whose crown
reaches each cell (compressed rows), so a step looks at a few crowns, not all.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from fwcore._jit import JIT

INDEX_CELL_M = 4.0


@dataclasses.dataclass(frozen=True)
class TreeIndex:
    """Trees (n, 8: x, y, crown centre z, half depth, radius, base density, top factor, shell density) and,
    per grid cell, the trees whose crown's box reaches it: items[start[c]:start[c + 1]]."""

    trees: np.ndarray
    shell_fraction: float
    west: float
    south: float
    cell: float
    width: int
    height: int
    start: np.ndarray
    items: np.ndarray

    @classmethod
    def of(cls, trees: np.ndarray, shell_fraction: float, cell: float = INDEX_CELL_M) -> "TreeIndex":
        trees = np.ascontiguousarray(trees, dtype=np.float64).reshape(-1, 8)
        if not len(trees):
            return cls(trees, shell_fraction, 0.0, 0.0, cell, 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64))
        r = trees[:, 4]
        west, south = float((trees[:, 0] - r).min()), float((trees[:, 1] - r).min())
        width = int(math.floor(((trees[:, 0] + r).max() - west) / cell)) + 1
        height = int(math.floor(((trees[:, 1] + r).max() - south) / cell)) + 1
        c0 = np.floor((trees[:, 0] - r - west) / cell).astype(np.int64)
        c1 = np.floor((trees[:, 0] + r - west) / cell).astype(np.int64)
        r0 = np.floor((trees[:, 1] - r - south) / cell).astype(np.int64)
        r1 = np.floor((trees[:, 1] + r - south) / cell).astype(np.int64)
        cells, owners = [], []
        for t in range(len(trees)):  # a few thousand trees: a Python loop over them is quick
            rows, cols = np.meshgrid(np.arange(r0[t], r1[t] + 1), np.arange(c0[t], c1[t] + 1), indexing="ij")
            cells.append((rows * width + cols).ravel())
            owners.append(np.full(rows.size, t))
        cells, owners = np.concatenate(cells), np.concatenate(owners)
        order = np.argsort(cells, kind="stable")
        start = np.zeros(width * height + 1, np.int64)
        np.cumsum(np.bincount(cells, minlength=width * height), out=start[1:])
        return cls(trees, shell_fraction, west, south, cell, width, height, start, owners[order].astype(np.int64))


def leaf_density(trees: np.ndarray, shell_fraction: float, x: float, y: float, z: float) -> float:
    """The leaf area density (m2/m3) at a point: the sum over the crowns holding it (the reference the kernel
    follows, one point at a time)."""
    return float(_density(trees, np.arange(len(trees)), 0, len(trees), shell_fraction, x, y, z))


@njit(**JIT)
def _density(trees, items, first, last, shell, x, y, z):
    """Crown ellipsoids: base density rising linearly to top factor x base at the top; the outer shell (the
    normalised radius above 1 - shell) holds the shell density."""
    total = 0.0
    for i in range(first, last):
        t = items[i]
        a, r = trees[t, 3], trees[t, 4]
        dz = (z - trees[t, 2]) / a
        if dz < -1.0 or dz > 1.0:
            continue
        dx, dy = (x - trees[t, 0]) / r, (y - trees[t, 1]) / r
        rho2 = dx * dx + dy * dy + dz * dz
        if rho2 > 1.0:
            continue
        if math.sqrt(rho2) >= 1.0 - shell:
            total += trees[t, 7]
        else:
            frac = 0.5 * (dz + 1.0)  # 0 at the crown's base, 1 at its top
            total += trees[t, 5] * (1.0 + (trees[t, 6] - 1.0) * frac)
    return total


@njit(**JIT)
def _trace(hit, beam, step, steps, trees, shell, west, south, cell, width, height, start, items, buildings,
           lad, roof_up):
    for p in range(hit.shape[0]):
        cos = -beam[p, 2]
        roof_up[p] = np.nan
        for k in range(steps - 1, -1, -1):  # from the top down: a roof stops the beam
            up = (k + 0.5) * step
            d = up / cos
            x, y, z = hit[p, 0] - beam[p, 0] * d, hit[p, 1] - beam[p, 1] * d, hit[p, 2] + up
            stop = False
            for b in range(buildings.shape[0]):
                if buildings[b, 0] <= x <= buildings[b, 2] and buildings[b, 1] <= y <= buildings[b, 3] \
                        and z <= buildings[b, 4]:
                    h_roof = buildings[b, 4] - hit[p, 2]
                    xr, yr = hit[p, 0] - beam[p, 0] * h_roof / cos, hit[p, 1] - beam[p, 1] * h_roof / cos
                    on_roof = buildings[b, 0] <= xr <= buildings[b, 2] and buildings[b, 1] <= yr <= buildings[b, 3]
                    roof_up[p] = h_roof if on_roof else up  # through the roof, or into a wall
                    stop = True
                    break
            if stop:
                break
            col, row = int(math.floor((x - west) / cell)), int(math.floor((y - south) / cell))
            if 0 <= col < width and 0 <= row < height:
                c = row * width + col
                lad[p, k] = _density(trees, items, start[c], start[c + 1], shell, x, y, z)


def trace_leaf_area(hit: np.ndarray, beam: np.ndarray, step: float, steps: int, index: TreeIndex,
                    buildings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per beam (its hit on the terrain, its unit direction downwards): the leaf area density at heights
    (k + 0.5) step above the hit, k = 0..steps-1, along the beam, (n, steps); and the height above the hit at
    which a building stops it (NaN: none). Below a roof the density is 0."""
    hit = np.ascontiguousarray(hit, dtype=np.float64).reshape(-1, 3)
    beam = np.ascontiguousarray(beam, dtype=np.float64).reshape(-1, 3)
    if np.any(beam[:, 2] >= 0):
        raise ValueError("beams must point down")
    lad = np.zeros((hit.shape[0], int(steps)))
    roof_up = np.empty(hit.shape[0])
    _trace(hit, beam, float(step), int(steps), index.trees, float(index.shell_fraction), index.west, index.south,
           index.cell, index.width, index.height, index.start, index.items,
           np.ascontiguousarray(buildings, dtype=np.float64).reshape(-1, 5), lad, roof_up)
    return lad, roof_up
