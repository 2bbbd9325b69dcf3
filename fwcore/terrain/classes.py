"""ASPRS classes of echoes from the ground, the buildings and the height above the terrain."""

from __future__ import annotations

import numpy as np

UNCLASSIFIED, GROUND, LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION, BUILDING, LOW_NOISE = 1, 2, 3, 4, 5, 6, 7
VEGETATION = (LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION)
# vegetation by height above the terrain, metres: below the first it is too near the ground to call (1)
VEGETATION_HEIGHTS = (0.3, 2.0, 5.0)


def asprs_classes(height: np.ndarray, ground: np.ndarray, building: np.ndarray,
                  noise: np.ndarray | None = None) -> np.ndarray:
    """2 for ground, 6 for buildings, 7 for low noise, vegetation 3 / 4 / 5 from VEGETATION_HEIGHTS up, 1
    otherwise."""
    height = np.asarray(height, float)
    low, medium, high = VEGETATION_HEIGHTS
    codes = np.full(height.shape, UNCLASSIFIED, np.uint8)
    codes[height >= low] = LOW_VEGETATION
    codes[height >= medium] = MEDIUM_VEGETATION
    codes[height >= high] = HIGH_VEGETATION
    codes[np.asarray(building, bool)] = BUILDING
    if noise is not None:
        codes[np.asarray(noise, bool)] = LOW_NOISE
    codes[np.asarray(ground, bool)] = GROUND
    return codes
