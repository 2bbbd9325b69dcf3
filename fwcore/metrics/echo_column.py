"""A small footprint's forest metrics from its decomposed echoes: what one airborne beam (a 0.5 m footprint) says
of its column, at a fraction of the waveform metrics' cost (fwcore.metrics.waveform: GEDI L2A's modes and RH on the
smoothed waveform, L2B's ground return fitted by Levenberg-Marquardt, ~15 iterations a pulse).

The engine has already fitted every return of the pulse with the system's pulse shape; fitting the ground return
again (L2B's extended Gaussian) repeats that work. Here the decomposition's echoes are the returns:

    ground       the pulse's last kept echo (the lowest: echoes are in time order); ground_z its height
    rg, rv       the ground echo's energy, and the energy of the kept echoes above it (L2B's rg and rv, the
                 fitted returns' areas instead of the waveform's samples; a pulse with one echo has rv 0: no fit)
    Pgap, cover, PAI   L2B's formulas on rv and rg (fwcore.metrics.canopy's constants)
    RH0..RH100   the height above the ground echo's centre below which 0..100 % of the echoes' energy lies, each
                 echo a Gaussian of its own width along the beam, between 3 sigma under the lowest and 3 sigma
                 over the highest (L2A's botloc and toploc), truncated to cm as L2A does
    pavd_z       L2B's profile: the gap probability at 0, 5, ... m above the ground from the canopy energy above it

GEDI, LVIS and simulated large footprints keep NASA's definitions (fwcore.metrics.waveform): a 25 m footprint's
ground is a mode among many returns, and its cover a fraction of the footprint, not of one beam's column. The maps
of small-footprint runs come from the echoes (pipeline.forest_maps), never from these per-pulse values.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT, JIT_INLINE
from fwcore.metrics.canopy import CanopySettings
from fwcore.metrics.kernel import plant_area_density
from fwcore.metrics.waveform import NO_AXIS, WaveformMetrics, empty_metrics

# a small-footprint pulse's metrics: from its echoes (this module), or the full waveform metrics (fwl run --pulse-metrics)
FROM_ECHOES, FROM_WAVEFORM = "echoes", "full"  # --pulse-metrics: a small footprint's metrics from what
PULSE_METRICS = (FROM_ECHOES, FROM_WAVEFORM)
NO_ECHO = "no kept echo: no ground"
NOT_DECOMPOSED = "not decomposed"
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
EXTENT_SIGMAS = 3.0  # the energy's extent: 3 sigma beyond the lowest and the highest echo
GRID_PER_SAMPLE = 4  # the cumulative energy's grid: a quarter of a sample, L2A's sub-bins
REASONS = ("", NOT_DECOMPOSED, NO_AXIS, NO_ECHO)  # by the kernel's codes
MEASURED, NOT_DECOMPOSED_CODE, NO_AXIS_CODE, NO_ECHO_CODE = range(4)
# beyond these erfc is exactly 2.0 and 0.0 in float64 (from -5.87 and 27.23 on; tested against libm)
ERFC_TWO_BELOW, ERFC_ZERO_ABOVE = -6.0, 27.5


@njit(**JIT_INLINE)
def _erfc(x):
    """math.erfc, its exact value without the call in its flat tails: most of a column's grid is far from an echo."""
    if x <= ERFC_TWO_BELOW:
        return 2.0
    if x >= ERFC_ZERO_ABOVE:
        return 0.0
    return math.erfc(x)


@njit(**JIT)
def _energy_below(z, centre, sd, energy):
    """The echoes' energy below height z (each a Gaussian of its sd about its centre)."""
    total = 0.0
    for k in range(centre.size):
        total += energy[k] * 0.5 * _erfc((centre[k] - z) / (math.sqrt(2.0) * sd[k]))
    return total


@njit(**JIT)
def _relative_heights(centre, sd, energy, ground, step, rh):
    """RH0..RH100 above `ground` from the cumulative energy on a grid of `step` metres over the echoes' extent."""
    low, high = np.inf, -np.inf
    for k in range(centre.size):
        low = min(low, centre[k] - EXTENT_SIGMAS * sd[k])
        high = max(high, centre[k] + EXTENT_SIGMAS * sd[k])
    m = max(2, int(math.ceil((high - low) / step)) + 1)
    step = (high - low) / (m - 1)
    below = np.empty(m)
    for j in range(m):
        below[j] = _energy_below(low + j * step, centre, sd, energy)
    base, span = below[0], below[m - 1] - below[0]
    j = 0
    for percent in range(101):
        target = base + span * percent / 100.0
        while j < m - 2 and below[j + 1] < target:
            j += 1
        rise = below[j + 1] - below[j]
        fraction = min(max((target - below[j]) / rise, 0.0), 1.0) if rise > 0 else 0.0
        z = low + (j + fraction) * step
        if percent == 0:
            z = low
        elif percent == 100:
            z = high
        rh[percent] = math.trunc((z - ground) * 100.0) / 100.0


@njit(**JIT)
def _profile(centre, sd, energy, ground, denominator, cos_zenith, rossg, omega, step, cover_z, pai_z, pavd_z):
    """L2B's profile at 0, step, ... m above the ground from the canopy echoes' energy above each height."""
    bins = cover_z.size
    for b in range(bins):
        above = 0.0
        for k in range(centre.size):
            above += energy[k] * (1.0 - 0.5 * _erfc((centre[k] - ground - b * step) / (math.sqrt(2.0) * sd[k])))
        pgap = min(max(1.0 - above / denominator, 0.0), 1.0) if denominator > 0 else 1.0
        cover_z[b] = cos_zenith * (1.0 - pgap)
        pai_z[b] = -math.log(pgap) * cos_zenith / (rossg * omega) + 0.0 if pgap > 0 else np.inf
    plant_area_density(pai_z, step, pavd_z)


@njit(**JIT)
def _column_kernel(echo_offsets, kept, position, echo_z, fwhm, energy, decomposed, drop, cos_zenith, constants,
                   reason, scalars, rh, cover_z, pai_z, pavd_z):
    """Every pulse's column metrics; constants: (rhov/rhog, rossg, omega, profile step). scalars (n, 9): toploc,
    botloc, ground index, ground z, rv, rg, pgap, cover, pai (WaveformMetrics' order)."""
    for i in range(echo_offsets.size - 1):
        if not decomposed[i]:
            reason[i] = NOT_DECOMPOSED_CODE
            continue
        if not (math.isfinite(drop[i]) and drop[i] > 0):
            reason[i] = NO_AXIS_CODE
            continue
        lo, hi = echo_offsets[i], echo_offsets[i + 1]
        count = 0
        for e in range(lo, hi):
            if kept[e]:
                count += 1
        if count == 0:
            reason[i] = NO_ECHO_CODE
            continue
        centre, sd, area = np.empty(count), np.empty(count), np.empty(count)
        k, first, last = 0, -1, -1
        for e in range(lo, hi):
            if kept[e]:
                centre[k], area[k] = echo_z[e], max(energy[e], 0.0)
                sd[k] = max(fwhm[e] / FWHM_PER_SIGMA, 0.25) * drop[i]  # a quarter sample at least: no zero width
                first = e if first < 0 else first
                last = e
                k += 1
        ground = echo_z[last]  # the last echo in time: the lowest
        rg = area[count - 1]
        rv = 0.0
        for k in range(count - 1):
            rv += area[k]
        denominator = rv + constants[0] * rg
        pgap = 1.0 - rv / denominator if denominator > 0 else 1.0
        reason[i] = MEASURED
        scalars[i, 0], scalars[i, 1], scalars[i, 2], scalars[i, 3] = position[first], position[last], position[last], ground
        scalars[i, 4], scalars[i, 5], scalars[i, 6] = rv, rg, pgap
        scalars[i, 7] = cos_zenith[i] * (1.0 - pgap)
        scalars[i, 8] = -math.log(pgap) * cos_zenith[i] / (constants[1] * constants[2]) + 0.0 if pgap > 0 else np.inf
        _relative_heights(centre, sd, area, ground, drop[i] / GRID_PER_SAMPLE, rh[i])
        # the canopy: every kept echo but the ground's
        _profile(centre[:count - 1], sd[:count - 1], area[:count - 1], ground, denominator, cos_zenith[i],
                 constants[1], constants[2], constants[3], cover_z[i], pai_z[i], pavd_z[i])


def echo_column_metrics(echo_offsets: np.ndarray, kept: np.ndarray, position: np.ndarray, echo_z: np.ndarray,
                        fwhm: np.ndarray, energy: np.ndarray, decomposed: np.ndarray, metres_per_sample: np.ndarray,
                        cos_zenith: np.ndarray, canopy: CanopySettings = CanopySettings()) -> WaveformMetrics:
    """Each pulse's column metrics from its echoes (see the module): echo e of pulse i at echo_offsets[i] <= e <
    echo_offsets[i + 1], in time order; `kept` the echoes that count, `position` and `fwhm` in samples, `echo_z`
    each echo's height, `energy` its area (the waveform's units x samples); per pulse whether it was decomposed,
    the vertical metres a sample and the beam's zenith cosine. Null (NaN) where `reason` says why."""
    n = echo_offsets.size - 1
    bins = canopy.profile_heights.size
    out = empty_metrics(n, bins, 0)  # no zcross modes: the kept echoes are in echoes/
    scalars = np.full((n, 9), np.nan)
    reason = np.zeros(n, dtype=np.int8)
    f64 = lambda a, size: np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), (size,)))  # noqa: E731
    m = int(echo_offsets[-1]) if n >= 0 and echo_offsets.size else 0
    _column_kernel(np.ascontiguousarray(echo_offsets, dtype=np.int64), np.ascontiguousarray(kept, dtype=np.bool_),
                   f64(position, m), f64(echo_z, m), f64(fwhm, m), f64(energy, m),
                   np.ascontiguousarray(np.broadcast_to(decomposed, (n,)), dtype=np.bool_), f64(metres_per_sample, n),
                   f64(cos_zenith, n),
                   np.array([canopy.rhov_rhog, canopy.rossg, canopy.omega, canopy.profile_step_m], dtype=np.float64),
                   reason, scalars, out["rh"], out["cover_z"], out["pai_z"], out["pavd_z"])
    for column, name in enumerate(("toploc", "botloc", "ground_index", "ground_z", "rv", "rg", "pgap", "cover",
                                   "pai")):
        out[name] = scalars[:, column]
    return WaveformMetrics(**out, reason=[REASONS[r] for r in reason])


def pulse_column_metrics(pulses, result, xyz: np.ndarray, canopy: CanopySettings = CanopySettings()) -> WaveformMetrics:
    """echo_column_metrics of a decomposed batch (fwcore.io.records.PulseBatch, fwcore.engine.records.
    BatchDecomposition) with every echo's position `xyz` (fwcore.pulses.echo_positions): the echoes the run keeps
    (result.reject 0), each pulse's vertical axis from its geolocation."""
    from fwcore.metrics.pulses import vertical_axis, zenith_cosine

    _, drop = vertical_axis(pulses)
    return echo_column_metrics(result.echo_offsets, result.reject == 0, result.position, xyz[:, 2], result.fwhm,
                               result.energy, result.status == 0, drop, zenith_cosine(pulses), canopy)
