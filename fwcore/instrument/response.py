"""The instrument's response: what one return from a point target looks like in its digitizer, as data.

A `SystemResponse` is the emitted pulse through the receiver, with whatever
the receiver adds (Leica's slow rise, tail and undershoot; RIEGL's afterpulse
10 ns behind the peak), and where it came from. This module holds it, saves
and loads it (`to_dict` / `from_dict`, JSON, a recorded impulse response's
CSV such as NEON's `system_impulse.csv`), names the shipped ones and makes
the Gaussian of a given FWHM (where nothing measured the instrument).
Measuring it on a file's strong single returns runs the engine's noise
estimate and lives a floor above, in fwcore.instrument.measure.

Its time 0 is its peak. fwcore.instrument.shape turns it into the kernels' echo table.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from fwcore.engine.model import SQRT_2LN2
from fwcore.instrument.peak import half_height_width, parabola_height, parabola_vertex

_FWHM_PER_SIGMA = 2.0 * SQRT_2LN2
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
