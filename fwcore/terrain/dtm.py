"""Terrain models from ground echoes: a triangulation of the ground thinned to one mean point a metre (linear
inside the ground's hull, the nearest ground outside it), so that the terrain under a canopy or a roof is the
plane of the ground around it."""

from __future__ import annotations

import numpy as np


THIN_CELL_M = 1.0


def thin(gx: np.ndarray, gy: np.ndarray, gz: np.ndarray, cell: float = THIN_CELL_M
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per cell of `cell` metres: the mean of its ground echoes (on a plane the mean lies on it; it
    averages the ranges' noise, and a triangulation of a fifth of the points is five times quicker)."""
    gx, gy, gz = (np.asarray(a, float) for a in (gx, gy, gz))
    if gx.size == 0:
        return gx, gy, gz
    col = np.floor((gx - gx.min()) / cell).astype(np.int64)
    row = np.floor((gy - gy.min()) / cell).astype(np.int64)
    _, owner, counts = np.unique(row * (col.max() + 1) + col, return_inverse=True, return_counts=True)
    return tuple(np.bincount(owner, weights=v) / counts for v in (gx, gy, gz))


def interpolate(gx: np.ndarray, gy: np.ndarray, gz: np.ndarray, x: np.ndarray, y: np.ndarray,
                thin_cell: float | None = THIN_CELL_M) -> np.ndarray:
    """The ground's surface at (x, y): linear on the Delaunay triangulation of the ground echoes (thinned to one
    a `thin_cell`, None: all), the nearest one's z outside their hull; NaN without ground."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
    from threadpoolctl import threadpool_limits

    gx, gy, gz = (np.asarray(a, float) for a in (gx, gy, gz))
    if thin_cell:
        gx, gy, gz = thin(gx, gy, gz, thin_cell)
    x, y = np.asarray(x, float), np.asarray(y, float)
    if gx.size == 0:
        return np.full(x.shape, np.nan)
    origin = np.array([gx.min(), gy.min()])  # a local frame: the triangulation's arithmetic in small numbers
    ground = np.column_stack([gx, gy]) - origin
    query = np.column_stack([x.ravel(), y.ravel()]) - origin
    if gx.size < 3:
        return NearestNDInterpolator(ground, gz)(query).reshape(x.shape)
    z = np.full(query.shape[0], np.nan)
    try:
        inside = np.flatnonzero(_in_hull(ground, query))  # scipy searches every triangle for a point outside
        inside = inside[_snake_order(query[inside], thin_cell or THIN_CELL_M)]  # the hull: not those
        # one BLAS thread: the triangles' barycentric transforms are thousands of 2 x 2 LAPACK solves, which
        # OpenBLAS's threads made 2-20 s a tile on a loaded machine (0.1 s on one)
        with threadpool_limits(limits=1, user_api="blas"):
            z[inside] = LinearNDInterpolator(ground, gz)(query[inside])
    except Exception:  # noqa: BLE001  collinear ground (a single line of echoes): no triangle to be linear on
        pass
    outside = ~np.isfinite(z)
    if outside.any():
        z[outside] = NearestNDInterpolator(ground, gz)(query[outside])
    return z.reshape(x.shape)


def _snake_order(points: np.ndarray, band: float) -> np.ndarray:
    """An order of the points along bands of `band` metres, east then west in turn: scipy walks to each query's
    triangle from the last one's, so that neighbours in a row make it a few steps (in the table's order the walks
    took 15 times longer: 0.5 s for a tile's 37,000 echoes)."""
    row = np.floor((points[:, 1] - points[:, 1].min(initial=0.0)) / band).astype(np.int64)
    return np.lexsort((np.where(row % 2 == 0, points[:, 0], -points[:, 0]), row))


def _in_hull(points: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Queries inside (or on) the convex hull of the points, by its facets' half-planes."""
    from scipy.spatial import ConvexHull

    equations = ConvexHull(points).equations  # a x + b y + c <= 0 inside
    inside = np.ones(query.shape[0], bool)
    for a, b, c in equations:
        inside &= a * query[:, 0] + b * query[:, 1] + c <= 1e-9
    return inside


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
