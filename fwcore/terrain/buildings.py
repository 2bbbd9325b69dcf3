"""Roofs among the echoes above the ground: where the beam stops at one flat surface.

A pulse into a crown leaves through its gaps (more echoes below it); a pulse onto a roof returns once. Over
cells of `cell` metres, the echoes at least `min_height` above the terrain are a roof where nearly all of them
are their pulse's only echo and their z spreads no more than a flat roof's (a crown's top is rough).
"""

from __future__ import annotations

import numpy as np

ROOF_CELL_M = 2.0
MIN_ROOF_HEIGHT_M = 2.0
MIN_SINGLE_SHARE = 0.85
MAX_ROUGHNESS_M = 0.15
MIN_ROOF_ECHOES = 3


def building_echoes(x: np.ndarray, y: np.ndarray, z: np.ndarray, height: np.ndarray, single: np.ndarray,
                    cell: float = ROOF_CELL_M) -> np.ndarray:
    """True for echoes on a roof (see the module); `single`: the echo is its pulse's only kept echo."""
    x, y, z, height, single = (np.asarray(a) for a in (x, y, z, height, single))
    out = np.zeros(x.size, bool)
    high = np.flatnonzero(np.isfinite(height) & (height >= MIN_ROOF_HEIGHT_M))
    if high.size == 0:
        return out
    col = np.floor((x[high] - x[high].min()) / cell).astype(np.int64)
    row = np.floor((y[high] - y[high].min()) / cell).astype(np.int64)
    key = row * (col.max() + 1) + col
    _, cell_of, counts = np.unique(key, return_inverse=True, return_counts=True)
    singles = np.bincount(cell_of, weights=single[high].astype(float))
    mean = np.bincount(cell_of, weights=z[high]) / counts
    spread = np.sqrt(np.maximum(np.bincount(cell_of, weights=(z[high] - mean[cell_of]) ** 2) / counts, 0.0))
    roof = (counts >= MIN_ROOF_ECHOES) & (singles >= MIN_SINGLE_SHARE * counts) & (spread <= MAX_ROUGHNESS_M)
    out[high] = roof[cell_of] & single[high]
    return out
