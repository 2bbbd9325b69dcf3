"""The system response as the kernels see it: a table of echoes, the response broadened by Gaussians.

`echo_shape` turns a SystemResponse into the kernels' table (fwcore.engine.model.EchoShape): the response
broadened by Gaussians (a target's depth spreads its return), one row per echo
width, each row's peak 1, so an echo is A * row(s)(t - u) with A its peak
amplitude, u the time of the centroid of the response's main lobe (above 5% of
its peak: where a target's broadening leaves it, unlike the peak of a skewed
response) and s the sigma of the Gaussian of equal FWHM: the engine's width
parameter means the same in every model.
"""

from __future__ import annotations

import math

import numpy as np

from fwcore.engine.model import SQRT_2LN2, EchoShape
from fwcore.instrument.peak import half_height_crossings, half_height_width, main_lobe
from fwcore.instrument.response import SystemResponse

_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2
TABLE_STEPS_PER_SAMPLE = 16  # the echo table's time step: linear interpolation then errs < 1e-4 of the peak
# The echo table's rows step by this share of the response's own equal-FWHM sigma, from it to the widest echo
# allowed: the same rows whatever the widest, so a table rebuilt from a run's settings gives its echoes again.
ROW_STEP = 2.0 / 47.0
# A row's support ends where it stays below this share of its peak: a quarter of an 8-bit digitizer's
# step at full scale, so the kernels need not visit the samples a narrow echo cannot reach.
SUPPORT_LEVEL = 1e-3
CENTROID_FRACTION = 0.05  # an echo's position: the centroid of its response's lobe above this share of the peak


def lobe_centroid_ps(response: SystemResponse) -> float:
    """The centroid of the response's main lobe (above CENTROID_FRACTION of its peak), ps after its peak:
    where an echo of it is placed."""
    first, last = main_lobe(response.response, int(np.argmax(response.response)), CENTROID_FRACTION)
    lobe = response.response[first:last + 1]
    return float(np.sum(response.times[first:last + 1] * lobe) / np.sum(lobe))


# the tables this process made or was handed (the last _KEPT: echo_shape's cache): a run's plan makes its file's
# table, then hands it to the workers (echo_shapes_of, hand_over_echo_shapes), which would each spend 0.5 s making it
_MADE: dict[tuple, EchoShape] = {}
_KEPT = 64


def echo_shapes_of(response: SystemResponse) -> list[tuple[float, float, EchoShape]]:
    """The echo tables of `response` this process made or was handed: (spacing_ps, max_width_factor, table)."""
    return [(spacing, factor, shape) for (made, spacing, factor), shape in _MADE.items() if made == response]


def hand_over_echo_shapes(response: SystemResponse, tables: list[tuple[float, float, EchoShape]]) -> None:
    """Tables of `response` another process made (echo_shapes_of there): echo_shape gives them instead of making
    them anew (the same arrays: the same echoes)."""
    for spacing, factor, shape in tables:
        _keep((response, float(spacing), float(factor)), shape)


def _keep(key: tuple, shape: EchoShape) -> None:
    _MADE[key] = shape
    while len(_MADE) > _KEPT:
        _MADE.pop(next(iter(_MADE)))


def echo_shape(response: SystemResponse, spacing_ps: float, max_width_factor: float = 3.0) -> EchoShape:
    """The response in samples of `spacing_ps`, broadened by Gaussians to rows whose FWHM runs from its own
    to max_width_factor x it (steps of ROW_STEP x its equal-FWHM sigma), each row's peak 1 and its slope by
    central differences; a table handed over (hand_over_echo_shapes) where there is one."""
    key = (response, float(spacing_ps), float(max_width_factor))
    if key not in _MADE:
        _keep(key, _echo_table(response, spacing_ps, max_width_factor))
    return _MADE[key]


def _echo_table(response: SystemResponse, spacing_ps: float, max_width_factor: float) -> EchoShape:
    """echo_shape's table, made."""
    step = 1.0 / TABLE_STEPS_PER_SAMPLE
    # the echo's position is the centroid of the response's main lobe, not its peak: a target's broadening
    # moves the peak of a skewed response (Leica's) but hardly the lobe's first moment, so a response measured
    # on returns their targets widened and the instrument's own place an echo at the same time
    t_resp = (response.times - lobe_centroid_ps(response)) / spacing_ps
    f0 = response.fwhm_ps / spacing_ps
    s_min = f0 / _FWHM_PER_SIGMA
    n_rows = int(math.ceil((max_width_factor - 1.0) / ROW_STEP - 1e-9)) + 1
    s_max = s_min * (1.0 + ROW_STEP * (n_rows - 1))
    widest = math.sqrt(max(s_max ** 2 - s_min ** 2, 0.0))  # the broadening of the widest row, roughly
    lo = math.floor((t_resp[0] - 4.0 * widest) / step)
    hi = math.ceil((t_resp[-1] + 4.0 * widest) / step)
    t = np.arange(lo, hi + 1) * step
    base = np.interp(t, t_resp, response.response, left=0.0, right=0.0)
    # FWHM as a function of the broadening sigma b, on a fine b grid, inverted for each row's width
    b_grid = np.arange(0.0, 1.5 * max(widest, step) + s_min / 32.0, s_min / 64.0)  # fixed steps, like the rows
    targets = np.linspace(s_min, s_max, n_rows) * _FWHM_PER_SIGMA
    fwhms = _broadened_fwhms(t, base, b_grid / step, targets[-1])
    rows = np.empty((n_rows, t.size))
    for w, f in enumerate(targets):
        b = float(np.interp(f, fwhms, b_grid))
        r = _broaden(base, b / step)
        rows[w] = r / r.max()
    support = np.empty((n_rows, 2), dtype=np.int64)
    for w in range(n_rows):
        above = np.flatnonzero(np.abs(rows[w]) > SUPPORT_LEVEL)
        support[w] = above[0], above[-1]
        rows[w, :above[0]] = 0.0  # so that every evaluation, windowed or not, gives the same echo
        rows[w, above[-1] + 1:] = 0.0
    slopes = np.gradient(rows, step, axis=1)
    areas = rows.sum(axis=1) * step
    peak_offsets = (np.argmax(rows, axis=1) + lo) * step
    crest = int(np.argmax(rows[0]))
    left, right = half_height_crossings(rows[0], np.ones(t.size, dtype=np.bool_), crest, rows[0, crest])
    half_widths = np.array([(crest - left) * step, (right - crest) * step])
    return EchoShape(True, rows, slopes, areas, support, peak_offsets, half_widths, step, float(-lo), s_min,
                     s_min * ROW_STEP)


def _broadened_fwhms(t: np.ndarray, base: np.ndarray, sigmas_steps: np.ndarray, widest_fwhm: float) -> np.ndarray:
    """The FWHM of `base` broadened by each of `sigmas_steps` (increasing), measured up to the first past
    `widest_fwhm` and infinite beyond: past its first few steps a wider Gaussian only widens the response, so the
    broadenings beyond bracket no row and compare alike in interpolation's search (the grid's length kept: the
    rows' widths come out the same to the bit), and their convolutions, the widest and half the cost, are skipped."""
    fwhms = np.full(sigmas_steps.size, np.inf)
    for k, sigma in enumerate(sigmas_steps):
        fwhms[k] = half_height_width(t, _broaden(base, sigma))
        if fwhms[k] > widest_fwhm:
            break
    return fwhms


def _broaden(values: np.ndarray, sigma_steps: float) -> np.ndarray:
    """values convolved with a unit-area Gaussian of sigma_steps grid steps (the same grid, zero beyond)."""
    if sigma_steps < 1e-3:
        return values.copy()
    half = int(math.ceil(5.0 * sigma_steps))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_steps) ** 2)
    return np.convolve(values, k / k.sum(), mode="same") if half < values.size else values.copy()
