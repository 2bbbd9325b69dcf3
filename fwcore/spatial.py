"""Where points are on a space-filling curve: a Hilbert key per point over a box, so that rows sorted by it lie
near each other in space and a file's row groups cover compact patches (their statistics then prune box queries).

Pure functions over numpy arrays; no I/O.
"""

from __future__ import annotations

import numpy as np

HILBERT_ORDER = 16  # bits per axis: 65,536 cells a side, centimetres over a survey of kilometres
NO_POSITION = np.iinfo(np.uint64).max  # the key of a point without a finite position: after every other


def hilbert_key(x: np.ndarray, y: np.ndarray, bounds: tuple[float, float, float, float],
                order: int = HILBERT_ORDER) -> np.ndarray:
    """Each point's distance along the Hilbert curve of order `order` over `bounds` (xmin, ymin, xmax, ymax), as
    uint64; points outside are clamped to the box's edge, points without a finite position get NO_POSITION."""
    if not 1 <= order <= 31:
        raise ValueError(f"order must be 1 to 31 bits per axis, not {order}")
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    side = (1 << order) - 1
    finite = np.isfinite(x) & np.isfinite(y)
    cx = _cells(np.where(finite, x, xmin), xmin, xmax, side)
    cy = _cells(np.where(finite, y, ymin), ymin, ymax, side)
    key = np.zeros(x.shape, dtype=np.uint64)
    s = np.uint64(1 << (order - 1))
    while s > 0:  # the classic xy -> d walk, all points at once: one bit of each axis per step
        rx = (cx & s) > 0
        ry = (cy & s) > 0
        key += s * s * ((np.uint64(3) * rx) ^ ry).astype(np.uint64)
        flip = ~ry  # rotate the quadrant so that the curve's next level joins this one's
        swap_x = flip & rx
        cx = np.where(swap_x, np.uint64(side) - cx, cx)  # only the bits below s matter from here on
        cy = np.where(swap_x, np.uint64(side) - cy, cy)
        cx, cy = np.where(flip, cy, cx), np.where(flip, cx, cy)
        s = s >> np.uint64(1)
    key[~finite] = NO_POSITION
    return key


def _cells(v: np.ndarray, low: float, high: float, side: int) -> np.ndarray:
    """Coordinates -> cell numbers 0..side over [low, high] (a box of no extent: all in cell 0)."""
    span = high - low
    if not np.isfinite(span) or span <= 0:
        return np.zeros(v.shape, dtype=np.uint64)
    return np.clip(np.floor((v - low) / span * (side + 1)), 0, side).astype(np.uint64)


def finite_bounds(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float] | None:
    """(xmin, ymin, xmax, ymax) of the points with a finite position; None when there is none."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    finite = np.isfinite(x) & np.isfinite(y)
    if not finite.any():
        return None
    return float(x[finite].min()), float(y[finite].min()), float(x[finite].max()), float(y[finite].max())


def square_bounds(bounds: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The square from the box's lower left corner whose side is the box's longer one: cells square in metres,
    so that a strip's curve runs along the strip (over the box itself a flight line's strip of a range, 2 m by
    400 m, is cut in quadrants that all meet at its centre)."""
    xmin, ymin, xmax, ymax = bounds
    side = max(xmax - xmin, ymax - ymin)
    return xmin, ymin, xmin + side, ymin + side


def spatial_order(x: np.ndarray, y: np.ndarray, bounds: tuple[float, float, float, float] | None = None
                  ) -> np.ndarray:
    """The permutation that sorts points along the Hilbert curve over `bounds` (default: the square over their
    own extent), stably, so that points in one cell keep their order; points without a finite position last."""
    bounds = bounds or (square_bounds(b) if (b := finite_bounds(x, y)) else None)
    if bounds is None:
        return np.arange(len(x))
    return np.argsort(hilbert_key(x, y, bounds), kind="stable")
