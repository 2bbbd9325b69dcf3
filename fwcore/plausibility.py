"""A plausibility rule after geolocation: no kept echo far under the ground its neighbours see.

Nothing below the ground returns light, so a kept echo more than UNDER_GROUND_M under the local floor is a noise
bump or an afterpulse in the long record after the ground (the Leica sample's lie 5-40 m under it). Each pulse
offers one surface, its lowest: its lowest system return where the file records them (LAS points of the waveform),
else its lowest strong echo (PulseWaves, GEDI, LVIS): kept, at least STRONG_SNR x sigma_noise and STRONG_SHARE of
its pulse's strongest echo, so that an afterpulse or a noise bump is no surface. An echo's floor is the lowest of
the lowest surfaces of the *other* pulses in the 3 x 3 cells of CELL_M around it: a true weak ground echo under
canopy lies at its neighbours' ground however far under its own pulse's canopy returns, and one neighbour reaching
the ground is enough however dense the canopy (a 10% quantile was not: under the forest scene's crowns fewer than 1
pulse in 10 reaches it); a pulse's own lowest return (perhaps the noise itself) never vouches for its echoes. An
echo with no other pulse near (a range's edge, the sparse footprints of GEDI) is judged against the range's lowest
surface. An echo under its floor stays only if it is strong (a surface its neighbours do not see: a pit, a well);
the others are filtered with the reason `under_ground`, counted with the spurious echoes. So no kept echo but a
strong one lies more than UNDER_GROUND_M under the lowest return near it, nor under its flight line's lowest.
"""

from __future__ import annotations

import numpy as np

from fwcore.engine.filter import UNDER_GROUND
from fwcore.engine.records import BatchDecomposition
from fwcore.io.records import PulseBatch

UNDER_GROUND_M = 5.0
CELL_M = 2.0  # 3 x 3 cells span 4-6 m: a 25% slope lowers the floor by at most 1.5 m
STRONG_SNR = 20.0
STRONG_SHARE = 0.5


def strong_echoes(result: BatchDecomposition) -> np.ndarray:
    """Per echo: kept, at least STRONG_SNR x sigma_noise and STRONG_SHARE of its pulse's strongest kept echo."""
    kept = result.reject == 0
    owner = result.echo_waveform
    strongest = np.zeros(result.echo_offsets.size - 1)
    np.maximum.at(strongest, owner[kept], result.amplitude[kept])
    noise = np.asarray(result.noise_sigma, float)[owner]
    return kept & (result.amplitude >= STRONG_SNR * noise) & (result.amplitude >= STRONG_SHARE * strongest[owner])


def lowest_surfaces(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray) -> np.ndarray:
    """Per pulse, the (x, y, z) of its lowest surface (the module says which; NaN where it has none)."""
    out = np.full((len(pulses), 3), np.nan)
    strong = strong_echoes(result)
    for owner, points in ((result.echo_waveform[strong], xyz[strong]),
                          (pulses.return_pulse(), pulses.return_xyz)):  # system returns win: written second
        if owner.size:
            order = np.lexsort((points[:, 2], owner))
            lowest = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]  # per pulse, its lowest
            out[owner[lowest]] = points[lowest]
    return out


def local_floor(surfaces: np.ndarray, at_x: np.ndarray, at_y: np.ndarray, at_pulse: np.ndarray,
                cell: float = CELL_M) -> np.ndarray:
    """At each (at_x, at_y): the lowest of the heights of surfaces (one row per pulse, NaN rows ignored) in the
    3 x 3 cells around it, leaving out the surface of pulse at_pulse (NaN where none is left)."""
    floor = np.full(np.size(at_x), np.nan)
    placed = np.flatnonzero(np.isfinite(at_x) & np.isfinite(at_y))  # an echo without a position has no floor
    at_x, at_y = np.asarray(at_x, float)[placed], np.asarray(at_y, float)[placed]
    at_pulse = np.asarray(at_pulse)[placed]
    pulse = np.flatnonzero(np.isfinite(surfaces).all(axis=1))
    if pulse.size == 0 or at_x.size == 0:
        return floor
    x, y, z = surfaces[pulse].T
    x0, y0 = min(x.min(), at_x.min()) - cell, min(y.min(), at_y.min()) - cell
    width = int((max(x.max(), at_x.max()) - x0) / cell) + 3
    cells = lambda px, py: np.floor((py - y0) / cell).astype(np.int64) * width + np.floor(  # noqa: E731
        (px - x0) / cell).astype(np.int64)
    # each surface in the nine windows it belongs to, a window named by its centre cell
    shifts = np.array([dr * width + dc for dr in (-1, 0, 1) for dc in (-1, 0, 1)])
    window = (cells(x, y)[:, None] + shifts[None, :]).ravel()
    member, height = np.repeat(pulse, 9), np.repeat(z, 9)
    order = np.lexsort((height, window))
    window, member, height = window[order], member[order], height[order]
    starts = np.flatnonzero(np.r_[True, window[1:] != window[:-1]])
    counts = np.diff(np.r_[starts, window.size])
    key = cells(at_x, at_y)
    g = np.searchsorted(window[starts], key)
    found = (g < starts.size) & (window[starts[np.minimum(g, starts.size - 1)]] == key)
    g, k = g[found], np.flatnonzero(found)
    n = counts[g]
    # where the own pulse's surface is in the window: its rank, to step over it
    pair = np.lexsort((member, window))
    pos = np.searchsorted(window[pair] * (member.max() + 1) + member[pair],
                          key[k] * (member.max() + 1) + at_pulse[k])
    pos = np.minimum(pos, pair.size - 1)
    own = (window[pair[pos]] == key[k]) & (member[pair[pos]] == at_pulse[k])
    others = n - own
    rank = (own & (pair[pos] == starts[g])).astype(np.int64)  # the own surface the lowest: the next
    has = others > 0
    floor[placed[k[has]]] = height[starts[g[has]] + rank[has]]
    return floor


def under_ground(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray,
                 cell: float = CELL_M) -> np.ndarray:
    """Per echo of `result` (positions `xyz`), True for a kept echo more than UNDER_GROUND_M under its floor
    (the module says which) without strong evidence; `cell` in the unit of x and y (CELL_M in metres)."""
    kept = result.reject == 0
    owner = result.echo_waveform
    surfaces = lowest_surfaces(pulses, result, xyz)
    floor = local_floor(surfaces, xyz[:, 0], xyz[:, 1], owner, cell)
    if np.isfinite(surfaces[:, 2]).any():  # no other pulse near: the range's lowest surface
        floor = np.where(np.isnan(floor), np.nanmin(surfaces[:, 2]), floor)
    return kept & (xyz[:, 2] < floor - UNDER_GROUND_M) & ~strong_echoes(result)


def filter_under_ground(pulses: PulseBatch, result: BatchDecomposition, xyz: np.ndarray,
                        cell: float = CELL_M) -> int:
    """Mark the echoes under_ground finds with its reason in result.reject (in place); how many."""
    mark = under_ground(pulses, result, xyz, cell)
    result.reject[mark] = UNDER_GROUND
    return int(mark.sum())
