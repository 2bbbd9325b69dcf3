"""The engine's records: waveforms in (WaveformBatch), results out (Decomposition, BatchDecomposition).

Times and widths in samples (time 0 = the first sample); amplitudes in digitizer units.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from fwcore.engine.filter import REJECT_REASONS
from fwcore.engine.model import (EchoShape, analytic_shape, batch_model, generalized_gaussian, tabulated_model,
                                 waveform_model)

STATUS_OK, STATUS_NO_VALID_SAMPLES, STATUS_NON_FINITE = 0, 1, 2
STATUS_REASONS = ("", "no_valid_samples", "non_finite_samples")
# How the optimizer ended, per waveform (codes of fwcore.engine.config: MSG_*).
MESSAGES = ("no_echoes", "converged", "max_generations", "max_iterations", "not_optimized")

# The per-waveform result, one record per waveform: the one declaration of its fields, which the kernels write by
# name and BatchDecomposition and Decomposition expose (aligned: int8 codes sit among float64s).
WAVEFORM_RESULT = np.dtype([
    ("status", np.int8),  # codes into STATUS_REASONS, set before the kernels (which skip a waveform with one)
    ("background", np.float64), ("noise_sigma", np.float64), ("fit_error", np.float64), ("fit_error_raw", np.float64),
    ("rmse", np.float64), ("r2", np.float64), ("nfev", np.int64), ("nit", np.int64),
    ("message", np.int8),  # codes into MESSAGES
    ("n_echoes_initial", np.int64), ("n_echoes_dropped", np.int64), ("n_echoes_added", np.int64),
    ("n_echoes", np.int64),  # the kernel's count; public as the batch's echo_offsets
], align=True)
WAVEFORM_FIELDS = tuple(name for name in WAVEFORM_RESULT.names if name != "n_echoes")  # the results' attributes
# The fields whose int8 codes a Decomposition (and a table) spells out as strings.
WAVEFORM_CODES = {"status": STATUS_REASONS, "message": MESSAGES}
# One echo in Chauve's parameters (fwcore.engine.model), sorted by position within its waveform.
ECHO_RESULT = np.dtype([("amplitude", np.float64), ("position", np.float64), ("sigma", np.float64),
                        ("alpha", np.float64), ("reason", np.int8)])


@dataclasses.dataclass(frozen=True)
class WaveformBatch:
    """Many waveforms as flat arrays: waveform i is samples[offsets[i]:offsets[i+1]]."""

    samples: np.ndarray  # float64, digitizer units
    valid: np.ndarray  # bool: False for padding and gaps
    offsets: np.ndarray  # int64, n + 1
    sample_spacing_ps: np.ndarray  # float64, n
    seeds: np.ndarray  # uint64, n: from fwcore.rng.pulse_seed
    # float64, n: the noise sigma the file records per waveform (GEDI's L1B), below which the engine's own estimate
    # may not fall: a waveform the instrument smoothed has correlated noise its residuals underestimate; None: 0
    noise_floor: np.ndarray | None = None

    def __len__(self) -> int:
        return self.offsets.size - 1

    @classmethod
    def from_waveforms(cls, waveforms: Sequence[np.ndarray], sample_spacing_ps, seeds,
                       valid: Sequence[np.ndarray] | None = None) -> "WaveformBatch":
        n = len(waveforms)
        lengths = np.array([len(w) for w in waveforms], dtype=np.int64)
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(lengths, out=offsets[1:])
        samples = (np.concatenate([np.asarray(w, dtype=np.float64) for w in waveforms])
                   if n else np.zeros(0))
        mask = (np.concatenate([np.asarray(v, dtype=bool) for v in valid]) if valid is not None and n
                else np.ones(samples.size, dtype=bool))
        if mask.shape != samples.shape:
            raise ValueError("valid masks must match the waveforms' lengths")
        spacing = np.broadcast_to(np.asarray(sample_spacing_ps, dtype=np.float64), (n,)).copy()
        seeds = np.asarray(seeds, dtype=np.uint64).reshape(n)
        return cls(samples, mask, offsets, spacing, seeds)


@dataclasses.dataclass(frozen=True)
class Decomposition:
    """One waveform's result. Times and widths in samples (time 0 = first sample)."""

    # WAVEFORM_FIELDS in their order, codes as strings (BatchDecomposition.waveform fills them by name)
    status: str  # "" when decomposed, else why not
    background: float
    noise_sigma: float
    fit_error: float  # Eq. 9: the sum of absolute residuals against the denoised samples (DN)
    fit_error_raw: float  # the same sum of absolute residuals against the raw samples
    rmse: float  # against the raw samples
    r2: float
    nfev: int
    nit: int  # the optimizer's generations or iterations
    message: str  # how the optimizer ended (MESSAGES)
    n_echoes_initial: int
    n_echoes_dropped: int  # by the model-order selection, or set aside unfitted beside a strong echo (strong_echo)
    n_echoes_added: int
    amplitude: np.ndarray
    position: np.ndarray
    sigma: np.ndarray  # Chauve's sigma, samples**(alpha**2 / 2); of a tabulated echo its equal-FWHM sigma
    alpha: np.ndarray  # NaN for echoes of the system response
    fwhm: np.ndarray
    energy: np.ndarray  # area under each echo, digitizer units x samples
    reject_reason: tuple[str, ...]  # "" for kept echoes
    shape: EchoShape | None = None  # the echoes' tabulated response (system model), None: generalized Gaussians

    @property
    def kept(self) -> np.ndarray:
        return np.array([r == "" for r in self.reject_reason], dtype=bool)

    def echo(self, k: int, t) -> np.ndarray:
        """Echo k alone at times t (no background)."""
        if self.shape is not None:
            return tabulated_model(t, 0.0, self.amplitude[k], self.position[k], self.sigma[k], self.shape)
        return generalized_gaussian(t, self.amplitude[k], self.position[k], self.sigma[k], self.alpha[k])

    def model(self, t) -> np.ndarray:
        if self.shape is not None:
            return tabulated_model(t, self.background, self.amplitude, self.position, self.sigma, self.shape)
        return waveform_model(t, self.background, self.amplitude, self.position, self.sigma, self.alpha)


@dataclasses.dataclass(frozen=True)
class BatchDecomposition:
    """A batch's results, columnar: per waveform (n records of WAVEFORM_RESULT, whose fields but n_echoes are
    attributes: result.nfev, result.status) and per echo (flat, echo_offsets)."""

    per_waveform: np.ndarray  # WAVEFORM_RESULT, n
    echo_offsets: np.ndarray  # n + 1
    amplitude: np.ndarray
    position: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    fwhm: np.ndarray
    energy: np.ndarray
    reject: np.ndarray  # int8 codes into fwcore.engine.filter.REJECT_REASONS
    shapes: dict[float, EchoShape] | None = None  # per sample spacing (ps), under the system model
    sample_spacing_ps: np.ndarray | None = None  # per waveform: which of `shapes` its echoes take

    def __getattr__(self, name: str) -> np.ndarray:
        # the per-waveform attributes are the record's fields, not a second list of them
        if name in WAVEFORM_FIELDS:
            return self.per_waveform[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return [*super().__dir__(), *WAVEFORM_FIELDS]

    def __len__(self) -> int:
        return self.per_waveform.size

    @property
    def echo_waveform(self) -> np.ndarray:
        """For each echo, the index of its waveform in the batch."""
        return np.repeat(np.arange(len(self)), np.diff(self.echo_offsets))

    def waveform(self, i: int) -> Decomposition:
        lo, hi = self.echo_offsets[i], self.echo_offsets[i + 1]
        record = self.per_waveform[i]
        return Decomposition(
            **{name: WAVEFORM_CODES[name][record[name]] if name in WAVEFORM_CODES else record[name].item()
               for name in WAVEFORM_FIELDS},
            amplitude=self.amplitude[lo:hi], position=self.position[lo:hi], sigma=self.sigma[lo:hi],
            alpha=self.alpha[lo:hi], fwhm=self.fwhm[lo:hi], energy=self.energy[lo:hi],
            reject_reason=tuple(REJECT_REASONS[r] for r in self.reject[lo:hi]), shape=self.shape_of(i))

    def shape_of(self, i: int) -> EchoShape | None:
        """The tabulated shape of waveform i's echoes (None: generalized Gaussians)."""
        if self.shapes is None:
            return None
        return self.shapes[float(self.sample_spacing_ps[i])]


def model_samples(result: BatchDecomposition, sample_offsets: np.ndarray) -> np.ndarray:
    """Each decomposed pulse's fitted model at its sample times, flat like the samples (0 where not decomposed),
    as float32 (fitted_model's)."""
    return fitted_model(result, sample_offsets).astype(np.float32)


def fitted_model(result: BatchDecomposition, sample_offsets: np.ndarray) -> np.ndarray:
    """Each decomposed pulse's fitted model at its sample times, flat like the samples (0 where not decomposed),
    float64: one kernel call per echo shape (fwcore.engine.model.batch_model), no Python per pulse."""
    model = np.zeros(int(sample_offsets[-1]), dtype=np.float64)
    ok = result.status == 0
    offsets = np.asarray(sample_offsets, dtype=np.int64)
    echo_offsets = np.asarray(result.echo_offsets, dtype=np.int64)
    groups = ([(None, ok)] if result.shapes is None else
              [(shape, ok & (result.sample_spacing_ps == spacing)) for spacing, shape in result.shapes.items()])
    for shape, rows in groups:
        batch_model(np.flatnonzero(rows), offsets, echo_offsets, result.background.astype(np.float64),
                    result.amplitude, result.position, result.sigma, result.alpha,
                    shape if shape is not None else analytic_shape(), model)
    return model
