"""The instrument's own pulse: its system response, measured once per source, and the echo shape built from it.

A `SystemResponse` is what one return from a point target looks like in the
instrument's digitizer: the emitted pulse through the receiver, with whatever
the receiver adds (Leica's slow rise, tail and undershoot; RIEGL's afterpulse
10 ns behind the peak). It is measured from

- the system's single returns (a LAS file's points with one return) or, where
  a file records none, its strongest isolated echoes: aligned at sub-sample
  precision on their peak, binned finely (the waveforms' random sub-sample
  phases sample the pulse between the digitizer's samples) and averaged by
  median;
- a recorded impulse response or outgoing pulse (NEON's `system_impulse.csv`);
- nothing: the Gaussian of a given FWHM, said so.

Its time 0 is its peak. `echo_shape` turns it into the kernels' table: the
response broadened by Gaussians (a target's depth spreads its return), one row
per echo width, each row's peak 1, so an echo is A * row(s)(t - u) with A its
peak amplitude, u the time of the centroid of the response's main lobe (above 5%
of its peak: where a target's broadening leaves it, unlike the peak of a skewed
response) and s the sigma of the Gaussian of equal FWHM: the engine's width
parameter means the same in every model.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import math
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.model import SQRT_2LN2

_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2
BINS_PER_SAMPLE = 4  # the measured response's resolution: a quarter of the digitizer's sample
TABLE_STEPS_PER_SAMPLE = 16  # the echo table's time step: linear interpolation then errs < 1e-4 of the peak
# The echo table's rows step by this share of the response's own equal-FWHM sigma, from it to the widest echo
# allowed: the same rows whatever the widest, so a table rebuilt from a run's settings gives its echoes again.
ROW_STEP = 2.0 / 47.0
# A row's support ends where it stays below this share of its peak: a quarter of an 8-bit digitizer's
# step at full scale, so the kernels need not visit the samples a narrow echo cannot reach.
SUPPORT_LEVEL = 1e-3
MIN_SNR = 30.0  # a return this far above the noise shows the response's tail and afterpulse
MIN_PULSES = 20  # fewer strong single returns than this measure nothing
CENTROID_FRACTION = 0.05  # an echo's position: the centroid of its response's lobe above this share of the peak


@dataclasses.dataclass(frozen=True)
class SystemResponse:
    """The instrument's response to a point target, peak 1 at time 0, on a fine grid (ps), and its source."""

    times_ps: tuple[float, ...]
    values: tuple[float, ...]
    source: str  # e.g. "single returns (412 of 5000 pulses)", "system_impulse.csv", "Gaussian, FWHM 4000 ps"
    n_pulses: int = 0  # the returns averaged into it (0: not measured on returns)

    def __post_init__(self) -> None:
        # held at the precision it is saved with (to_dict), so a response read back is the one measured
        object.__setattr__(self, "times_ps", tuple(round(float(x), 3) for x in self.times_ps))
        object.__setattr__(self, "values", tuple(round(float(x), 6) for x in self.values))
        t, v = np.asarray(self.times_ps, float), np.asarray(self.values, float)
        if t.size < 5 or t.size != v.size or not np.all(np.diff(t) > 0) or not np.isfinite(v).all():
            raise ValueError(f"system response ({self.source}): need >= 5 increasing, finite samples")

    @property
    def times(self) -> np.ndarray:
        return np.asarray(self.times_ps, dtype=float)

    @property
    def response(self) -> np.ndarray:
        return np.asarray(self.values, dtype=float)

    @property
    def fwhm_ps(self) -> float:
        return _half_height_width(self.times, self.response)

    def at(self, t_ps) -> np.ndarray:
        """The response at times t (ps), 0 outside its grid."""
        return np.interp(np.asarray(t_ps, float), self.times, self.response, left=0.0, right=0.0)

    def afterpulse(self, after_ps: float | None = None) -> tuple[float, float]:
        """(delay ps, height) of the highest local maximum behind the main lobe (after it falls below 10%),
        or (nan, 0) where there is none."""
        t, v = self.times, self.response
        peak = int(np.argmax(v))
        end = peak + int(np.argmax(v[peak:] < 0.1)) if (v[peak:] < 0.1).any() else v.size
        if after_ps is not None:
            end = max(end, int(np.searchsorted(t, after_ps)))
        tail = v[end:]
        maxima = np.flatnonzero((tail[1:-1] > tail[:-2]) & (tail[1:-1] >= tail[2:])) + 1
        if maxima.size == 0:
            return float("nan"), 0.0
        best = maxima[np.argmax(tail[maxima])]
        return float(t[end + best]), float(tail[best])

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "n_pulses": self.n_pulses, "fwhm_ps": round(self.fwhm_ps, 1),
                "times_ps": list(self.times_ps), "values": list(self.values)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SystemResponse":
        return cls(tuple(map(float, d["times_ps"])), tuple(map(float, d["values"])), str(d["source"]),
                   int(d.get("n_pulses", 0)))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")


def gaussian_response(fwhm_ps: float) -> SystemResponse:
    """The Gaussian of a given FWHM as a response (the model where nothing measured the instrument)."""
    sigma = fwhm_ps / _FWHM_PER_SIGMA
    t = np.linspace(-5.0 * sigma, 5.0 * sigma, 201)
    return SystemResponse(tuple(t), tuple(np.exp(-0.5 * (t / sigma) ** 2)), f"Gaussian, FWHM {fwhm_ps:.0f} ps")


# Responses shipped with the package, measured by fwcore.survey on the shared samples: the Leica sample's
# single returns (2 ns digitizer) and the RIEGL Q680 file's isolated echoes (1 ns).
SHIPPED = {"leica": "leica.json", "riegl": "riegl.json"}
SHIPPED_SPACING_PS = {"leica": 2000.0, "riegl": 1000.0}


def named_response(name: str, pulse_fwhm_ps: float = 4000.0) -> SystemResponse:
    """A response by name: `gaussian` (of pulse_fwhm_ps), a shipped instrument (`leica`, `riegl`) or a file."""
    if name == "gaussian":
        return gaussian_response(pulse_fwhm_ps)
    if name in SHIPPED:
        text = (Path(__file__).parent / "responses" / SHIPPED[name]).read_text()
        return SystemResponse.from_dict(json.loads(text))
    return load_response(name)


def response_from_samples(samples, spacing_ps: float, source: str, n_pulses: int = 0) -> SystemResponse:
    """A response recorded as digitizer samples (an impulse response or an outgoing pulse): the background
    (the median of the samples below 10% of the range) removed, peak located by a parabola and put at 0."""
    y = np.asarray(samples, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 5 or np.ptp(y) <= 0:
        raise ValueError(f"{source}: a response needs at least 5 samples that vary")
    base = float(np.median(y[y <= y.min() + 0.1 * np.ptp(y)]))
    v = y - base
    peak = int(np.argmax(v))
    shift = parabola_vertex(v, peak)
    t = (np.arange(y.size) - peak - shift) * float(spacing_ps)
    height = parabola_height(v, peak, shift)
    return SystemResponse(tuple(t), tuple(v / height), source, n_pulses)


def load_response(path: str | Path, spacing_ps: float = 1000.0) -> SystemResponse:
    """A response from a file: our JSON (`SystemResponse.save`, `fwl info --json`), or a CSV whose first
    column holds the response's samples at `spacing_ps` (NEON's `system_impulse.csv`; zero padding dropped)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise ValueError(f"{path}: cannot read the system response ({err.strerror})") from None
    if path.suffix.lower() == ".json":
        try:
            d = json.loads(text)
            if isinstance(d, list):  # fwl info of several files: the one file's
                (d,) = d
            return SystemResponse.from_dict(d.get("system_response", d))
        except (ValueError, KeyError, TypeError, AttributeError) as err:
            raise ValueError(f"{path}: not a system response JSON ({err})") from None
    rows = list(csv.reader(text.splitlines()))
    values = []
    for row in rows:
        try:
            values.append(float(row[0]))
        except (ValueError, IndexError):
            continue  # the header
    y = np.asarray(values)
    y = y[:np.flatnonzero(y != 0)[-1] + 1] if (y != 0).any() else y  # zero padding after the record
    try:
        return response_from_samples(y, spacing_ps, path.name)
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None


@njit(**JIT)
def parabola_vertex(v, i):
    """Where the parabola through v[i - 1], v[i], v[i + 1] peaks, in samples from i (within half a sample;
    0 at an edge or where v does not bend down there)."""
    if i <= 0 or i >= v.size - 1:
        return 0.0
    den = v[i - 1] - 2.0 * v[i] + v[i + 1]
    return min(max(0.5 * (v[i - 1] - v[i + 1]) / den, -0.5), 0.5) if den < 0 else 0.0


@njit(**JIT)
def parabola_height(v, i, shift):
    """That parabola's height `shift` samples from i."""
    if i <= 0 or i >= v.size - 1:
        return float(v[i])
    return v[i] - 0.25 * (v[i - 1] - v[i + 1]) * shift


@njit(**JIT)
def half_height_crossings(values, valid, peak, height):
    """(left, right): where the values first fall to half of `height` walking out from index `peak` over valid
    samples, interpolated; -1.0 for a side that does not fall that far."""
    half = 0.5 * height
    left = -1.0
    i = peak
    while i > 0 and valid[i - 1]:
        if values[i - 1] <= half:
            left = (i - 1) + (half - values[i - 1]) / (values[i] - values[i - 1])
            break
        i -= 1
    right = -1.0
    i = peak
    while i < values.size - 1 and valid[i + 1]:
        if values[i + 1] <= half:
            right = i + (values[i] - half) / (values[i] - values[i + 1])
            break
        i += 1
    return left, right


def _half_height_width(t: np.ndarray, v: np.ndarray) -> float:
    peak = int(np.argmax(v))
    half = 0.5 * v[peak]
    left = peak
    while left > 0 and v[left - 1] > half:
        left -= 1
    right = peak
    while right < v.size - 1 and v[right + 1] > half:
        right += 1
    lx = np.interp(half, [v[left - 1], v[left]], [t[left - 1], t[left]]) if left > 0 else t[0]
    rx = np.interp(half, [v[right + 1], v[right]], [t[right + 1], t[right]]) if right < v.size - 1 else t[-1]
    return float(rx - lx)


# ---------------------------------------------------------------- measured on returns

@dataclasses.dataclass(frozen=True)
class _Return:
    signal: np.ndarray  # samples minus background
    peak_time: float  # samples, sub-sample
    height: float
    fwhm: float  # samples


def main_lobe(signal: np.ndarray, peak: int, fraction: float) -> tuple[int, int]:
    """The first and last sample of the run around `peak` where signal stays above fraction x its height."""
    above = signal > fraction * signal[peak]
    lo = peak
    while lo > 0 and above[lo - 1]:
        lo -= 1
    hi = peak
    while hi < signal.size - 1 and above[hi + 1]:
        hi += 1
    return lo, hi


def _strong_single_return(samples: np.ndarray, noise: float, background: float) -> _Return | None:
    """The waveform as one strong return, or None: SNR >= MIN_SNR, not clipped, one local maximum above 10%
    of the peak in its main lobe, nothing above 15% of the peak outside it, and its lobe clear of the edges."""
    v = samples - background
    peak = int(np.argmax(v))
    height = v[peak]
    if height < MIN_SNR * noise or peak < 2 or peak > v.size - 3:
        return None
    if v[peak - 1] == height or v[peak + 1] == height:
        return None  # a flat top: the digitizer clipped it
    lo, hi = main_lobe(v, peak, 0.1)
    if lo == 0 or hi == v.size - 1:
        return None
    outside = np.concatenate([v[:lo], v[hi + 1:]])
    if outside.size and outside.max() > 0.15 * height:
        return None  # another return in the record
    lobe = np.convolve(v[lo:hi + 1], [0.25, 0.5, 0.25], mode="same")
    maxima = np.flatnonzero((lobe[1:-1] > lobe[:-2]) & (lobe[1:-1] >= lobe[2:]))
    if maxima.size > 1:
        return None  # a shoulder: two returns in one lobe
    shift = parabola_vertex(v, peak)
    h = parabola_height(v, peak, shift)
    return _Return(v, peak + shift, h, _half_height_width(np.arange(v.size, dtype=float), v))


def measure_response(waveforms: Sequence[np.ndarray], spacing_ps: float, source: str,
                     noise: Sequence[float], background: Sequence[float],
                     min_pulses: int = MIN_PULSES) -> SystemResponse:
    """The response from returns a target did not shape much: the strong single returns among `waveforms`
    (with each one's noise sigma and background), the narrower half of them by FWHM (a target only ever
    widens a return), aligned on their sub-sample peaks and normalised to it, binned at a quarter sample
    and averaged by median per bin. Raises when fewer than `min_pulses` qualify."""
    returns = [r for y, s, b in zip(waveforms, noise, background)
               if len(y) >= 12 for r in [_strong_single_return(np.asarray(y, float), s, b)] if r is not None]
    if len(returns) < min_pulses:
        raise ValueError(f"only {len(returns)} strong single returns (need {min_pulses}) to measure the "
                         "system response")
    widths = np.array([r.fwhm for r in returns])
    narrow = [r for r in returns if r.fwhm <= np.median(widths)]
    width = float(np.median([r.fwhm for r in narrow]))
    before, after = 2.5 * width, 6.0 * width  # the tail, undershoot and afterpulse lie behind the peak
    edges = np.arange(-before, after + 1e-9, 1.0 / BINS_PER_SAMPLE)
    offsets, values = [], []
    for r in narrow:
        d = np.arange(r.signal.size) - r.peak_time
        keep = (d >= edges[0]) & (d < edges[-1])
        offsets.append(d[keep])
        values.append(r.signal[keep] / r.height)
    d, v = np.concatenate(offsets), np.concatenate(values)
    bins = np.digitize(d, edges) - 1
    counts = np.bincount(bins, minlength=edges.size)
    centres = edges + 0.5 / BINS_PER_SAMPLE
    order = np.argsort(bins, kind="stable")
    groups = np.split(v[order], np.cumsum(counts)[:-1])
    filled = counts >= 3
    median = np.array([np.median(g) if ok else np.nan for g, ok in zip(groups, filled)])
    # a bin's median is noisy where few returns fall in it: one light pass of [1, 2, 1] / 4
    known = np.interp(centres, centres[filled], median[filled])
    smooth = np.convolve(np.pad(known, 1, mode="edge"), [0.25, 0.5, 0.25], mode="valid")
    first, last = np.flatnonzero(filled)[[0, -1]]
    t, y = centres[first:last + 1], smooth[first:last + 1]
    peak = int(np.argmax(y))
    shift = parabola_vertex(y, peak)
    height = parabola_height(y, peak, shift)
    t = (t - t[peak] - shift / BINS_PER_SAMPLE) * spacing_ps
    y = y / height
    y[[0, -1]] = 0.0  # the response ends at its grid's edges
    return SystemResponse(tuple(t), tuple(y), f"{source} ({len(narrow)} of {len(returns)} strong single returns)",
                          len(narrow))


# ---------------------------------------------------------------- the kernels' echo shape

class EchoShape(NamedTuple):
    """An echo model as the kernels see it. tabulated False: the generalized Gaussian (its parameters
    alone define it; the arrays are empty). True: rows[w] is the response broadened to the w-th width,
    peak 1, at times (j - origin) * step samples; slopes its time derivative per sample."""

    tabulated: bool
    rows: np.ndarray  # (widths, grid) float64
    slopes: np.ndarray  # (widths, grid) float64, d row / dt per sample
    areas: np.ndarray  # (widths,) integral of each row, samples
    support: np.ndarray  # (widths, 2) int64: the grid indices [first, last] where each row exceeds SUPPORT_LEVEL
    peak_offsets: np.ndarray  # (widths,) where each row peaks, samples after the echo's position (its lobe's centroid)
    half_widths: np.ndarray  # (2,) row 0 from its peak to half height before and after it, samples
    step: float  # samples per grid point
    origin: float  # grid index of t = 0, the echo's position (the centroid of the response's main lobe)
    s_min: float  # the equal-FWHM Gaussian sigma (samples) of row 0: the response's own
    s_step: float  # between rows


def analytic_shape() -> EchoShape:
    """The generalized Gaussian's (and the Gaussian's) EchoShape: no table."""
    empty = np.zeros((1, 2))
    return EchoShape(False, empty, empty, np.zeros(1), np.zeros((1, 2), dtype=np.int64), np.zeros(1), np.ones(2), 1.0,
                     0.0, 0.0, 1.0)


def lobe_centroid_ps(response: SystemResponse) -> float:
    """The centroid of the response's main lobe (above CENTROID_FRACTION of its peak), ps after its peak:
    where an echo of it is placed."""
    first, last = main_lobe(response.response, int(np.argmax(response.response)), CENTROID_FRACTION)
    lobe = response.response[first:last + 1]
    return float(np.sum(response.times[first:last + 1] * lobe) / np.sum(lobe))


@functools.lru_cache(maxsize=64)
def echo_shape(response: SystemResponse, spacing_ps: float, max_width_factor: float = 3.0) -> EchoShape:
    """The response in samples of `spacing_ps`, broadened by Gaussians to rows whose FWHM runs from its own
    to max_width_factor x it (steps of ROW_STEP x its equal-FWHM sigma), each row's peak 1 and its slope by
    central differences."""
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
    broadened = [_broaden(base, b / step) for b in b_grid]
    fwhms = np.array([_half_height_width(t, r) for r in broadened])
    targets = np.linspace(s_min, s_max, n_rows) * _FWHM_PER_SIGMA
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


def _broaden(values: np.ndarray, sigma_steps: float) -> np.ndarray:
    """values convolved with a unit-area Gaussian of sigma_steps grid steps (the same grid, zero beyond)."""
    if sigma_steps < 1e-3:
        return values.copy()
    half = int(math.ceil(5.0 * sigma_steps))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_steps) ** 2)
    return np.convolve(values, k / k.sum(), mode="same") if half < values.size else values.copy()
