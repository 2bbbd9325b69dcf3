"""A file's SystemPulse, measured on its own waveforms: its width, response, shape tolerance and range offset, and
under `--model auto` the echo model that predicts its samples better.

The response is measured on the system's single returns (a LAS file's points
with one return) or, where a file records none, its strongest isolated echoes:
aligned at sub-sample precision on their peak, binned finely (the waveforms'
random sub-sample phases sample the pulse between the digitizer's samples)
and averaged by median. This module runs the engine: it sits a floor above it.

    file_response(pulses), csv_response(...)              the response of a file's head, of a NEON-layout CSV
    file_system_pulse(path, count, config, overrides)     LAS/LAZ, PulseWaves: the first records of the file
    csv_system_pulse(samples, valid, spacing, config, ...) a NEON-layout CSV's waveforms (and outgoing pulses)
    read_csv_input(path, config, overrides, ...)           a NEON-layout CSV read and its pulse measured

What the user gives (PulseOverrides) is taken instead of being measured.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.smoothing import noise_and_background
from fwcore.instrument.peak import half_height_width, isolated_lobe, local_maxima, parabola_height, parabola_vertex
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, PulseOverrides, SystemPulse
from fwcore.instrument.response import SystemResponse
from fwcore.instrument.width import csv_pulse_fwhm_ps, estimate_pulse_fwhm, recorded_pulse_fwhm_ps
from fwcore.io import PointRange, input_summary, read_pulses
from fwcore.io.formats import NEON_CSV, format_of
from fwcore.io.neon import NEON_SAMPLE_SPACING_PS, CsvWaveforms
from fwcore.io.records import PulseBatch
from fwcore.pulses import pulse_waveforms
from fwcore.engine.records import WaveformBatch
from fwcore.rng import pulse_seed

LOG = logging.getLogger("fwl")

BINS_PER_SAMPLE = 4  # the measured response's resolution: a quarter of the digitizer's sample
MIN_SNR = 30.0  # a return this far above the noise shows the response's tail and afterpulse
OUTSIDE_FRACTION = 0.15  # of the peak: a sample outside the return's lobe above this is another return
MIN_PULSES = 20  # fewer strong single returns than this measure nothing
RESPONSE_PULSES = 3000  # candidates for the response: a few hundred strong single returns among them
HEAD_PULSES = 5000  # the head of a file that measures its pulse: fixed by the file, not the range size
RANGE_OFFSET_PULSES = 300  # single-return pulses that measure a file's range offset
# waveforms that choose the echo model under --model auto: on the shared Leica, RIEGL and NEON files the two
# models' held-out errors differ by 20-70%, far beyond what 200 waveforms leave uncertain
MODEL_PULSES = 200
# ... taken a block at a time, and the choice ends at the first block from MODEL_MIN_PULSES on where the two
# models' paired held-out misses differ by DECISIVE_SE standard errors (every shared file's models differ plainly:
# judged on 50 waveforms, whatever their length), or where they surely differ by less than EQUIVALENT of the miss
# (their difference and EQUIVALENT_SE standard errors within it: either model predicts the samples as well; GEDI
# over simulated tall canopy, 3% apart, stops at 75); else on all MODEL_PULSES
MODEL_BLOCK = 25
MODEL_MIN_PULSES = 50
DECISIVE_SE = 4.0
EQUIVALENT = 0.05
EQUIVALENT_SE = 2.0
# GEDI's transmitted pulses all qualify as strong single returns: the response's median per bin is settled long
# before RESPONSE_PULSES of them, whose noise and background cost 0.7 ms each
TRANSMITTED_PULSES = 500
# every fifth valid sample is held out of the fits that judge the models: half the others keep both
# neighbours, where the engine measures a quantised digitizer's noise (every third leaves it none)
HELD_OUT_EVERY = 5
AUTO_MODELS = (Model.SYSTEM, Model.GENERALIZED)  # what `auto` chooses between


# ---------------------------------------------------------------- the response, on strong single returns

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
        head = range(min(len(pulses), TRANSMITTED_PULSES))
        response = response_of_waveforms([pulses.outgoing_samples(i) for i in head], spacing, "transmitted waveforms")
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


# ---------------------------------------------------------------- the `auto` choice

def held_out_errors(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse,
                    every: int = HELD_OUT_EVERY) -> tuple[float, float]:
    """How well a decomposition predicts samples it did not see: every `every`-th valid sample of each
    waveform held out, the rest decomposed under `config` with `pulse`; (mean |model - sample| at the held-out
    samples, the same at the fitted ones), digitizer units, averaged over the decomposed waveforms."""
    errors = held_out_misses(batch, config, pulse, every)
    errors = errors[np.isfinite(errors[:, 0])]
    return tuple(errors.mean(axis=0)) if errors.size else (np.inf, np.inf)


def held_out_misses(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse,
                    every: int = HELD_OUT_EVERY) -> np.ndarray:
    """Per waveform of `batch` (held_out_errors' fits): (mean |model - sample| at its held-out samples, the same
    at its fitted ones), NaN for a waveform not decomposed."""
    held = np.zeros(batch.valid.size, dtype=bool)
    for lo, hi in zip(batch.offsets[:-1], batch.offsets[1:]):
        held[lo + np.flatnonzero(batch.valid[lo:hi])[1::every]] = True
    fitted = batch.valid & ~held
    result = decompose_batch(dataclasses.replace(batch, valid=fitted), config, pulse, threads=1)
    errors = np.full((len(result), 2), np.nan)
    for i in np.flatnonzero(result.status == 0):
        lo, hi = batch.offsets[i], batch.offsets[i + 1]
        miss = np.abs(result.waveform(int(i)).model(np.arange(hi - lo)) - batch.samples[lo:hi])
        errors[i] = miss[held[lo:hi]].mean(), miss[fitted[lo:hi]].mean()
    return errors


def _waveforms(batch: WaveformBatch, lo: int, hi: int) -> WaveformBatch:
    """Waveforms lo..hi of a batch as a batch of their own."""
    a, b = batch.offsets[lo], batch.offsets[hi]
    return WaveformBatch(batch.samples[a:b], batch.valid[a:b], batch.offsets[lo:hi + 1] - a,
                         batch.sample_spacing_ps[lo:hi], batch.seeds[lo:hi],
                         None if batch.noise_floor is None else batch.noise_floor[lo:hi])


def settled(system: np.ndarray, generalized: np.ndarray) -> bool:
    """Whether the paired held-out misses of the waveforms both models decomposed settle the choice: their mean
    difference beyond DECISIVE_SE standard errors (one model is better), or within EQUIVALENT of the mean miss
    with EQUIVALENT_SE standard errors added (the two are as good)."""
    both = np.isfinite(system) & np.isfinite(generalized)
    d = system[both] - generalized[both]
    if d.size < 2:
        return False
    se = d.std(ddof=1) / np.sqrt(d.size)
    level = 0.5 * (system[both].mean() + generalized[both].mean())
    return bool(abs(d.mean()) > DECISIVE_SE * se or abs(d.mean()) + EQUIVALENT_SE * se < EQUIVALENT * level)


def compare_models(candidates: dict[Model, SystemPulse], batch: WaveformBatch, config: DecompositionConfig
                   ) -> tuple[dict[Model, float], int]:
    """Each model's mean held-out miss over the waveforms it decomposed, and how many waveforms judged them:
    blocks of MODEL_BLOCK from the batch's first, until the difference is settled from MODEL_MIN_PULSES on
    (deterministic: the blocks and the test depend on the waveforms only), else the whole batch."""
    misses: dict[Model, list[np.ndarray]] = {model: [] for model in candidates}
    n, used = len(batch), 0
    while used < n:
        block = _waveforms(batch, used, min(used + MODEL_BLOCK, n))
        for model, pulse in candidates.items():
            misses[model].append(held_out_misses(block, config.replace(model=model), pulse)[:, 0])
        used += len(block)
        if used >= MODEL_MIN_PULSES and settled(np.concatenate(misses[Model.SYSTEM]),
                                                np.concatenate(misses[Model.GENERALIZED])):
            break
    means = {}
    for model, parts in misses.items():
        found = np.concatenate(parts)
        found = found[np.isfinite(found)]
        means[model] = float(found.mean()) if found.size else np.inf
    return means, used


def choose_system_pulse(candidates: dict[Model, SystemPulse], batch: WaveformBatch,
                        config: DecompositionConfig) -> SystemPulse:
    """`--model auto`: of a file's system pulses measured for the system response and for the generalized
    Gaussian, the one whose echoes predict held-out samples of its first waveforms (`batch`) more closely
    (held_out_errors under the run's settings, on as many of them as make the difference decisive:
    compare_models); a tie, or no response measured, keeps the generalized Gaussian, the method's model. The
    chosen pulse says which and why."""
    shaped, generalized = candidates[Model.SYSTEM], candidates[Model.GENERALIZED]
    if shaped.response is None:
        return dataclasses.replace(generalized, model=Model.GENERALIZED.value,
                                   model_choice="generalized: no system response measured")
    errors, used = compare_models(candidates, batch, config)
    model = Model.SYSTEM if errors[Model.SYSTEM] < errors[Model.GENERALIZED] else Model.GENERALIZED
    why = (f"{model.value}: at held-out samples of {used} waveforms, echoes of the system response "
           f"({shaped.response_source}) miss by {errors[Model.SYSTEM]:.3f}, generalized Gaussians by "
           f"{errors[Model.GENERALIZED]:.3f}")
    LOG.info("--model auto: %s", why)
    return dataclasses.replace(candidates[model], model=model.value, model_choice=why)


# ---------------------------------------------------------------- shape tolerance and range offset

def measure_shape_tolerance(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse) -> float:
    """How far the system's pulse departs from a generalized Gaussian, relative to its height: one echo
    fitted by LM to each waveform of `batch` (single returns), then eps of variance sigma^2 + (eps s)^2
    fitted by least squares to the squared residuals, s the echo's height at each sample.
    0 for an exact model; Leica's skewed, ringing pulse gives 0.05."""
    single = config.replace(optimizer="lm", select_echoes=False, max_echoes=1, fit_target="raw")
    result = decompose_batch(batch, single, dataclasses.replace(pulse, shape_tolerance=0.0), threads=1)
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


def measure_range_offset(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse,
                         return_time_ps: np.ndarray) -> tuple[float, int]:
    """Where the system places a return against the centre of the echo the run finds there: the median of
    (return time - echo time) over the waveforms of `batch` (single returns, `return_time_ps` within
    each packet) where the run's decomposition keeps exactly one echo; and how many those are.
    The system's range reference is a point of its pulse that a fitted centre need not be (Leica:
    1.19 ns before it, 0.18 m of range)."""
    result = decompose_batch(batch, config, pulse, threads=1)
    kept = np.flatnonzero(result.reject == 0)
    owner = result.echo_waveform[kept]  # sorted: echoes are grouped by waveform
    one = np.flatnonzero((result.status == 0) & (np.bincount(owner, minlength=len(result)) == 1))
    if one.size == 0:
        return 0.0, 0
    echo_time_ps = result.position[kept[np.searchsorted(owner, one)]] * batch.sample_spacing_ps[one]
    return float(np.median(np.asarray(return_time_ps, dtype=float)[one] - echo_time_ps)), int(one.size)


# ---------------------------------------------------------------- a LAS/LAZ or PulseWaves file

def measure_input_response(path: str | Path) -> SystemResponse | None:
    """The response `fwl run --model system` measures on an input (LAS/LAZ, PulseWaves: its first records'
    single returns, else isolated echoes) or on a NEON-layout CSV's isolated echoes; None where too few qualify."""
    if format_of(path) is NEON_CSV:
        waveforms = NEON_CSV.open(path)
        return csv_response(waveforms.samples, waveforms.valid, NEON_SAMPLE_SPACING_PS)
    count = input_summary(path).records
    return file_response(read_pulses(PointRange(str(path), 0, min(count, HEAD_PULSES)))) if count else None


def _head_records(pulses: PulseBatch, records: int, seed: int) -> WaveformBatch:
    """The waveforms of the pulses among a file's first `records` records, from its head already read (LAS:
    the pulses whose first point is among them; PulseWaves, whose records are pulses: the first ones)."""
    has_points = pulses.return_offsets[-1] > 0
    n = int(np.searchsorted(pulses.return_offsets[:-1], records)) if has_points else min(records, len(pulses))
    # the first n pulses' waveforms only (each pulse's window and seed are its own): not the whole head's
    cut = {name: getattr(pulses, name)[:n] for name in ("pulse_id", "sample_spacing_ps", "noise_mean", "noise_sd",
                                                         "channel", "segment") if getattr(pulses, name) is not None}
    head = dataclasses.replace(pulses, samples=pulses.samples[:pulses.sample_offsets[n]],
                               sample_offsets=pulses.sample_offsets[:n + 1], **cut)
    return pulse_waveforms(head, seed)


def _file_width(pulses: PulseBatch | None, name: str) -> tuple[float, str]:
    """A file's pulse FWHM (ps) where nothing gave it: recorded (outgoing waveforms, single returns), else
    estimated from its isolated echoes, else the default, with a warning."""
    if pulses is not None:
        try:  # ValueError: its recorded pulses measure nothing (all flat): its echoes are tried
            measured = recorded_pulse_fwhm_ps(pulses)
        except ValueError:
            measured = None
        if measured is not None:
            return measured
        try:  # ValueError: too few isolated echoes
            estimate = estimate_pulse_fwhm([pulses.pulse_samples(i) for i in range(len(pulses))])
        except ValueError:
            estimate = None
        if estimate is not None:
            fwhm = estimate.fwhm_samples * float(np.median(pulses.sample_spacing_ps))
            source = f"estimated from {estimate.n_waveforms} isolated echoes"
            LOG.warning("%s: no single-return pulse; system pulse FWHM %.0f ps %s", name, fwhm, source)
            return fwhm, source
    LOG.warning("%s: no single return and no isolated echo to measure the system pulse width; "
                "using %.0f ps (set --system-pulse-fwhm-ps)", name, DEFAULT_PULSE_FWHM_PS)
    return DEFAULT_PULSE_FWHM_PS, "default (unmeasurable)"


def _pulses_system_pulse(pulses: PulseBatch | None, name: str, config: DecompositionConfig,
                         overrides: PulseOverrides, range_offset: bool = True) -> SystemPulse:
    """The system pulse of a file's head (`pulses`, None for a file without records) for one echo model; its
    range offset measured unless not `range_offset` (_with_range_offset measures it later)."""
    response = overrides.response
    if response is None and pulses is not None and config.model is Model.SYSTEM:
        response = file_response(pulses)
        if response is None:
            LOG.warning("%s: too few strong single returns to measure the system response; echoes are "
                        "Gaussians of the pulse width", name)
    fwhm, fwhm_source = overrides.fwhm_ps, "configured"
    if fwhm is None and response is not None and config.model is Model.SYSTEM:
        fwhm, fwhm_source = response.fwhm_ps, f"system response: {response.source}"
    if fwhm is None:
        fwhm, fwhm_source = _file_width(pulses, name)
    pulse = SystemPulse(float(fwhm), fwhm_source, 0.0, "none measured", response=response)
    if overrides.shape_tolerance is not None:
        pulse = dataclasses.replace(pulse, shape_tolerance=float(overrides.shape_tolerance), shape_source="configured")
    single = _single_returns(pulses)
    if single.size and overrides.shape_tolerance is None:
        tolerance = measure_shape_tolerance(_rows_batch(pulses, single, config.seed), config, pulse)
        pulse = dataclasses.replace(pulse, shape_tolerance=float(tolerance), shape_source="single returns")
    return _with_range_offset(pulses, config, pulse) if range_offset else pulse


def _single_returns(pulses: PulseBatch | None) -> np.ndarray:
    """The rows of a file's head whose pulse the system saw as one return."""
    return np.flatnonzero(np.diff(pulses.return_offsets) == 1) if pulses is not None else np.zeros(0, int)


def _rows_batch(pulses: PulseBatch, rows: np.ndarray, seed: int) -> WaveformBatch:
    """The waveforms of pulses[rows], each with its own seed (the one its range gives it)."""
    seeds = pulse_waveforms(pulses, seed).seeds
    return WaveformBatch.from_waveforms([pulses.pulse_samples(i) for i in rows], pulses.sample_spacing_ps[rows],
                                        seeds[rows])


def _with_range_offset(pulses: PulseBatch | None, config: DecompositionConfig, pulse: SystemPulse) -> SystemPulse:
    """The pulse with its range offset measured on the file's first single returns (unchanged without any)."""
    single = _single_returns(pulses)
    if not single.size:
        return pulse
    head = single[:RANGE_OFFSET_PULSES]  # enough for a median within millimetres, cheap for any preset
    offset, n = measure_range_offset(_rows_batch(pulses, head, config.seed), config, pulse,
                                     pulses.return_location_ps[pulses.return_offsets[head]])
    return dataclasses.replace(pulse, range_offset_ps=offset,
                               range_offset_source=f"single returns ({n})" if n else "none measured")


def file_system_pulse(path: str | Path, point_count: int, config: DecompositionConfig,
                      overrides: PulseOverrides = PulseOverrides(), head_points: int = HEAD_PULSES) -> SystemPulse:
    """The file's system pulse from its first `head_points` records (read once): its FWHM from the recorded
    outgoing waveforms (PulseWaves) or the pulses the system saw as single returns (LAS), else estimated from
    the waveforms' isolated echoes, else the default, with a warning; under the system model its response;
    the model's shape tolerance fitted on the single returns (0 where there are none); and the range offset
    that places an echo where the system places its returns (0 where there are no single returns). What
    `overrides` gives is taken instead. Under --model auto, the pulse of the model chosen for the file."""
    pulses = read_pulses(PointRange(str(path), 0, min(point_count, head_points))) if point_count > 0 else None
    name = Path(path).name
    if config.model is not Model.AUTO or pulses is None:
        return _pulses_system_pulse(pulses, name, config, overrides)
    # the range offset, which no decomposition reads, measured for the chosen model only
    candidates = {model: _pulses_system_pulse(pulses, name, config.replace(model=model), overrides, range_offset=False)
                  for model in AUTO_MODELS}
    chosen = choose_system_pulse(candidates, _head_records(pulses, MODEL_PULSES, config.seed), config)
    return _with_range_offset(pulses, config.replace(model=Model(chosen.model)), chosen)


# ---------------------------------------------------------------- a NEON-layout CSV

def csv_system_pulse(samples, valid, spacing_ps: float, config: DecompositionConfig,
                     overrides: PulseOverrides = PulseOverrides(), outgoing: CsvWaveforms | None = None) -> SystemPulse:
    """A NEON-layout CSV's system pulse: the response given, else (system model) measured on the outgoing
    pulses (`--outgoing`), else on the returns' strong single echoes; its FWHM given, else the response's
    (system model) or the outgoing pulses' median, else estimated from the returns' isolated echoes. Under
    --model auto, the pulse of the model chosen on its first waveforms."""
    if config.model is not Model.AUTO:
        return _csv_model_pulse(samples, valid, spacing_ps, config, overrides, outgoing)
    n = min(len(samples), MODEL_PULSES)
    head = WaveformBatch.from_waveforms(samples[:n], spacing_ps, [pulse_seed(config.seed, i) for i in range(n)],
                                        valid[:n])
    candidates = {model: _csv_model_pulse(samples, valid, spacing_ps, config.replace(model=model), overrides, outgoing)
                  for model in AUTO_MODELS}
    return choose_system_pulse(candidates, head, config)


def _csv_model_pulse(samples, valid, spacing_ps: float, config: DecompositionConfig, overrides: PulseOverrides,
                     outgoing: CsvWaveforms | None) -> SystemPulse:
    """csv_system_pulse for one echo model."""
    response = overrides.response
    if response is None and config.model is Model.SYSTEM:
        response = csv_response(samples, valid, spacing_ps, outgoing)
    fwhm, source = overrides.fwhm_ps, "configured"
    if fwhm is None and response is not None and config.model is Model.SYSTEM:
        fwhm, source = response.fwhm_ps, f"system response: {response.source}"
    elif fwhm is None and outgoing is not None:
        fwhm, source = csv_pulse_fwhm_ps(outgoing, spacing_ps), "median of the outgoing pulses"
    elif fwhm is None:
        estimate = estimate_pulse_fwhm(samples, valid)
        fwhm = estimate.fwhm_samples * spacing_ps
        source = f"estimated from {estimate.n_waveforms} isolated echoes of {estimate.n_candidates} waveforms"
    tolerance = overrides.shape_tolerance
    return SystemPulse(float(fwhm), source, float(tolerance or 0.0),
                       "configured" if tolerance is not None else "none measured", response=response)


@dataclasses.dataclass(frozen=True)
class CsvInput:
    """A NEON-layout CSV read: its waveforms, the engine's batch of the first `limit` of them, and their pulse."""

    waveforms: CsvWaveforms
    batch: WaveformBatch
    pulse: SystemPulse

    @property
    def waveform_id(self) -> np.ndarray:
        return self.waveforms.waveform_id[:len(self.batch)]


def read_csv_input(path: str | Path, config: DecompositionConfig, overrides: PulseOverrides = PulseOverrides(),
                   outgoing: str | Path | None = None, spacing_ps: float = NEON_SAMPLE_SPACING_PS,
                   limit: int | None = None) -> CsvInput:
    """The one NEON CSV path of `fwl decompose-csv` and `fwl compare`: the waveforms read, their pulse measured on
    all of them (csv_system_pulse, with `outgoing`'s pulses), the first `limit` seeded by their ids."""
    waveforms = NEON_CSV.open(path)  # a file of another kind is named as such first
    pulse = csv_system_pulse(waveforms.samples, waveforms.valid, spacing_ps, config, overrides,
                             NEON_CSV.open(outgoing) if outgoing else None)
    n = len(waveforms.waveform_id) if limit is None else min(limit, len(waveforms.waveform_id))
    batch = WaveformBatch.from_waveforms(waveforms.samples[:n], spacing_ps,
                                         [pulse_seed(config.seed, int(i)) for i in waveforms.waveform_id[:n]],
                                         waveforms.valid[:n])
    return CsvInput(waveforms, batch, pulse)
