"""A plausibility rule after geolocation: no kept echo far under the lowest surface of its pulse and its neighbours.

Nothing below the ground returns light, so an echo more than UNDER_GROUND_M under the lowest return is a noise
bump or an afterpulse in the long record after the ground (the Leica sample's, 5-40 m under it). The lowest
return is the lower of two: the pulse's own lowest system return where the file records them (LAS points of
the waveform), and the local lowest surface, the lowest of the LOW_QUANTILE quantiles of the range's surfaces
(its system returns; in a file without them, its kept echoes of at least FLOOR_SNR x sigma_noise) in the
3 x 3 cells of CELL_M around the echo (fwcore.terrain.ground.low_noise's rule): a true
weak ground echo under canopy lies at its neighbours' ground, however far under its own pulse's canopy
returns, and a file without system returns (PulseWaves, GEDI, LVIS) is judged by its neighbours alone.
An echo under both stays only on strong evidence: at least STRONG_SNR x sigma_noise and STRONG_SHARE of its
pulse's strongest echo (a surface its neighbours do not see: a pit, a well). The others are filtered with the
reason `under_ground`, counted with the spurious echoes.
"""

from __future__ import annotations

import numpy as np

from fwcore.engine.filter import UNDER_GROUND
from fwcore.engine.records import BatchDecomposition
from fwcore.io.records import PulseBatch

UNDER_GROUND_M = 5.0
CELL_M = 2.0  # 3 x 3 cells span 6 m: a 25% slope lowers the floor by 1.5 m
LOW_QUANTILE = 0.1
FLOOR_SNR = 10.0
STRONG_SNR = 20.0
STRONG_SHARE = 0.5


def local_floor(x: np.ndarray, y: np.ndarray, z: np.ndarray, at_x: np.ndarray, at_y: np.ndarray,
                cell: float = CELL_M) -> np.ndarray:
    """At each (at_x, at_y): the lowest of the LOW_QUANTILE quantiles of z in the 3 x 3 cells around it (inf
    where none holds a point)."""
    x, y, z, at_x, at_y = (np.asarray(a, float) for a in (x, y, z, at_x, at_y))
    if x.size == 0:
        return np.full(at_x.size, np.inf)
    x0, y0 = min(x.min(), at_x.min(initial=np.inf)), min(y.min(), at_y.min(initial=np.inf))
    width = int((max(x.max(), at_x.max(initial=-np.inf)) - x0) / cell) + 4
    height = int((max(y.max(), at_y.max(initial=-np.inf)) - y0) / cell) + 4

    def key(px, py):
        return (np.floor((py - y0) / cell).astype(np.int64) + 1) * width + np.floor((px - x0) / cell).astype(
            np.int64) + 1

    k = key(x, y)
    order = np.lexsort((z, k))
    sorted_key = k[order]
    starts = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1]])
    counts = np.diff(np.r_[starts, sorted_key.size])
    low = np.full(width * height, np.inf)
    low[sorted_key[starts]] = z[order][starts + np.floor(LOW_QUANTILE * (counts - 1)).astype(np.int64)]
    grid = low.reshape(height, width)
    floor = np.full_like(grid, np.inf)
    for dr in (-1, 0, 1):  # the lowest of the neighbourhood's quantiles: a hollow's floor is not noise
        for dc in (-1, 0, 1):
            floor[1:-1, 1:-1] = np.minimum(floor[1:-1, 1:-1], grid[1 + dr:height - 1 + dr, 1 + dc:width - 1 + dc])
    return floor.ravel()[key(at_x, at_y)]


def lowest_system_return(pulses: PulseBatch) -> np.ndarray:
    """Per pulse, the height of its lowest system return (NaN where the file records none for it)."""
    counts = np.diff(pulses.return_offsets)
    out = np.full(len(pulses), np.nan)
    has = counts > 0
    if has.any():
        z = pulses.return_xyz[:, 2]
        out[has] = np.minimum.reduceat(z, pulses.return_offsets[:-1][has])
    return out


def under_ground(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray) -> np.ndarray:
    """Per echo of `result` (positions `xyz`), True for a kept echo more than UNDER_GROUND_M under the lowest
    return (the module says which) without strong evidence."""
    kept = result.reject == 0
    owner = result.echo_waveform
    own = lowest_system_return(pulses)[owner]
    noise = np.asarray(result.noise_sigma, float)[owner]
    # the surfaces: the system's returns where the file records them (its detector's, not our fits), else the
    # strong kept echoes
    surface = pulses.return_xyz if pulses.return_xyz.shape[0] else xyz[kept & (result.amplitude >= FLOOR_SNR * noise)]
    x, y, z = surface[:, 0], surface[:, 1], surface[:, 2]
    floor = local_floor(x, y, z, xyz[:, 0], xyz[:, 1])
    lowest = np.fmin(own, floor)  # NaN own: the neighbours' alone
    deep = kept & (xyz[:, 2] < lowest - UNDER_GROUND_M)
    if not deep.any():
        return deep
    strongest = np.zeros(len(pulses))
    np.maximum.at(strongest, owner[kept], result.amplitude[kept])
    strong = (result.amplitude >= STRONG_SNR * noise) & (result.amplitude >= STRONG_SHARE * strongest[owner])
    return deep & ~strong


def filter_under_ground(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray) -> int:
    """Mark the echoes under_ground finds with its reason in result.reject (in place); how many."""
    mark = under_ground(pulses, result, xyz)
    result.reject[mark] = UNDER_GROUND
    return int(mark.sum())
