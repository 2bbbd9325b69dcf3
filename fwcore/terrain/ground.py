"""Which echoes are the ground: the cloth simulation filter (Zhang et al. 2016) on each pulse's last echo,
then a densification against the terrain it finds; echoes far below the ground around them are noise first.

A waveform's ground can only be its pulse's last kept echo (nothing below the ground returns light), so the
cloth is dropped on the last echoes only: branches and leaves above are never candidates, whatever the cloth
does. The cloth bridges narrow hollows (a ditch) and rides over low roofs' edges; the densification fixes the
first: last echoes within `refine_below` under and `refine_above` over the terrain of the cloth's ground
(a triangulation) join it, iterated, so that a ditch's floor is found from its banks.
"""

from __future__ import annotations

import dataclasses
import functools
import os

import numpy as np


@dataclasses.dataclass(frozen=True)
class GroundConfig:
    """The cloth and the densification; metres."""

    cloth_resolution: float = 1.0
    rigidness: int = 2  # 1 steep terrain, 2 moderate slopes, 3 flat
    class_threshold: float = 0.5
    slope_smooth: bool = True
    iterations: int = 500
    refine_above: float = 0.3  # a last echo this close above the terrain is ground ...
    refine_below: float = 2.0  # ... and so is one this far below it (a hollow the cloth bridged)
    refine_passes: int = 2

    def __post_init__(self) -> None:
        if self.rigidness not in (1, 2, 3):
            raise ValueError("rigidness is 1 (steep), 2 (moderate slopes) or 3 (flat)")
        if not (self.cloth_resolution > 0 and self.class_threshold > 0):
            raise ValueError("the cloth's resolution and class threshold must be positive metres")


def last_echoes(pulse: np.ndarray, echo_index: np.ndarray) -> np.ndarray:
    """True for each pulse's last echo (the highest echo_index among the rows given, which are kept echoes)."""
    pulse, echo_index = np.asarray(pulse), np.asarray(echo_index)
    order = np.lexsort((echo_index, pulse))
    last = np.zeros(pulse.size, bool)
    sorted_pulse = pulse[order]
    ends = np.ones(pulse.size, bool)
    ends[:-1] = sorted_pulse[1:] != sorted_pulse[:-1]
    last[order[ends]] = True
    return last


NOISE_CELL_M = 5.0
NOISE_MARGIN_M = 3.0
NOISE_QUANTILE = 0.1


def low_noise(x: np.ndarray, y: np.ndarray, z: np.ndarray, cell: float = NOISE_CELL_M,
              margin: float = NOISE_MARGIN_M) -> np.ndarray:
    """Echoes far below the ground around them (a spurious echo past the last surface): more than `margin`
    under the lowest of the NOISE_QUANTILE quantiles of z in the 3 x 3 cells around theirs. The cloth would
    hang on one of them (inverted, it is the highest peak) and call the true ground above it off-ground."""
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    if x.size == 0:
        return np.zeros(0, bool)
    col = np.floor((x - x.min()) / cell).astype(np.int64)
    row = np.floor((y - y.min()) / cell).astype(np.int64)
    width, height = int(col.max()) + 3, int(row.max()) + 3
    key = (row + 1) * width + col + 1
    order = np.lexsort((z, key))
    sorted_key = key[order]
    starts = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1]])
    counts = np.diff(np.r_[starts, sorted_key.size])
    low = np.full(width * height, np.inf)
    low[sorted_key[starts]] = z[order][starts + np.floor(NOISE_QUANTILE * (counts - 1)).astype(np.int64)]
    grid = low.reshape(height, width)
    floor = np.full_like(grid, np.inf)
    for dr in (-1, 0, 1):  # the lowest of the neighbourhood's quantiles: a hollow's floor is not noise
        for dc in (-1, 0, 1):
            floor[1:-1, 1:-1] = np.minimum(floor[1:-1, 1:-1], grid[1 + dr:height - 1 + dr, 1 + dc:width - 1 + dc])
    return z < floor.ravel()[key] - margin


def cloth_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray, config: GroundConfig = GroundConfig()) -> np.ndarray:
    """The cloth simulation filter's ground (cloth-simulation-filter, the authors' C++), True for ground."""
    import CSF

    n = np.asarray(x).size
    if n < 3:
        return np.ones(n, bool)
    xyz = np.column_stack([x, y, z]).astype(np.float64)
    origin = xyz.min(axis=0)  # CSF works in float: metres from the tile's corner keep its precision
    csf = CSF.CSF()
    csf.params.bSloopSmooth = config.slope_smooth
    csf.params.cloth_resolution = config.cloth_resolution
    csf.params.rigidness = config.rigidness
    csf.params.class_threshold = config.class_threshold
    csf.params.interations = config.iterations
    csf.setPointCloud(xyz - origin)
    ground, other = CSF.VecInt(), CSF.VecInt()
    _one_openmp_thread(CSF)
    with _quiet_stdout():  # the C++ prints its progress to the process's stdout
        csf.do_filtering(ground, other, False)
    mask = np.zeros(n, bool)
    mask[np.asarray(list(ground), dtype=np.int64)] = True
    return mask


def classify_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray, last: np.ndarray,
                    config: GroundConfig = GroundConfig()) -> np.ndarray:
    """True for ground echoes: the cloth's ground among the last echoes, densified (see the module)."""
    from fwcore.terrain.dtm import interpolate

    x, y, z, last = (np.asarray(a) for a in (x, y, z, last))
    ground = np.zeros(x.size, bool)
    candidates = np.flatnonzero(last & ~low_noise(x, y, z))
    if candidates.size < 3:
        ground[candidates] = True
        return ground
    ground[candidates[cloth_ground(x[candidates], y[candidates], z[candidates], config)]] = True
    for _ in range(config.refine_passes):
        g = np.flatnonzero(ground)
        if g.size < 3:
            break
        surface = interpolate(x[g], y[g], z[g], x[candidates], y[candidates])
        dz = z[candidates] - surface
        ground[candidates] = (dz <= config.refine_above) & (dz >= -config.refine_below)
    return ground


def _one_openmp_thread(csf_module) -> None:
    """The cloth's OpenMP loop moves particles that share constraints from several threads at once: a race, so
    that the same tile gave another ground on some runs. One thread (set for the calling thread, where the cloth
    runs) makes it deterministic."""
    library = _openmp_library(csf_module.__file__)
    if library is not None:  # none: a build without OpenMP, one thread already
        library.omp_set_num_threads(1)


@functools.lru_cache(maxsize=None)
def _openmp_library(module_file: str):
    """The OpenMP library the wheel bundles beside the module, or the system's; None without one (found once)."""
    import ctypes
    import ctypes.util
    from pathlib import Path

    libs = Path(module_file).parent
    bundled = sorted(libs.glob("*.libs/libgomp*"))
    name = str(bundled[0]) if bundled else ctypes.util.find_library("gomp")
    return ctypes.CDLL(name) if name is not None else None


class _quiet_stdout:
    """File descriptor 1 to /dev/null for the duration (C++ writes there, not to sys.stdout)."""

    def __enter__(self):
        import sys

        sys.stdout.flush()
        self._saved = os.dup(1)
        self._null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(self._null, 1)

    def __exit__(self, *exc):
        os.dup2(self._saved, 1)
        os.close(self._saved)
        os.close(self._null)
