"""What a run derives around the decomposition: a file's system pulse (its response, width, the model's
shape error, where it places returns), and the fitted model's samples.

Plain functions over the reader's and the engine's records, so that the
pipeline's stages only call them.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from fwcore.config import DecompositionConfig, Model
from fwcore.engine import decompose_batch
from fwcore.io import PointRange, input_summary, read_pulses
from fwcore.io.formats import NEON_CSV, format_of
from fwcore.io.neon import read_neon_csv
from fwcore.instrument import SystemResponse, measure_response
from fwcore.preprocess import estimate_pulse_fwhm, noise_and_background
from fwcore.pulses import csv_pulse_fwhm_ps, pulse_waveforms, system_pulse_fwhm_ps
from fwcore.records import BatchDecomposition, WaveformBatch
from fwcore.rng import pulse_seed

LOG = logging.getLogger("fwl")

PULSE_WIDTH_POINTS = 5000  # the head of a file that measures its pulse width: fixed by the file, not the range size
RANGE_OFFSET_PULSES = 300  # single-return pulses that measure a file's range offset
RESPONSE_PULSES = 3000  # candidates for the response: a few hundred strong single returns among them
# waveforms that choose the echo model under --model auto: on the shared Leica, RIEGL and NEON files the two
# models' held-out errors differ by 20-70%, far beyond what 200 waveforms leave uncertain
MODEL_PULSES = 200
# every fifth valid sample is held out of the fits that judge the models: half the others keep both
# neighbours, where the engine measures a quantised digitizer's noise (every third leaves it none)
HELD_OUT_EVERY = 5


@dataclasses.dataclass(frozen=True)
class SystemPulse:
    """What a file does not record about its system's pulse, measured on its own waveforms, and how."""

    fwhm_ps: float
    fwhm_source: str  # configured | single returns | estimated from the waveforms | default (unmeasurable)
    shape_tolerance: float
    shape_source: str  # configured | single returns | none measured
    range_offset_ps: float = 0.0  # added to an echo's time to place it where the system places its returns
    range_offset_source: str = "none measured"  # single returns (how many) | none measured
    response: SystemResponse | None = None  # the measured response (fwcore.instrument); None: not measurable
    model: str = ""  # under --model auto, the echo model chosen for the file (system | generalized)
    model_choice: str = ""  # ... and why (choose_system_pulse)

    def configure(self, config: DecompositionConfig) -> DecompositionConfig:
        """The file's decomposition settings: the run's, with what was measured on the file (under
        --model auto, the model chosen for it)."""
        model = Model(self.model) if config.model is Model.AUTO and self.model else config.model
        return config.replace(model=model, system_pulse_fwhm_ps=self.fwhm_ps, shape_tolerance=self.shape_tolerance,
                              system_response=self.response)

    @property
    def response_source(self) -> str:
        return self.response.source if self.response is not None else "none measured"

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "response": self.response.to_dict() if self.response else None}

    @classmethod
    def from_dict(cls, d: dict) -> "SystemPulse":
        response = d.get("response")
        return cls(**{**d, "response": SystemResponse.from_dict(response) if response else None})


def held_out_errors(batch: WaveformBatch, config: DecompositionConfig,
                    every: int = HELD_OUT_EVERY) -> tuple[float, float]:
    """How well a decomposition predicts samples it did not see: every `every`-th valid sample of each
    waveform held out, the rest decomposed under `config`; (mean |model - sample| at the held-out samples, the
    same at the fitted ones), digitizer units, averaged over the decomposed waveforms."""
    held = np.zeros(batch.valid.size, dtype=bool)
    for lo, hi in zip(batch.offsets[:-1], batch.offsets[1:]):
        held[lo + np.flatnonzero(batch.valid[lo:hi])[1::every]] = True
    fitted = batch.valid & ~held
    result = decompose_batch(dataclasses.replace(batch, valid=fitted), config, threads=1)
    errors = []
    for i in np.flatnonzero(result.status == 0):
        lo, hi = batch.offsets[i], batch.offsets[i + 1]
        miss = np.abs(result.waveform(int(i)).model(np.arange(hi - lo)) - batch.samples[lo:hi])
        errors.append((miss[held[lo:hi]].mean(), miss[fitted[lo:hi]].mean()))
    return tuple(np.mean(errors, axis=0)) if errors else (np.inf, np.inf)


def choose_system_pulse(candidates: dict[Model, SystemPulse], batch: WaveformBatch,
                        config: DecompositionConfig) -> SystemPulse:
    """`--model auto`: of a file's system pulses measured for the system response and for the generalized
    Gaussian, the one whose echoes predict held-out samples of its first waveforms (`batch`) more closely
    (held_out_errors under the run's settings); a tie, or no response measured, keeps the generalized
    Gaussian, the method's model. The chosen pulse says which and why."""
    shaped, generalized = candidates[Model.SYSTEM], candidates[Model.GENERALIZED]
    if shaped.response is None:
        return dataclasses.replace(generalized, model=Model.GENERALIZED.value,
                                   model_choice="generalized: no system response measured")
    errors = {model: held_out_errors(batch, pulse.configure(config.replace(model=model)))[0]
              for model, pulse in candidates.items()}
    model = Model.SYSTEM if errors[Model.SYSTEM] < errors[Model.GENERALIZED] else Model.GENERALIZED
    why = (f"{model.value}: at held-out samples of {len(batch)} waveforms, echoes of the system response "
           f"({shaped.response_source}) miss by {errors[Model.SYSTEM]:.3f}, generalized Gaussians by "
           f"{errors[Model.GENERALIZED]:.3f}")
    LOG.info("--model auto: %s", why)
    return dataclasses.replace(candidates[model], model=model.value, model_choice=why)


def _each_model(measure, config: DecompositionConfig) -> dict[Model, SystemPulse]:
    return {model: measure(config.replace(model=model)) for model in (Model.SYSTEM, Model.GENERALIZED)}


def response_of_waveforms(waveforms, spacing_ps: float, source: str) -> SystemResponse | None:
    """The system response from waveforms (float arrays of valid samples): their strong single returns
    aligned and averaged (fwcore.instrument.measure_response), or None where too few are strong and single."""
    waveforms = [w for w in (np.asarray(w, dtype=float) for w in waveforms[:RESPONSE_PULSES]) if np.isfinite(w).all()]
    noise_background = [noise_and_background(w) if w.size >= 12 else (np.inf, 0.0) for w in waveforms]
    try:
        return measure_response(waveforms, spacing_ps, source, [n for n, _ in noise_background],
                                [b for _, b in noise_background])
    except ValueError:
        return None


def measure_file_response(pulses, rows: np.ndarray, source: str) -> SystemResponse | None:
    """The system response from pulses[rows] (response_of_waveforms)."""
    rows = rows[:RESPONSE_PULSES]
    return response_of_waveforms([pulses.pulse_samples(i) for i in rows],
                                 float(np.median(pulses.sample_spacing_ps[rows])), source)


def measure_input_response(path: str | Path) -> SystemResponse | None:
    """The response `fwl run --model system` measures on an input (LAS/LAZ, PulseWaves: its first records'
    single returns, else isolated echoes) or on a NEON-layout CSV's isolated echoes; None where too few qualify."""
    if format_of(path) is NEON_CSV:
        waveforms = read_neon_csv(path)
        return csv_system_pulse(waveforms.samples, waveforms.valid, 1000.0,
                                DecompositionConfig(model=Model.SYSTEM)).response
    count = input_summary(path).records
    return file_response(read_pulses(PointRange(str(path), 0, min(count, PULSE_WIDTH_POINTS)))) if count else None


def file_response(pulses) -> SystemResponse | None:
    """The response of a file's first pulses: on the system's single returns where the file has them,
    otherwise on its strongest isolated echoes; None where too few qualify."""
    single = np.flatnonzero(np.diff(pulses.return_offsets) == 1)
    response = measure_file_response(pulses, single, "single returns") if single.size else None
    return response or measure_file_response(pulses, np.arange(len(pulses)), "isolated echoes")


def csv_system_pulse(samples, valid, spacing_ps: float, config: DecompositionConfig,
                     response: SystemResponse | None = None, outgoing=None) -> SystemPulse:
    """A NEON-layout CSV's system pulse: the response given (`--system-response`), else measured on the
    outgoing pulses (`--outgoing`), else on the returns' strong single echoes; its FWHM configured, else the
    response's (system model) or the outgoing pulses' median, else estimated from the returns' isolated echoes."""
    if config.model is Model.AUTO:
        n = min(len(samples), MODEL_PULSES)
        head = WaveformBatch.from_waveforms(samples[:n], spacing_ps, [pulse_seed(config.seed, i) for i in range(n)],
                                            valid[:n])
        measure = lambda c: csv_system_pulse(samples, valid, spacing_ps, c, response, outgoing)  # noqa: E731
        return choose_system_pulse(_each_model(measure, config), head, config)
    if response is None and config.system_response is not None:
        response = config.system_response
    if response is None and config.model is Model.SYSTEM:
        if outgoing is not None:
            response = response_of_waveforms([y[v] for y, v in zip(outgoing.samples, outgoing.valid)], spacing_ps,
                                             "outgoing pulses")
        if response is None:
            response = response_of_waveforms([y[v] for y, v in zip(samples, valid)], spacing_ps, "isolated echoes")
    fwhm, source = config.system_pulse_fwhm_ps, "configured"
    if fwhm is None and response is not None and config.model is Model.SYSTEM:
        fwhm, source = response.fwhm_ps, f"system response: {response.source}"
    elif fwhm is None and outgoing is not None:
        fwhm, source = csv_pulse_fwhm_ps(outgoing, spacing_ps), "median of the outgoing pulses"
    elif fwhm is None:
        estimate = estimate_pulse_fwhm(samples, valid)
        fwhm = estimate.fwhm_samples * spacing_ps
        source = f"estimated from {estimate.n_waveforms} isolated echoes of {estimate.n_candidates} waveforms"
    tolerance = config.shape_tolerance if config.shape_tolerance is not None else 0.0
    shape_source = "configured" if config.shape_tolerance is not None else "none measured"
    return SystemPulse(float(fwhm), source, float(tolerance), shape_source, response=response)


def measure_shape_tolerance(batch: WaveformBatch, config: DecompositionConfig) -> float:
    """How far the system's pulse departs from a generalized Gaussian, relative to its height: one echo
    fitted by LM to each waveform of `batch` (single returns), then eps of variance sigma^2 + (eps s)^2
    fitted by least squares to the squared residuals, s the echo's height at each sample.
    0 for an exact model; Leica's skewed, ringing pulse gives 0.05."""
    single = config.replace(optimizer="lm", select_echoes=False, max_echoes=1, fit_target="raw", shape_tolerance=0.0)
    result = decompose_batch(batch, single, threads=1)
    num = den = 0.0
    for i in np.flatnonzero((result.status == 0) & (np.diff(result.echo_offsets) == 1)):
        d = result.waveform(int(i))
        lo, hi = batch.offsets[i], batch.offsets[i + 1]
        y, valid = batch.samples[lo:hi], batch.valid[lo:hi]
        model = d.model(np.arange(hi - lo))
        signal = np.maximum(model - d.background, 0.0)[valid]
        residual = (y - model)[valid]
        num += float(np.sum(signal ** 2 * (residual ** 2 - d.noise_sigma ** 2)))
        den += float(np.sum(signal ** 4))
    return float(np.sqrt(max(num / den, 0.0))) if den > 0 else 0.0


def measure_range_offset(batch: WaveformBatch, config: DecompositionConfig,
                         return_time_ps: np.ndarray) -> tuple[float, int]:
    """Where the system places a return against the centre of the echo the run finds there: the median of
    (return time - echo time) over the waveforms of `batch` (single returns, `return_time_ps` within
    each packet) where the run's decomposition keeps exactly one echo; and how many those are.
    The system's range reference is a point of its pulse that a fitted centre need not be (Leica:
    1.19 ns before it, 0.18 m of range)."""
    result = decompose_batch(batch, config, threads=1)
    kept = np.flatnonzero(result.reject == 0)
    owner = result.echo_waveform[kept]  # sorted: echoes are grouped by waveform
    one = np.flatnonzero((result.status == 0) & (np.bincount(owner, minlength=len(result)) == 1))
    if one.size == 0:
        return 0.0, 0
    echo_time_ps = result.position[kept[np.searchsorted(owner, one)]] * batch.sample_spacing_ps[one]
    return float(np.median(np.asarray(return_time_ps, dtype=float)[one] - echo_time_ps)), int(one.size)


def file_system_pulse(path: str | Path, point_count: int, config: DecompositionConfig,
                      head_points: int = PULSE_WIDTH_POINTS) -> SystemPulse:
    """The file's system pulse from the first `head_points` records: its FWHM from the recorded outgoing
    waveforms (PulseWaves) or the pulses the system saw as single returns (LAS), else estimated from the
    waveforms' isolated echoes, else the configured default, with a warning; the model's shape
    tolerance fitted on the single returns (0 where there are none); and the range offset that places
    an echo where the system places its returns (0 where there are no single returns)."""
    if config.model is Model.AUTO and point_count > 0:
        pulses = read_pulses(PointRange(str(path), 0, min(point_count, MODEL_PULSES)))
        measure = lambda c: file_system_pulse(path, point_count, c, head_points)  # noqa: E731
        return choose_system_pulse(_each_model(measure, config), pulse_waveforms(pulses, config.seed), config)
    fwhm, fwhm_source = config.system_pulse_fwhm_ps, "configured"
    tolerance, shape_source = config.shape_tolerance, "configured"
    pulses = read_pulses(PointRange(str(path), 0, min(point_count, head_points))) if point_count > 0 else None
    single = np.flatnonzero(np.diff(pulses.return_offsets) == 1) if pulses is not None else np.zeros(0, int)
    response = config.system_response
    if response is None and pulses is not None and config.model is Model.SYSTEM:
        response = file_response(pulses)
        if response is None:
            LOG.warning("%s: too few strong single returns to measure the system response; echoes are "
                        "Gaussians of the pulse width", Path(path).name)
    if fwhm is None and response is not None and config.model is Model.SYSTEM:
        fwhm, fwhm_source = response.fwhm_ps, f"system response: {response.source}"
    if fwhm is None:
        try:
            fwhm = system_pulse_fwhm_ps(pulses)
            outgoing = pulses.outgoing is not None and pulses.outgoing.size > 0
            fwhm_source = "outgoing waveforms" if outgoing else "single returns"
        except (ValueError, AttributeError):
            try:
                estimate = estimate_pulse_fwhm([pulses.pulse_samples(i) for i in range(len(pulses))])
                fwhm = estimate.fwhm_samples * float(np.median(pulses.sample_spacing_ps))
                fwhm_source = f"estimated from {estimate.n_waveforms} isolated echoes"
            except (ValueError, AttributeError, TypeError):
                fwhm, fwhm_source = config.default_pulse_fwhm_ps, "default (unmeasurable)"
                LOG.warning("%s: no single return and no isolated echo to measure the system pulse width; "
                            "using %.0f ps (set --system-pulse-fwhm-ps)", Path(path).name, fwhm)
        if fwhm_source.startswith("estimated"):
            LOG.warning("%s: no single-return pulse; system pulse FWHM %.0f ps %s", Path(path).name, fwhm,
                        fwhm_source)
    offset, offset_source = 0.0, "none measured"
    if single.size:
        seeds = pulse_waveforms(pulses, config.seed).seeds

        def waveforms(rows: np.ndarray) -> WaveformBatch:
            return WaveformBatch.from_waveforms([pulses.pulse_samples(i) for i in rows],
                                                pulses.sample_spacing_ps[rows], seeds[rows])

        if tolerance is None:
            tolerance = measure_shape_tolerance(waveforms(single), config.replace(system_pulse_fwhm_ps=fwhm,
                                                                                   system_response=response))
            shape_source = "single returns"
        head = single[:RANGE_OFFSET_PULSES]  # enough for a median within millimetres, cheap for any preset
        offset, n = measure_range_offset(waveforms(head), config.replace(system_pulse_fwhm_ps=fwhm,
                                                                         shape_tolerance=tolerance,
                                                                         system_response=response),
                                         pulses.return_location_ps[pulses.return_offsets[head]])
        if n:
            offset_source = f"single returns ({n})"
    if tolerance is None:
        tolerance, shape_source = 0.0, "none measured"
    return SystemPulse(float(fwhm), fwhm_source, float(tolerance), shape_source, offset, offset_source, response)


def model_samples(result: BatchDecomposition, sample_offsets: np.ndarray) -> np.ndarray:
    """Each decomposed pulse's fitted model at its sample times, flat like the samples (0 where not decomposed)."""
    model = np.zeros(int(sample_offsets[-1]), dtype=np.float32)
    for i in np.flatnonzero(result.status == 0):
        lo, hi = sample_offsets[i], sample_offsets[i + 1]
        model[lo:hi] = result.waveform(int(i)).model(np.arange(hi - lo))
    return model
