"""The instrument's response: what one return from a point target looks like in its digitizer, measured once per
source.

A `SystemResponse` is the emitted pulse through the receiver, with whatever
the receiver adds (Leica's slow rise, tail and undershoot; RIEGL's afterpulse
10 ns behind the peak). It is measured from

- the system's single returns (a LAS file's points with one return) or, where
  a file records none, its strongest isolated echoes: aligned at sub-sample
  precision on their peak, binned finely (the waveforms' random sub-sample
  phases sample the pulse between the digitizer's samples) and averaged by
  median;
- a recorded impulse response or outgoing pulse (NEON's `system_impulse.csv`);
- nothing: the Gaussian of a given FWHM, said so.

Its time 0 is its peak. fwcore.instrument.shape turns it into the kernels' echo table.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fwcore.instrument.peak import half_height_width, isolated_lobe, local_maxima, parabola_height, parabola_vertex
from fwcore.engine.model import SQRT_2LN2
from fwcore.engine.preprocess import noise_and_background

_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2
BINS_PER_SAMPLE = 4  # the measured response's resolution: a quarter of the digitizer's sample
MIN_SNR = 30.0  # a return this far above the noise shows the response's tail and afterpulse
OUTSIDE_FRACTION = 0.15  # of the peak: a sample outside the return's lobe above this is another return
MIN_PULSES = 20  # fewer strong single returns than this measure nothing
RESPONSE_PULSES = 3000  # candidates for the response: a few hundred strong single returns among them
CSV_SPACING_PS = 1000.0  # a response CSV's samples: 1 ns apart, as in NEON's system_impulse.csv


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
        return half_height_width(self.times, self.response)

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


# Responses shipped with the package, measured by fwcore.instrument.measure on the shared samples: the Leica sample's
# single returns (2 ns digitizer) and the RIEGL Q680 file's isolated echoes (1 ns).
SHIPPED = {"leica": "leica.json", "riegl": "riegl.json"}
SHIPPED_SPACING_PS = {"leica": 2000.0, "riegl": 1000.0}


def named_response(name: str, pulse_fwhm_ps: float = 4000.0) -> SystemResponse:
    """A response by name: `gaussian` (of pulse_fwhm_ps), a shipped instrument (`leica`, `riegl`) or a file."""
    if name == "gaussian":
        return gaussian_response(pulse_fwhm_ps)
    if name in SHIPPED:
        text = (Path(__file__).parents[1] / "responses" / SHIPPED[name]).read_text()
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


def load_response(path: str | Path, spacing_ps: float = CSV_SPACING_PS) -> SystemResponse:
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


# ---------------------------------------------------------------- measured on returns

@dataclasses.dataclass(frozen=True)
class _Return:
    signal: np.ndarray  # samples minus background
    peak_time: float  # samples, sub-sample
    height: float
    fwhm: float  # samples


def _strong_single_return(samples: np.ndarray, noise: float, background: float) -> _Return | None:
    """The waveform as one strong return, or None: SNR >= MIN_SNR, not clipped, one local maximum in its main
    lobe (lightly smoothed), nothing above OUTSIDE_FRACTION of the peak outside it, and its lobe clear of the
    edges (fwcore.instrument.peak.isolated_lobe)."""
    v = samples - background
    peak = int(np.argmax(v))
    if peak < 2 or peak > v.size - 3:
        return None
    if v[peak - 1] == v[peak] or v[peak + 1] == v[peak]:
        return None  # a flat top: the digitizer clipped it
    lobe = isolated_lobe(v, peak, MIN_SNR * noise, OUTSIDE_FRACTION)
    if lobe is None:
        return None
    lo, hi = lobe
    if local_maxima(np.convolve(v[lo:hi + 1], [0.25, 0.5, 0.25], mode="same")) > 1:
        return None  # a shoulder: two returns in one lobe
    shift = parabola_vertex(v, peak)
    h = parabola_height(v, peak, shift)
    return _Return(v, peak + shift, h, half_height_width(np.arange(v.size, dtype=float), v))


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


def response_of_waveforms(waveforms, spacing_ps: float, source: str) -> SystemResponse | None:
    """The system response from waveforms (float arrays of valid samples): their strong single returns
    aligned and averaged (measure_response), or None where too few are strong and single."""
    waveforms = [w for w in (np.asarray(w, dtype=float) for w in waveforms[:RESPONSE_PULSES]) if np.isfinite(w).all()]
    noise_background = [noise_and_background(w) if w.size >= 12 else (np.inf, 0.0) for w in waveforms]
    try:
        return measure_response(waveforms, spacing_ps, source, [n for n, _ in noise_background],
                                [b for _, b in noise_background])
    except ValueError:
        return None


def pulses_response(pulses, rows: np.ndarray, source: str) -> SystemResponse | None:
    """The system response from pulses[rows] (response_of_waveforms)."""
    rows = rows[:RESPONSE_PULSES]
    return response_of_waveforms([pulses.pulse_samples(i) for i in rows],
                                 float(np.median(pulses.sample_spacing_ps[rows])), source)


def file_response(pulses) -> SystemResponse | None:
    """The response of a file's first pulses: on its transmitted waveforms where it records them with their
    shape (GEDI), else on the system's single returns where the file has them, otherwise on its strongest
    isolated echoes; None where too few qualify."""
    if pulses.outgoing is not None and pulses.outgoing.size and pulses.transmit_shape is not None:
        # GEDI records each shot's transmitted pulse, which its returns are made of (PulseWaves' outgoing
        # waveforms are the system's own monitor channel, not measured here as the response)
        spacing = float(np.median(pulses.outgoing_spacing_ps))
        response = response_of_waveforms([pulses.outgoing_samples(i) for i in range(len(pulses))], spacing,
                                         "transmitted waveforms")
        if response is not None:
            return response
    single = np.flatnonzero(np.diff(pulses.return_offsets) == 1)
    response = pulses_response(pulses, single, "single returns") if single.size else None
    return response or pulses_response(pulses, np.arange(len(pulses)), "isolated echoes")


def csv_response(samples, valid, spacing_ps: float, outgoing=None) -> SystemResponse | None:
    """A NEON-layout CSV's response: on its outgoing pulses (fwcore.io.neon.CsvWaveforms) where given and
    enough qualify, else on the returns' strong single echoes; None where too few qualify."""
    response = None
    if outgoing is not None:
        response = response_of_waveforms([y[v] for y, v in zip(outgoing.samples, outgoing.valid)], spacing_ps,
                                         "outgoing pulses")
    if response is None:
        response = response_of_waveforms([y[v] for y, v in zip(samples, valid)], spacing_ps, "isolated echoes")
    return response
