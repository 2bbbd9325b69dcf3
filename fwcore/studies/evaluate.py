"""`fwl evaluate`: a run's echoes against a simulated flight's truth (fwcore.studies.truth).

A true echo and a decomposed (kept) echo of the same pulse match when each
is the other's nearest in time and they lie within `match_ps` (default
1 ns). Reported per run, overall and split by SNR band (true amplitude over
the noise sigma) and by separation (single echo; resolved: the nearest other
true echo of the pulse at least one FWHM away; overlapping: closer), with the
Cramer-Rao lower bound of the range error of a single echo in the same noise.

`score_resolution` scores what the instrument can resolve: W is the truth's
median FWHM (the pulse width); a true echo is resolvable when every other
true echo of its pulse lies at least W away and its SNR is at least 5; a kept
echo is right when it is matched to a true echo (within 1 ns), or lies within
0.5 W of the amplitude-weighted centre of a group of true echoes closer than W
to each other (which no instrument splits) none of which is matched; recall
is also given by separation, in pulse widths, each split beside the recall and
RMSE of an ideal engine at the joint Cramer-Rao bound (fwcore.studies.bound), and of one told the widths.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Sequence

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from fwcore.instrument.shape import echo_shape
from fwcore.engine.model import tabulated_row
from fwcore.studies.bound import echo_time_bounds_ps, expected_match
from fwcore.studies.simulate import RANGE_M_PER_PS, RESPONSE_WIDEST, SensorConfig
from fwcore.studies.truth import TRUTH_METADATA_KEY

SNR_BANDS = ((0.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 50.0), (50.0, np.inf))
_CM_PER_PS = RANGE_M_PER_PS * 100.0
RESOLVABLE_MIN_SNR = 5.0
GROUP_MATCH_W = 0.5  # a kept echo this many pulse widths from an unsplittable group's centre reports the group
SEPARATION_BINS_W = (0.0, 0.5, 0.75, 1.0, 1.5, 2.0, np.inf)  # the nearest other true echo of the pulse, in W
BOUND_FROM_W = 0.75  # the ideal engine's rows from this separation on (closer, an echo count is a choice, not a bound)
_KEY_STRIDE = 1.0e6  # ps: wider than any packet, so pulse_id * stride + time never mixes pulses


def _sensor_of(truth: pa.Table) -> SensorConfig:
    meta = json.loads((truth.schema.metadata or {}).get(TRUTH_METADATA_KEY, b"{}"))
    if "sensor" not in meta:
        raise ValueError("the truth table carries no simulation metadata (was it written by fwl simulate?)")
    return SensorConfig(**meta["sensor"])


def match_echoes(true_pulse, true_time, found_pulse, found_time, match_ps: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (true, found) of mutual nearest echoes of the same pulse within match_ps."""
    # pulse ids are 63-bit hashes: rank them first so that rank * stride + time stays exact in float64
    ids, rank = np.unique(np.concatenate([np.asarray(true_pulse), np.asarray(found_pulse)]), return_inverse=True)
    n_true = np.asarray(true_pulse).size
    tk = rank[:n_true].astype(float) * _KEY_STRIDE + np.asarray(true_time, float)
    fk = rank[n_true:].astype(float) * _KEY_STRIDE + np.asarray(found_time, float)
    if tk.size == 0 or fk.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    t_order, f_order = np.argsort(tk, kind="stable"), np.argsort(fk, kind="stable")
    ts, fs = tk[t_order], fk[f_order]

    def nearest(keys, sorted_other):
        j = np.clip(np.searchsorted(sorted_other, keys), 1, sorted_other.size - 1) if sorted_other.size > 1 \
            else np.zeros(keys.size, np.int64)
        if sorted_other.size > 1:
            left_closer = np.abs(keys - sorted_other[j - 1]) <= np.abs(sorted_other[j] - keys)
            j = np.where(left_closer, j - 1, j)
        return j

    t_to_f = nearest(ts, fs)
    f_to_t = nearest(fs, ts)
    mutual = (f_to_t[t_to_f] == np.arange(ts.size)) & (np.abs(ts - fs[t_to_f]) <= match_ps)
    return t_order[mutual], f_order[t_to_f[mutual]]


def range_crlb_cm(amplitude, sigma_ps, alpha, sensor: SensorConfig) -> np.ndarray:
    """Cramer-Rao bound (cm) of the range of one echo of known shape in the sensor's noise (Gaussian +
    signal-dependent + quantisation), sampled on the packet's grid: a generalized Gaussian, or the
    sensor's response broadened to the echo's width where the flight was simulated with one."""
    amplitude, sigma_ps, alpha = (np.asarray(a, float) for a in (amplitude, sigma_ps, alpha))
    if sensor.response is not None:
        return _response_crlb_cm(amplitude, sigma_ps, sensor)
    out = np.empty(amplitude.size)
    # the echo centred mid-sample and on a sample average out the grid phase: use both
    offsets = np.arange(-40, 41) * sensor.sample_spacing_ps
    for lo in range(0, amplitude.size, 20000):
        a, s, p = amplitude[lo:lo + 20000, None], sigma_ps[lo:lo + 20000, None], alpha[lo:lo + 20000, None] ** 2
        info = 0.0
        for phase in (0.0, 0.5 * sensor.sample_spacing_ps):
            d = offsets[None, :] + phase
            z = np.abs(d)
            f = a * np.exp(-z ** p / (2 * s ** 2))
            slope = f * p * z ** (p - 1) * np.sign(d) / (2 * s ** 2)
            var = sensor.noise_sigma ** 2 + sensor.shot_noise * f + 1.0 / 12.0
            info = info + 0.5 * (slope ** 2 / var).sum(axis=1)
        out[lo:lo + 20000] = _CM_PER_PS / np.sqrt(info)
    return out


def _response_crlb_cm(amplitude: np.ndarray, sigma_ps: np.ndarray, sensor: SensorConfig) -> np.ndarray:
    """range_crlb_cm for echoes of the sensor's response: A row(s)(t - u), its slope from the echo table."""
    spacing = sensor.sample_spacing_ps
    shape = echo_shape(sensor.response, spacing, RESPONSE_WIDEST)
    offsets = np.arange(-60, 61, dtype=float)
    out = np.empty(amplitude.size)
    for e, (a, s) in enumerate(zip(amplitude, sigma_ps / spacing)):
        grid, row, slope_row = tabulated_row(shape, s)
        info = 0.0
        for phase in (0.0, 0.5):
            f = a * np.interp(offsets + phase, grid, row, left=0.0, right=0.0)
            slope = a * np.interp(offsets + phase, grid, slope_row, left=0.0, right=0.0) / spacing  # per ps
            var = sensor.noise_sigma ** 2 + sensor.shot_noise * np.maximum(f, 0.0) + 1.0 / 12.0
            info += 0.5 * float((slope ** 2 / var).sum())
        out[e] = _CM_PER_PS / np.sqrt(info)
    return out


def _separation_class(pulse_id: np.ndarray, time_ps: np.ndarray, fwhm_ps: np.ndarray) -> np.ndarray:
    order = np.lexsort((time_ps, pulse_id))
    pid, t = pulse_id[order], time_ps[order]
    same_prev = np.r_[False, pid[1:] == pid[:-1]]
    gap = np.where(same_prev, np.r_[np.inf, np.diff(t)], np.inf)  # to the previous echo of the same pulse
    gap_next = np.r_[gap[1:], np.inf]
    nearest = np.minimum(gap, gap_next)
    out = np.empty(t.size, dtype=object)
    out[order] = np.where(np.isinf(nearest), "single", np.where(nearest >= fwhm_ps[order], "resolved", "overlapping"))
    return out


def nearest_separation_ps(pulse_id: np.ndarray, time_ps: np.ndarray) -> np.ndarray:
    """Per echo: the time to the nearest other echo of its pulse (ps); inf for a pulse's only echo."""
    pulse_id, time_ps = np.asarray(pulse_id), np.asarray(time_ps, float)
    order = np.lexsort((time_ps, pulse_id))
    pid, t = pulse_id[order], time_ps[order]
    same = pid[1:] == pid[:-1]
    gap = np.where(same, np.diff(t), np.inf)
    out = np.empty(t.size)
    out[order] = np.minimum(np.r_[np.inf, gap], np.r_[gap, np.inf])
    return out


def unsplittable_groups(pulse_id: np.ndarray, time_ps: np.ndarray, width_ps: float) -> np.ndarray:
    """Per echo: the group of echoes of its pulse chained by gaps under `width_ps` (-1 for an echo alone)."""
    pulse_id, time_ps = np.asarray(pulse_id), np.asarray(time_ps, float)
    order = np.lexsort((time_ps, pulse_id))
    pid, t = pulse_id[order], time_ps[order]
    close = np.r_[False, (pid[1:] == pid[:-1]) & (np.diff(t) < width_ps)]  # joined to the echo before it
    label = np.cumsum(~close) - 1
    size = np.bincount(label)
    out = np.empty(t.size, np.int64)
    out[order] = np.where(size[label] > 1, label, -1)
    return out


@dataclasses.dataclass(frozen=True)
class SeparationRecall:
    """Recall of true echoes (SNR >= 5) whose nearest other echo of the pulse lies lo..hi pulse widths away."""

    lo_w: float
    hi_w: float
    true_echoes: int
    matched: int

    @property
    def label(self) -> str:
        return (f"< {self.hi_w:g} W" if self.lo_w == 0 else f">= {self.lo_w:g} W" if np.isinf(self.hi_w)
                else f"{self.lo_w:g}-{self.hi_w:g} W")

    @property
    def recall(self) -> float:
        return self.matched / self.true_echoes if self.true_echoes else float("nan")


@dataclasses.dataclass(frozen=True)
class Resolution:
    """A run scored on what the instrument can resolve (the module's docstring says how)."""

    pulse_width_ps: float  # W: the truth's median FWHM
    resolvable: int  # true echoes at least W from every other of their pulse, SNR >= 5
    matched: int  # of those, with a kept echo within the match window
    kept: int
    right: int  # kept echoes matched to a true echo or reporting an unsplittable group
    range_rmse_cm: float  # over the matched resolvable echoes
    range_bias_cm: float
    by_separation: tuple[SeparationRecall, ...]  # true echoes of pulses with more than one, SNR >= 5

    @property
    def recall(self) -> float:
        return self.matched / self.resolvable if self.resolvable else float("nan")

    @property
    def precision(self) -> float:
        return self.right / self.kept if self.kept else float("nan")


def resolvability(truth: dict[str, np.ndarray]) -> tuple[float, np.ndarray, np.ndarray]:
    """The pulse width W (the truth's median FWHM, ps), each true echo's separation from the nearest other of its
    pulse in W (inf when alone), and whether its SNR is at least 5."""
    width = float(np.median(truth["fwhm_ps"])) if len(truth["fwhm_ps"]) else float("nan")
    separation = nearest_separation_ps(truth["pulse_id"], truth["time_ps"]) / width
    strong = np.asarray(truth["amplitude"], float) / np.asarray(truth["noise_sigma"], float) >= RESOLVABLE_MIN_SNR
    return width, separation, strong


def score_resolution(truth: dict[str, np.ndarray], found: dict[str, np.ndarray], match_ps: float = 1000.0,
                     pairs: tuple[np.ndarray, np.ndarray] | None = None) -> Resolution:
    """Recall, precision and range RMSE on resolvable echoes, and recall by separation, of kept echoes `found`
    (pulse_id, time_ps) against true echoes `truth` (pulse_id, time_ps, amplitude, noise_sigma, fwhm_ps).
    `pairs` are match_echoes' (true, found) index pairs where the caller has them."""
    t_idx, f_idx = pairs if pairs is not None else match_echoes(truth["pulse_id"], truth["time_ps"],
                                                                found["pulse_id"], found["time_ps"], match_ps)
    width, separation, strong = resolvability(truth)
    matched = np.zeros(separation.size, bool)
    matched[t_idx] = True
    resolvable = strong & (separation >= 1.0)
    dt_cm = (np.asarray(found["time_ps"], float)[f_idx] - np.asarray(truth["time_ps"], float)[t_idx]) * _CM_PER_PS
    range_cm = dt_cm[resolvable[t_idx]]
    bins = tuple(SeparationRecall(lo, hi, int(sel.sum()), int((sel & matched).sum()))
                 for lo, hi in zip(SEPARATION_BINS_W[:-1], SEPARATION_BINS_W[1:])
                 for sel in [strong & (separation >= lo) & (separation < hi)])
    right = f_idx.size + _group_reports(truth, found, width, matched, f_idx)
    return Resolution(width, int(resolvable.sum()), int((resolvable & matched).sum()), len(found["time_ps"]), right,
                      float(np.sqrt(np.mean(range_cm ** 2))) if range_cm.size else float("nan"),
                      float(np.mean(range_cm)) if range_cm.size else float("nan"), bins)


def _group_reports(truth: dict, found: dict, width_ps: float, matched: np.ndarray, f_idx: np.ndarray) -> int:
    """Kept echoes, not matched to a true echo, each the nearest within 0.5 W of the amplitude-weighted centre of a
    group of true echoes closer than W to each other none of which is matched: one per group."""
    group = unsplittable_groups(truth["pulse_id"], truth["time_ps"], width_ps)
    grouped = group >= 0
    if not grouped.any():
        return 0
    label = np.unique(group[grouped], return_inverse=True)[1]
    weight = np.asarray(truth["amplitude"], float)[grouped]
    centre = (np.bincount(label, weight * np.asarray(truth["time_ps"], float)[grouped]) / np.bincount(label, weight))
    pulse = np.zeros(centre.size, np.asarray(truth["pulse_id"]).dtype)
    pulse[label] = np.asarray(truth["pulse_id"])[grouped]
    open_group = np.bincount(label, matched[grouped]) == 0
    free = np.ones(len(found["time_ps"]), bool)
    free[f_idx] = False
    g, _ = match_echoes(pulse[open_group], centre[open_group], np.asarray(found["pulse_id"])[free],
                        np.asarray(found["time_ps"], float)[free], GROUP_MATCH_W * width_ps)
    return int(g.size)


def _stats(label: str, kind: str, true_sel: np.ndarray, found_count: int | None, pairs, truth, found, crlb) -> dict:
    t_idx, f_idx = pairs
    in_band = true_sel[t_idx]
    ti, fi = t_idx[in_band], f_idx[in_band]
    dt = found["time_ps"][fi] - truth["time_ps"][ti]
    range_cm = dt * _CM_PER_PS
    n_true = int(true_sel.sum())
    row = {"run": label, "split": kind, "true_echoes": n_true, "matched": int(ti.size),
           "recall": ti.size / n_true if n_true else float("nan"),
           "precision": (ti.size / found_count) if found_count else float("nan"),
           "range_bias_cm": float(range_cm.mean()) if ti.size else float("nan"),
           "range_rmse_cm": float(np.sqrt((range_cm ** 2).mean())) if ti.size else float("nan"),
           "amplitude_error": float(np.median((found["amplitude"][fi] - truth["amplitude"][ti])
                                              / truth["amplitude"][ti])) if ti.size else float("nan"),
           "fwhm_error": float(np.median((found["fwhm_ps"][fi] - truth["fwhm_ps"][ti])
                                         / truth["fwhm_ps"][ti])) if ti.size else float("nan"),
           "crlb_cm": float(np.sqrt((crlb[ti] ** 2).mean())) if ti.size else float("nan")}
    row["rmse_over_crlb"] = row["range_rmse_cm"] / row["crlb_cm"] if ti.size else float("nan")
    return row


def _kept_echoes(results_dir: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """A run's kept echoes (pulse_id, time_ps, amplitude, fwhm_ps) and the models they were fitted with."""
    if not (results_dir / "echoes").is_dir():
        raise FileNotFoundError(f"{results_dir}: no echoes/ table (is it an fwl run output directory?)")
    table = ds.dataset(str(results_dir / "echoes"), format="parquet")
    has_model = "model" in table.schema.names
    echoes = table.to_table(columns=["pulse_id", "time_ps", "amplitude", "fwhm_ps", "kept"] + ["model"] * has_model)
    fitted = sorted(set(echoes.column("model").to_pylist()) - {None}) if has_model else []
    kept = echoes.column("kept").to_numpy(zero_copy_only=False)
    return {c: echoes.column(c).to_numpy()[kept] for c in ("pulse_id", "time_ps", "amplitude", "fwhm_ps")}, fitted


def resolution_of_run(results_dir: str | Path, truth_file: str | Path, match_ps: float = 1000.0) -> Resolution:
    """score_resolution of one `fwl run` output directory against a simulated flight's truth."""
    columns = ("pulse_id", "time_ps", "amplitude", "fwhm_ps", "noise_sigma")
    truth_table = pq.read_table(truth_file, columns=list(columns))
    truth = {c: truth_table.column(c).to_numpy() for c in columns}
    return score_resolution(truth, _kept_echoes(Path(results_dir))[0], match_ps)


def evaluate_run(results_dir: str | Path, truth_file: str | Path, match_ps: float = 1000.0) -> list[dict]:
    """Rows of accuracy statistics for one `fwl run` output directory against the truth."""
    results_dir = Path(results_dir)
    truth_table = pq.read_table(truth_file)
    sensor = _sensor_of(truth_table)
    truth = {c: truth_table.column(c).to_numpy() for c in ("pulse_id", "time_ps", "amplitude", "sigma_ps",
                                                             "alpha", "fwhm_ps", "noise_sigma")}
    found, fitted = _kept_echoes(results_dir)
    run_json = results_dir / "run.json"
    config = json.loads(run_json.read_text()).get("config", {}) if run_json.exists() else {}
    model = config.get("model", "?")
    if fitted and fitted != [model]:  # --model auto: the model(s) the echoes were fitted with
        model = f"{model}: {', '.join(fitted)}"
    label = f"{results_dir.name} ({config.get('optimizer', '?')}, {model})"
    pairs = match_echoes(truth["pulse_id"], truth["time_ps"], found["pulse_id"], found["time_ps"], match_ps)
    crlb = range_crlb_cm(truth["amplitude"], truth["sigma_ps"], truth["alpha"], sensor)
    snr = truth["amplitude"] / truth["noise_sigma"]
    separation = _separation_class(truth["pulse_id"], truth["time_ps"], truth["fwhm_ps"])
    everything = np.ones(snr.size, bool)
    rows = [_stats(label, "all", everything, found["pulse_id"].size, pairs, truth, found, crlb)]
    for lo, hi in SNR_BANDS:
        name = f"SNR {lo:g}-{hi:g}" if np.isfinite(hi) else f"SNR >= {lo:g}"
        rows.append(_stats(label, name, (snr >= lo) & (snr < hi), None, pairs, truth, found, crlb))
    for kind in ("single", "resolved", "overlapping"):
        rows.append(_stats(label, kind, separation == kind, None, pairs, truth, found, crlb))
    # the engine's target split: echoes the system can separate, well above the noise
    rows.append(_stats(label, "single or resolved, SNR >= 10", (separation != "overlapping") & (snr >= 10.0), None, pairs,
                       truth, found, crlb))
    return rows + _resolution_rows(label, truth, found, pairs, crlb, sensor, match_ps)


def _resolution_rows(label: str, truth: dict, found: dict, pairs, crlb: np.ndarray, sensor: SensorConfig,
                     match_ps: float) -> list[dict]:
    """score_resolution as rows: resolvable echoes (precision: kept echoes that are right) and recall by separation,
    each resolvable split followed by what an ideal engine would reach there (fwcore.studies.bound), with the widths
    unknown (the joint CRLB) and known (the limit physical width priors approach)."""
    scored = score_resolution(truth, found, match_ps, pairs=pairs)
    _, apart, strong = resolvability(truth)
    resolvable = strong & (apart >= 1.0)
    wanted = strong & (apart >= BOUND_FROM_W)
    bounds = {known: echo_time_bounds_ps(truth["pulse_id"], truth["time_ps"], truth["amplitude"], truth["sigma_ps"],
                                         truth["alpha"], sensor, wanted=wanted, widths_known=known)
              for known in (False, True)}

    def at_bound(split: str, within: np.ndarray) -> list[dict]:
        rows = []
        for known, name in ((False, "at the joint CRLB (an ideal engine)"), (True, "widths known (the limit)")):
            ideal = expected_match(bounds[known][within], match_ps, _CM_PER_PS)
            row = {c: float("nan") for c, _, _ in EVALUATION_COLUMNS}
            rows.append({**row, "run": label, "split": f"{split}, {name}", "true_echoes": ideal.true_echoes,
                         "matched": round(ideal.expected_matched), "recall": ideal.recall,
                         "range_rmse_cm": ideal.range_rmse_cm})
        return rows

    row = _stats(label, "resolvable: >= 1 W apart, SNR >= 5", resolvable, None, pairs, truth, found, crlb)
    rows = [{**row, "precision": scored.precision}, *at_bound("resolvable", resolvable)]
    for b in scored.by_separation:
        within = strong & (apart >= b.lo_w) & (apart < b.hi_w)
        rows.append(_stats(label, f"{b.label} apart, SNR >= 5", within, None, pairs, truth, found, crlb))
        if b.lo_w >= BOUND_FROM_W:
            rows.extend(at_bound(b.label, within))
    return rows


EVALUATION_COLUMNS = [("run", "run", "{}"), ("split", "echoes", "{}"), ("true_echoes", "true", "{}"),
                      ("matched", "matched", "{}"), ("recall", "recall", "{:.3f}"),
                      ("precision", "precision", "{:.3f}"), ("range_bias_cm", "range bias (cm)", "{:.2f}"),
                      ("range_rmse_cm", "range RMSE (cm)", "{:.2f}"), ("crlb_cm", "CRLB (cm)", "{:.2f}"),
                      ("rmse_over_crlb", "RMSE / CRLB", "{:.2f}"), ("amplitude_error", "amplitude err", "{:+.3f}"),
                      ("fwhm_error", "FWHM err", "{:+.3f}")]


def evaluate_runs(results_dirs: Sequence[str | Path], truth_file: str | Path, match_ps: float = 1000.0) -> list[dict]:
    rows = []
    for d in results_dirs:
        rows.extend(evaluate_run(d, truth_file, match_ps))
    return rows


def evaluate_radiometry(results_dir: str | Path, truth_file: str | Path, match_ps: float = 1000.0) -> dict:
    """A run's ranges and reflectances against a radiometric flight's truth (`fwl simulate --radiometry`): over
    the extended true echoes (one surface filling the footprint) matched by a kept echo, the median and 90th
    percentile of |rho / rho_true - 1|, the median |range error| in cm over every matched echo, and over every
    kept echo the share with a reflectance, the largest and how many exceed 1.5 (true ones are 0.05-0.6)."""
    truth_table = pq.read_table(truth_file, columns=["pulse_id", "time_ps", "range_m", "reflectance", "extended"])
    truth = {c: truth_table.column(c).to_numpy(zero_copy_only=False) for c in truth_table.column_names}
    echoes = ds.dataset(str(Path(results_dir) / "echoes"), format="parquet").to_table(
        columns=["pulse_id", "time_ps", "kept", "range_m", "reflectance", "incidence_deg", "radiometry"])
    kept = echoes.column("kept").to_numpy(zero_copy_only=False)
    found = {c: echoes.column(c).to_numpy(zero_copy_only=False)[kept] for c in echoes.column_names}
    t_idx, f_idx = match_echoes(truth["pulse_id"], truth["time_ps"], found["pulse_id"], found["time_ps"], match_ps)
    range_error = np.asarray(found["range_m"][f_idx], float) - truth["range_m"][t_idx]
    extended = truth["extended"][t_idx].astype(bool) & np.isfinite(truth["reflectance"][t_idx])
    rho = np.asarray(found["reflectance"][f_idx], float)[extended]
    ratio = np.abs(rho / truth["reflectance"][t_idx][extended] - 1.0)
    ratio = ratio[np.isfinite(ratio)]
    with_plane = np.isfinite(np.asarray(found["incidence_deg"][f_idx], float))[extended]
    finite_range = np.isfinite(range_error)
    given = np.asarray(found["reflectance"], float)
    given = given[np.isfinite(given)]
    return {"kept": int(kept.sum()), "kept_with_reflectance": given.size / kept.sum() if kept.any() else float("nan"),
            "reflectance_max": float(given.max()) if given.size else float("nan"),
            "reflectance_above_1_5": int((given > 1.5).sum()), "matched": int(t_idx.size), "extended": int(extended.sum()), "extended_with_reflectance": int(ratio.size),
            "extended_with_plane": float(with_plane.mean()) if with_plane.size else float("nan"),
            "reflectance_error_median": float(np.median(ratio)) if ratio.size else float("nan"),
            "reflectance_error_p90": float(np.percentile(ratio, 90)) if ratio.size else float("nan"),
            "range_error_median_cm": float(np.median(np.abs(range_error[finite_range])) * 100.0)
            if finite_range.any() else float("nan"),
            "range_bias_cm": float(np.median(range_error[finite_range]) * 100.0) if finite_range.any()
            else float("nan"),
            "with_range": float(finite_range.mean()) if t_idx.size else float("nan"),
            "calibrated": float(np.mean(found["radiometry"][f_idx] == "calibrated")) if t_idx.size else float("nan")}
