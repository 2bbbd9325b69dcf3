"""Terrain models from ground echoes: a triangulation (linear inside the ground's hull, the nearest ground
outside it), so that the terrain under a canopy or a roof is the plane of the ground around it."""

from __future__ import annotations

import numpy as np


def interpolate(gx: np.ndarray, gy: np.ndarray, gz: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The ground's surface at (x, y): linear on the Delaunay triangulation of the ground echoes, the nearest
    ground echo's z outside their hull; NaN without ground."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    gx, gy, gz = (np.asarray(a, float) for a in (gx, gy, gz))
    x, y = np.asarray(x, float), np.asarray(y, float)
    if gx.size == 0:
        return np.full(x.shape, np.nan)
    origin = np.array([gx.min(), gy.min()])  # a local frame: the triangulation's arithmetic in small numbers
    ground = np.column_stack([gx, gy]) - origin
    query = np.column_stack([x.ravel(), y.ravel()]) - origin
    if gx.size < 3:
        return NearestNDInterpolator(ground, gz)(query).reshape(x.shape)
    try:
        z = LinearNDInterpolator(ground, gz)(query)
    except Exception:  # noqa: BLE001  collinear ground (a single line of echoes): no triangle to be linear on
        z = np.full(query.shape[0], np.nan)
    outside = ~np.isfinite(z)
    if outside.any():
        z[outside] = NearestNDInterpolator(ground, gz)(query[outside])
    return z.reshape(x.shape)


def bilinear(raster: np.ndarray, west: float, north: float, cell: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A raster (rows north to south, values at cell centres) at points, bilinear between the four nearest
    centres, the edge's value beyond the outer centres."""
    raster = np.asarray(raster, float)
    h, w = raster.shape
    fc = np.clip((np.asarray(x, float) - west) / cell - 0.5, 0.0, w - 1.0)
    fr = np.clip((north - np.asarray(y, float)) / cell - 0.5, 0.0, h - 1.0)
    c0, r0 = np.minimum(np.floor(fc).astype(np.int64), max(w - 2, 0)), np.minimum(np.floor(fr).astype(np.int64),
                                                                                   max(h - 2, 0))
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    tc, tr = fc - c0, fr - r0
    top = raster[r0, c0] * (1 - tc) + raster[r0, c1] * tc
    bottom = raster[r1, c0] * (1 - tc) + raster[r1, c1] * tc
    return top * (1 - tr) + bottom * tr
