"""Where a pulse's gap probability belongs on a map: a pulse's canopy and ground energies are one measurement
(their ratio is the gap along its beam), so they go to one cell together, the one where the beam crosses the
canopy, not each to the cell under its own echo.

An airborne beam is slanted (12 degrees at a 220 m swath's edge from 500 m): its canopy echoes lie metres to the
side of its ground echo (4 m at 20 m up), so binning echoes where they lie puts a pulse's rv in one 5 m cell and
its rg in the next, and a cell's Pgap = 1 - rv / (rv + 1.5 rg) mixes beams it never held whole.

Each pulse goes where its own beam crossed the canopy: at its own leaves' energy-weighted mean height (a beam
that met a crown's top 25 m up and one that met an understorey at 6 m cross their cells 4 m apart at 12
degrees). A pulse with no vegetation echo (a gap's: all its energy reached the ground) passed the canopy
unhindered, and that is where its gap belongs: at the height its neighbours' beams met the canopy, not at the
ground, which a slanted beam reaches metres to the side, away from the crowns' hits it was among. On simulated
forests (fwcore.studies.forest; docs/forest.md) the 5 m cells' PAI against the truth's effective PAI, median
relative error on seed 5: 23 % with echoes where they lie, 17 % with every pulse at its tile's mean canopy
height, 21 % with each at its own leaves and the gaps at the ground, 14 % with the gaps at their neighbours'.

    pulse_interception_heights(pulse, x, y, z, height, energy, vegetation)
                                                      per echo, its pulse's own vegetation's mean height (m
                                                      above the terrain); a gap's pulse, its neighbours'
    beam_positions(pulse, x, y, z, height, at)       each echo's pulse's point at `at` m above the terrain
    range_normalised(energy, range_m)                 energy x range^2: the echoes of one pulse on one scale

The received energy of a target falls as 1 / R^2; a canopy echo 20 m above the ground at 500 m is 8 % stronger
than the same leaf area at the ground's range. GEDI, 400 km up, can ignore it; an airborne survey cannot.
"""

from __future__ import annotations

import numpy as np

MIN_DEPTH_M = 1.0  # a pulse's echoes this far apart in z give its beam's direction
GAP_NEIGHBOURS = 8  # a gap's pulse crosses the canopy at these nearest leaf-hit pulses' mean height


def pulse_interception_heights(pulse: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, height: np.ndarray,
                               energy: np.ndarray, vegetation: np.ndarray,
                               neighbours: int = GAP_NEIGHBOURS) -> np.ndarray:
    """Per echo, the energy-weighted mean height above the terrain of its pulse's vegetation echoes (those with
    a finite height and a positive energy). A pulse with none (a gap's) takes the mean of the `neighbours`
    nearest pulses' that have some, nearest by where the beams end (their lowest echoes); NaN where no pulse
    has a vegetation echo."""
    x, y, z, height = (np.asarray(a, float) for a in (x, y, z, height))
    energy = np.nan_to_num(np.asarray(energy, float))
    if not height.size:
        return np.empty(0)
    _, owner = np.unique(np.asarray(pulse), return_inverse=True)
    ok = np.asarray(vegetation, bool) & np.isfinite(height) & (energy > 0)
    w = np.where(ok, energy, 0.0)
    total = np.bincount(owner, weights=w)
    moment = np.bincount(owner, weights=w * np.where(ok, height, 0.0))
    leaves = total > 0
    at = np.full(total.size, np.nan)
    at[leaves] = moment[leaves] / total[leaves]
    if leaves.any() and not leaves.all():
        from scipy.spatial import cKDTree

        lowest = _extreme(owner, z)
        ends = np.column_stack([x[lowest], y[lowest]])
        k = min(int(neighbours), int(leaves.sum()))
        _, near = cKDTree(ends[leaves]).query(ends[~leaves], k=k)
        at[~leaves] = at[leaves][np.reshape(near, (-1, k))].mean(axis=1)
    return at[owner]


def beam_positions(pulse: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, height: np.ndarray,
                   at: float | np.ndarray, min_depth_m: float = MIN_DEPTH_M) -> tuple[np.ndarray, np.ndarray]:
    """Per echo, the x, y of its pulse's beam `at` metres above the terrain under the pulse's lowest echo: one
    height for all, or per echo (the same for a pulse's echoes: its lowest echo's is taken). A beam's direction
    is its highest echo less its lowest where they are `min_depth_m` apart; a pulse with one echo (a gap's, or a
    crown's that stopped it) takes the direction of the nearest pulse that has one (a scan's neighbouring beams
    are parallel within a fraction of a degree). Echoes keep their own x, y where no pulse has a direction, or
    where their `at` is not finite."""
    x, y, z, height = (np.asarray(a, float) for a in (x, y, z, height))
    at = np.broadcast_to(np.asarray(at, float), x.shape)
    if not x.size or not np.isfinite(at).any():
        return x.copy(), y.copy()
    _, owner = np.unique(np.asarray(pulse), return_inverse=True)
    lowest, highest = _extreme(owner, z), _extreme(owner, -z)
    d = np.column_stack([x[highest] - x[lowest], y[highest] - y[lowest], z[highest] - z[lowest]])
    has = d[:, 2] >= min_depth_m
    if not has.any():
        return x.copy(), y.copy()
    if not has.all():  # the nearest pulse with a direction, by where the beams end
        from scipy.spatial import cKDTree

        ends = np.column_stack([x[lowest], y[lowest]])
        _, near = cKDTree(ends[has]).query(ends[~has])
        d[~has] = d[has][near]
    terrain = z[lowest] - height[lowest]
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (terrain + at[lowest] - z[lowest]) / d[:, 2]
        px, py = x[lowest] + s * d[:, 0], y[lowest] + s * d[:, 1]
    ok = np.isfinite(px) & np.isfinite(py)
    return np.where(ok[owner], px[owner], x), np.where(ok[owner], py[owner], y)


def _extreme(owner: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Per pulse, the index of its echo with the smallest key."""
    order = np.lexsort((key, owner))
    first = np.r_[True, owner[order][1:] != owner[order][:-1]]
    out = np.empty(owner.max() + 1, np.int64)
    out[owner[order][first]] = order[first]
    return out


def range_normalised(energy: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """energy x range^2 where every range is known, else the energy as it is (one scale for all echoes)."""
    energy, range_m = np.asarray(energy, float), np.asarray(range_m, float)
    if range_m.size and np.isfinite(range_m).all():
        return energy * range_m ** 2
    return energy
