"""The batch kernel: every waveform's metrics in one numba call, the same steps as signal.py, ground.py, rh.py and
canopy.py (which stay the readable NumPy reference, and which tests/fwcore/metrics/test_kernel.py holds it to).

A GEDI shot's metrics cost about 0.8 ms in NumPy's small-array calls and a few tens of microseconds here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.metrics.canopy import TAIL_SAMPLES, _extended_gaussian_at, _fit_extended_gaussian

# why a pulse's metrics are null: the index into waveform.REASONS
MEASURED, NO_NOISE, NOT_FINITE, NO_AXIS, NO_SIGNAL, NO_GROUND = range(6)
RH_COUNT = 101


@njit(**JIT)
def _smooth(samples, sigma, half, out):
    """gaussian_smooth: a unit-area Gaussian of sigma `sigma` over +-half samples (signal.smoothing_kernel), the
    edge samples repeated."""
    n = samples.size
    if sigma <= 0 or n < 2:
        out[:] = samples
        return
    weights = np.empty(2 * half + 1)
    total = 0.0
    for k in range(2 * half + 1):
        d = (k - half) / sigma
        weights[k] = math.exp(-0.5 * d * d)
        total += weights[k]
    # tap by tap over every output (each output's terms still added in tap order, so the sums are the same to the
    # bit): the inner loop has no carried dependency and no clamp, and runs 5-10x faster than output by output
    acc = np.zeros(n)
    for k in range(2 * half + 1):
        w, shift = weights[k], k - half
        lo, hi = min(max(-shift, 0), n), max(min(n - shift, n), 0)  # outputs whose sample j + shift is inside
        first, last = samples[0], samples[n - 1]
        for j in range(lo):
            acc[j] += w * first
        inside, source = acc[lo:hi], samples[lo + shift:hi + shift]
        for q in range(hi - lo):
            inside[q] += w * source[q]
        for j in range(max(hi, lo), n):
            acc[j] += w * last
    for j in range(n):
        out[j] = acc[j] / total


@njit(**JIT)
def _at(values, position):
    """Linear interpolation of values (one a sample) at a position in samples, clamped to the ends."""
    n = values.size
    if position <= 0.0:
        return values[0]
    if position >= n - 1:
        return values[n - 1]
    j = int(math.floor(position))
    return values[j] + (values[j + 1] - values[j]) * (position - j)


@njit(**JIT)
def _first_above(smoothed, subbins, threshold):
    """The first sub-bin where the smoothed waveform rises above `threshold`; -1 where it never does."""
    for k in range((smoothed.size - 1) * subbins + 1):
        if _at(smoothed, k / subbins) > threshold:
            return k
    return -1


@njit(**JIT)
def _extent(smoothed, subbins, front, back):
    """signal_extent on the sub-bin grid: (toploc, botloc), NaN where the waveform never rises above them."""
    m = (smoothed.size - 1) * subbins + 1
    top = _first_above(smoothed, subbins, front)
    bottom = -1
    for k in range(m - 1, -1, -1):
        if _at(smoothed, k / subbins) > back:
            bottom = k
            break
    if top < 0 or bottom < 0 or bottom < top:
        return np.nan, np.nan
    return top / subbins, bottom / subbins


@njit(**JIT)
def _modes(smoothed, toploc, botloc, threshold, subbins, position, amplitude):
    """ground.signal_modes into position and amplitude (top to bottom): the rising-to-falling zeros of the
    central-difference slope inside the signal whose amplitude clears the threshold, on the sub-bin grid; returns
    their count."""
    n = smoothed.size
    if n < 3:
        return 0
    slope = np.empty(n)
    slope[0] = smoothed[1] - smoothed[0]
    slope[n - 1] = smoothed[n - 1] - smoothed[n - 2]
    for j in range(1, n - 1):
        slope[j] = 0.5 * (smoothed[j + 1] - smoothed[j - 1])
    count = 0
    for j in range(n - 1):
        if slope[j] > 0 and slope[j + 1] <= 0:
            at = np.rint((j + slope[j] / (slope[j] - slope[j + 1])) * subbins) / subbins
            value = _at(smoothed, at)
            if toploc <= at <= botloc and value > threshold:
                position[count], amplitude[count] = at, value
                count += 1
    return count


@njit(**JIT)
def _cumulative(smoothed, noise_mean, top, bottom, subbins):
    """The energy above the noise mean summed from sub-bin `bottom` up to each sub-bin (index 0: bottom alone)."""
    count = bottom - top + 1
    cumulative = np.empty(max(count, 0))
    running = 0.0
    for i in range(count):  # from the bottom up
        running += _at(smoothed, (bottom - i) / subbins) - noise_mean
        cumulative[i] = running
    return cumulative


@njit(**JIT)
def _ground_mode(smoothed, noise_mean, position, amplitude, count, cumulative, bottom, botloc, back, subbins, select,
                 slots):
    """ground.selected_mode (select: waveform.MetricSettings.mode_selection): the ground's index among the modes,
    chosen among the lowest `slots` (waveform.ground_mode)."""
    if select[0] == 0.0 or cumulative.size == 0:
        return count - 1
    separation, minimum, enough, energy_thresh, amp_thresh = select[1], select[2], select[3], select[4], select[5]
    total = cumulative[cumulative.size - 1]
    h = int(round(separation * subbins))
    last = (smoothed.size - 1) * subbins
    for j in range(count - 1, max(count - max(slots, 1), 0) - 1, -1):
        k = int(round(position[j] * subbins))
        share = 100.0 * cumulative[min(max(bottom - k, 0), cumulative.size - 1)] / total if total > 0 else np.nan
        above = amplitude[j] - noise_mean
        if botloc - position[j] < separation or above < back - noise_mean or share < minimum:
            continue
        lo, hi = max(k - h, 0), min(k + h, last)
        local = 0.0
        for q in range(lo, hi + 1):
            local += _at(smoothed, q / subbins) - noise_mean
        ends = _at(smoothed, lo / subbins) + _at(smoothed, hi / subbins) - 2.0 * noise_mean
        local = (local - 0.5 * ends * (hi - lo + 1)) / subbins
        if local > energy_thresh or above > amp_thresh or share > enough:
            return j
    return count - 1


@njit(**JIT)
def _relative_heights(cumulative, toploc, botloc, ground, drop, subbins, rh):
    """rh.energy_positions and rh.relative_heights into rh (101 values), from the signal's cumulative energy."""
    count = cumulative.size
    bottom = int(round(botloc * subbins))
    if count < 2 or not cumulative[count - 1] > 0:
        rh[:] = np.nan
        return
    share = cumulative / cumulative[count - 1]
    for k in range(RH_COUNT):
        index = np.searchsorted(share, k / 100.0) - 1
        index = min(max(index, 0), count - 1)
        position = (bottom - index) / subbins
        if k == 0:
            position = botloc
        elif k == RH_COUNT - 1:
            position = toploc
        rh[k] = math.trunc((ground - position) * drop * 100.0) / 100.0


@njit(**JIT)
def _canopy(samples, noise_mean, toploc, botloc, ground, shape, buffer, centre_buffer, canopy):
    """canopy.ground_return and canopy.canopy_energy: the canopy's energy per sample into `canopy`; returns rg."""
    n = samples.size
    x = np.arange(1, n + 1).astype(np.float64)  # L2B's 1-based sample index
    signal = np.zeros(n)
    last = -1
    peak = -np.inf
    for j in range(n):
        if x[j] > toploc - buffer and x[j] < botloc + buffer:
            signal[j] = max(samples[j] - noise_mean, 0.0)
        if signal[j] != 0.0:
            last = j
        peak = max(peak, signal[j])
    end = (last + 1 if last >= 0 else n) + TAIL_SAMPLES
    fitted = np.zeros(n, dtype=np.bool_)
    m = 0
    for j in range(n):
        if x[j] > ground - 2 * centre_buffer and x[j] <= end:
            fitted[j] = True
            m += 1
    xs, ys = np.empty(m), np.empty(m)
    m = 0
    for j in range(n):
        if fitted[j]:
            xs[m], ys[m] = x[j], signal[j]
            m += 1
    lower = np.array([-np.inf, ground - centre_buffer, shape[0] - 3 * shape[1], shape[2] - 3 * shape[3]])
    upper = np.array([np.inf, ground + centre_buffer, np.inf, shape[2] + 3 * shape[3]])
    start = np.array([peak, ground, shape[0], shape[2]])
    for i in range(4):
        start[i] = min(max(start[i], lower[i] + 1e-9), upper[i] - 1e-9)
    p = _fit_extended_gaussian(xs, ys, start, lower, upper, 100)
    for j in range(n):  # the model only where the canopy can be: signal above the ground
        canopy[j] = 0.0
        if x[j] < ground and signal[j] > 0.0:
            canopy[j] = max(signal[j] - _extended_gaussian_at(p[0], p[1], p[2], p[3], x[j]), 0.0)
    return p[0]


@njit(**JIT)
def plant_area_density(pai_z, step, pavd_z):
    """PAVD in each height bin: minus the PAI profile's derivative (central differences, one-sided at the ends;
    canopy.vertical_profile), into pavd_z."""
    bins = pai_z.size
    if bins > 1:
        pavd_z[0] = -(pai_z[1] - pai_z[0]) / step
        pavd_z[bins - 1] = -(pai_z[bins - 1] - pai_z[bins - 2]) / step
        for b in range(1, bins - 1):
            pavd_z[b] = -(pai_z[b + 1] - pai_z[b - 1]) / (2.0 * step)
    elif bins == 1:
        pavd_z[0] = 0.0


@njit(**JIT)
def _profile(canopy, ground, drop, denominator, cos_zenith, rossg, omega, step, cover_z, pai_z, pavd_z):
    """canopy.vertical_profile into cover_z, pai_z and pavd_z."""
    n, bins = canopy.size, cover_z.size
    pgap = np.empty(n)
    running = 0.0
    for j in range(n):
        running += canopy[j]
        pgap[j] = 1.0 - running / denominator if denominator > 0 else 1.0
    highest = (ground - 0.0) * drop  # sample 0 is the highest
    for b in range(bins):
        h = b * step
        value = 1.0
        if h < highest:
            # the first sample at or below the height: (ground - j) * drop falls with j (drop > 0, rounding is
            # monotone), so a bisection finds the linear scan's sample, in log n steps instead of up to n a bin
            lo, hi = 0, n
            while lo < hi:
                mid = (lo + hi) // 2
                if (ground - mid) * drop <= h:
                    hi = mid
                else:
                    lo = mid + 1
            value = pgap[lo if lo < n else 0]
        value = min(max(value, 0.0), 1.0)
        cover_z[b] = cos_zenith * (1.0 - value)
        pai_z[b] = -math.log(value) * cos_zenith / (rossg * omega) if value > 0 else np.inf
    plant_area_density(pai_z, step, pavd_z)


@njit(**JIT)
def metrics_kernel(samples, offsets, noise_mean, noise_sd, first_z, drop, cos_zenith, shape, widths, thresholds,
                   subbins, buffers, canopy_constants, select, reason, scalars, rh, cover_z, pai_z, pavd_z, mode_z):
    """Every waveform's metrics. widths: the smoothing's and the zcross smoothing's sigma and half-width (samples,
    signal.smoothing_kernel); thresholds: (front, back) in noise sigmas;
    buffers: (signal search, ground centre); canopy_constants: (rhov/rhog, rossg, omega, profile step); select: the
    mode selection (MetricSettings.mode_selection). Outputs: reason per waveform, scalars (n, 10): toploc, botloc,
    ground index, ground z, rv, rg, pgap, cover, pai, mode count; rh (n, 101); cover_z, pai_z, pavd_z (n, bins);
    mode_z (n, slots). Outputs of a waveform whose reason is not MEASURED stay NaN."""
    longest = 0
    for i in range(offsets.size - 1):
        longest = max(longest, offsets[i + 1] - offsets[i])
    position, amplitude = np.empty(longest + 1), np.empty(longest + 1)
    for i in range(offsets.size - 1):
        wave = samples[offsets[i]:offsets[i + 1]]
        mean, sd = noise_mean[i], noise_sd[i]
        if not (math.isfinite(mean) and math.isfinite(sd)):
            reason[i] = NO_NOISE
            continue
        finite = True
        for v in wave:
            if not math.isfinite(v):
                finite = False
        if not finite:
            reason[i] = NOT_FINITE
            continue
        if not (math.isfinite(first_z[i]) and math.isfinite(drop[i]) and drop[i] > 0):
            reason[i] = NO_AXIS
            continue
        smoothed = np.empty(wave.size)
        _smooth(wave, widths[0], int(widths[1]), smoothed)
        back = mean + thresholds[1] * sd
        toploc, botloc = _extent(smoothed, subbins, mean + thresholds[0] * sd, back)
        if not math.isfinite(toploc):
            reason[i] = NO_SIGNAL
            continue
        scalars[i, 0], scalars[i, 1] = toploc, botloc
        zcross_smoothed = smoothed
        if widths[2] != widths[0] or widths[3] != widths[1]:
            zcross_smoothed = np.empty(wave.size)
            _smooth(wave, widths[2], int(widths[3]), zcross_smoothed)
        count = _modes(zcross_smoothed, toploc, botloc, back, subbins, position, amplitude)
        if count == 0:
            reason[i] = NO_GROUND
            continue
        reason[i] = MEASURED
        # the modes' energies and the RH from the waveform the modes are found on (rx_smoothing_width_zcross)
        top, bottom = int(round(toploc * subbins)), int(round(botloc * subbins))
        cumulative = _cumulative(zcross_smoothed, mean, top, bottom, subbins)
        ground = position[_ground_mode(zcross_smoothed, mean, position, amplitude, count, cumulative, bottom, botloc,
                                       back, subbins, select, mode_z.shape[1])]
        scalars[i, 2], scalars[i, 3], scalars[i, 9] = ground, first_z[i] - ground * drop[i], count
        first = max(count - mode_z.shape[1], 0)  # the lowest modes where there are more than the slots
        for j in range(first, count):
            mode_z[i, j - first] = first_z[i] - position[j] * drop[i]
        _relative_heights(cumulative, toploc, botloc, ground, drop[i], subbins, rh[i])
        canopy = np.empty(wave.size)
        rg = _canopy(wave, mean, toploc, botloc, ground, shape[i], buffers[0], buffers[1], canopy)
        rv = canopy.sum()
        denominator = rv + canopy_constants[0] * rg
        pgap = 1.0 - rv / denominator if denominator > 0 else 1.0
        scalars[i, 4], scalars[i, 5], scalars[i, 6] = rv, rg, pgap
        scalars[i, 7] = cos_zenith[i] * (1.0 - pgap)
        scalars[i, 8] = (-math.log(pgap) * cos_zenith[i] / (canopy_constants[1] * canopy_constants[2])
                         if pgap > 0 else np.inf)
        _profile(canopy, ground, drop[i], denominator, cos_zenith[i], canopy_constants[1], canopy_constants[2],
                 canopy_constants[3], cover_z[i], pai_z[i], pavd_z[i])
