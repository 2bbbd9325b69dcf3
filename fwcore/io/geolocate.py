"""Geolocation of echoes along the beam: X = X0 + (L0 - t) x_t (likewise Y, Z)."""

from __future__ import annotations

import numpy as np


def geolocate(anchor: np.ndarray, anchor_location_ps: np.ndarray, direction: np.ndarray,
              time_ps: np.ndarray) -> np.ndarray:
    """Positions (n, 3) of echoes at `time_ps` from the packet's first sample.

    anchor (n, 3) is the anchor point, anchor_location_ps its L0 (its own time
    in the packet) and direction (n, 3) the (x_t, y_t, z_t) of its pulse.
    """
    dt = np.asarray(anchor_location_ps, dtype=float) - np.asarray(time_ps, dtype=float)
    return np.asarray(anchor, dtype=float) + dt[:, None] * np.asarray(direction, dtype=float)
