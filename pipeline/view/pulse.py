"""One pulse of a run, again: its samples re-read from the input, decomposed by the engine as the run did.

The run's configuration (run.json), the system pulse it measured for the file
(run.json's inputs[], and the pulse's row) and the pulse's own seed make the
engine reproduce the run's echoes exactly; the same function refits the pulse
with any other configuration for the page's "Try".
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from pathlib import Path

import numpy as np

from fwcore.engine.config import PRESETS, DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch, smoothing_sigma_samples
from fwcore.engine.records import WaveformBatch
from fwcore.io import PointRange, PulseBatch, plan_point_ranges, read_pulses
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, PulseOverrides, SystemPulse
from fwcore.instrument.shape import lobe_centroid_ps
from fwcore.engine.model import sigma_to_time_unit
from fwcore.engine.smoothing import gaussian_smooth
from fwcore.metrics.pulses import vertical_axis
from fwcore.pulses import pulse_waveforms
from pipeline.layout import range_start
from pipeline.outputs import recorded_pulse
from pipeline.view import queries
from pipeline.view.catalog import run_inputs, run_summary

# what run.json's config held of the file's pulse before the pulse left it: read from the row and inputs[] instead
_FORMER_PULSE_SETTINGS = ("system_pulse_fwhm_ps", "default_pulse_fwhm_ps", "system_response", "shape_tolerance")
_read_lock = threading.Lock()


@dataclasses.dataclass(frozen=True)
class RawPulse:
    """What the input holds for one pulse."""

    samples: np.ndarray
    sample_spacing_ps: float
    seed: int
    return_location_ps: np.ndarray
    return_number: np.ndarray
    return_intensity: np.ndarray
    valid: np.ndarray | None = None  # the samples the engine saw (fwcore.pulses.signal_windows); None: all
    noise_floor: float = 0.0  # the noise sigma the file records (GEDI), the engine's floor
    first_z: float = float("nan")  # the first sample's height and the height a sample drops (m): forest markers
    metres_per_sample: float = float("nan")


@functools.lru_cache(maxsize=16)
def _ranges(path: str, points_per_range: int) -> tuple[PointRange, ...]:
    return tuple(plan_point_ranges(path, points_per_range))


@functools.lru_cache(maxsize=8)
def _range_pulses(point_range: PointRange) -> PulseBatch:
    return read_pulses(dataclasses.replace(point_range, max_pulses=None))


def _find_in_ranges(path: Path, points_per_range: int, part_name: str, pulse_id: int) -> tuple[PulseBatch, int]:
    """The pulse's batch and index, reading the range the run wrote it from (its part file's name)
    first, then the others."""
    ranges = _ranges(str(path), points_per_range)
    start = range_start(part_name)
    ordered = sorted(ranges, key=lambda r: r.start != start)
    for r in ordered:
        with _read_lock:
            pulses = _range_pulses(r)
        hit = np.flatnonzero(pulses.pulse_id == pulse_id)
        if hit.size:
            return pulses, int(hit[0])
    raise LookupError(f"pulse {pulse_id} is not in {path.name}")


def load_pulse(run: Path, source_file: str,
               pulse_id: int) -> tuple[RawPulse, DecompositionConfig, SystemPulse, dict]:
    """One pulse of a run: its samples re-read from the input with the seed the run gave it, the
    configuration the run decomposed it with (run.json's), its file's system pulse (run_pulse), its pulse row."""
    found = queries.pulse_row(run, source_file, pulse_id)
    if found is None:
        raise LookupError(f"pulse {pulse_id} of {source_file} is not in this run's pulse table")
    row, part = found
    inputs = run_inputs(run)
    if source_file not in inputs:
        raise FileNotFoundError(f"{source_file}: the run's input is no longer where run.json says")
    summary = run_summary(run)
    config = DecompositionConfig.from_dict({k: v for k, v in summary["config"].items()
                                            if k not in _FORMER_PULSE_SETTINGS})
    if row.get("model"):  # the echo model the run fitted (under --model auto, the one chosen for the file)
        config = config.replace(model=Model(row["model"]))
    pulse = run_pulse(summary, source_file, row)
    pulses, i = _find_in_ranges(inputs[source_file], int(summary.get("points_per_range") or 5000), part, pulse_id)
    engine_input = pulse_waveforms(pulses, config.seed)
    seed = int(engine_input.seeds[i])
    lo, hi = pulses.return_offsets[i], pulses.return_offsets[i + 1]
    first_z, drop = vertical_axis(pulses)
    raw = RawPulse(pulses.pulse_samples(i).astype(float), float(pulses.sample_spacing_ps[i]), seed,
                   pulses.return_location_ps[lo:hi].astype(float), pulses.return_number[lo:hi].astype(int),
                   pulses.return_intensity[lo:hi].astype(int),
                   engine_input.valid[pulses.sample_offsets[i]:pulses.sample_offsets[i + 1]].copy(),
                   0.0 if engine_input.noise_floor is None else float(engine_input.noise_floor[i]),
                   float(first_z[i]), float(drop[i]))
    return raw, config, pulse, row


def run_pulse(summary: dict, source_file: str, row: dict) -> SystemPulse:
    """The system pulse a run decomposed a file's pulses with: the record run.json's inputs[] holds of it
    (SystemPulse.from_dict, pipeline.outputs.recorded_pulse); where it holds none, the width and shape tolerance
    of the pulse's row."""
    entry = next((e for e in summary.get("inputs", []) if isinstance(e, dict) and e.get("name") == source_file), {})
    recorded = recorded_pulse(entry)
    if recorded is not None:
        return recorded
    fwhm, tolerance = row.get("system_pulse_fwhm_ps"), row.get("shape_tolerance")
    return SystemPulse(float(fwhm) if fwhm is not None else DEFAULT_PULSE_FWHM_PS, "the run's",
                       float(tolerance or 0.0), "the run's")


def try_pulse(pulse: SystemPulse, preset: str | None) -> SystemPulse:
    """The file's pulse under another preset: what the preset says of it (the paper's: its model exact)."""
    return PulseOverrides.of_preset(preset).applied(pulse)


def try_config(base: DecompositionConfig, preset: str | None, changes: dict) -> DecompositionConfig:
    """Another method for a pulse: a preset's method (as `fwl run --preset` has it) or the run's own, then the
    changed settings; the run's model and seed stay unless a change names them, so only the method differs
    (the file's pulse: try_pulse)."""
    config = base
    if preset:
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {', '.join(sorted(PRESETS))}, not {preset!r}")
        config = PRESETS[preset].config().replace(model=base.model, seed=base.seed)
    unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(DecompositionConfig)})
    if unknown:
        raise ValueError(f"unknown decomposition settings {unknown}")
    return DecompositionConfig.from_dict({**config.to_dict(), **changes})


def decompose_pulse(raw: RawPulse, config: DecompositionConfig, pulse: SystemPulse) -> dict:
    """The engine on one pulse, and everything the pulse view draws: times in ps, amplitudes in counts."""
    batch = WaveformBatch.from_waveforms([raw.samples], raw.sample_spacing_ps, [raw.seed],
                                         None if raw.valid is None else [raw.valid])
    batch = dataclasses.replace(batch, noise_floor=np.array([raw.noise_floor]))
    result = decompose_batch(batch, config, pulse, threads=1).waveform(0)
    spacing = raw.sample_spacing_ps
    t = np.arange(raw.samples.size, dtype=float)
    fine = np.linspace(0.0, raw.samples.size - 1.0, 4 * raw.samples.size - 3)  # smooth curves between samples
    smoothing = float(smoothing_sigma_samples(config, pulse, np.array([spacing]))[0])
    echoes = []
    for k in range(result.amplitude.size):
        a, u, s, al = (float(v[k]) for v in (result.amplitude, result.position, result.sigma, result.alpha))
        echoes.append({
            "echo_index": k, "amplitude": a, "time_ps": u * spacing,
            "sigma_chauve": float(sigma_to_time_unit(np.array([s]), np.array([al]), np.array([spacing]))[0]),
            "alpha": al, "fwhm_ps": float(result.fwhm[k]) * spacing, "energy": float(result.energy[k]) * spacing,
            "kept": result.reject_reason[k] == "", "reject_reason": result.reject_reason[k],
            "curve": result.background + result.echo(k, fine),
        })
    return {
        "config": config.to_dict(),
        "pulse": pulse.to_dict(),
        "status": result.status,
        "time_ps": t * spacing,
        "raw": raw.samples,
        "denoised": gaussian_smooth(raw.samples, smoothing) if smoothing > 0 else raw.samples,
        "fine_time_ps": fine * spacing,
        "model": result.model(fine) if not result.status else np.full(fine.size, np.nan),
        "background": result.background, "noise_sigma": result.noise_sigma,
        "fit_error": result.fit_error, "fit_error_raw": result.fit_error_raw, "rmse": result.rmse, "r2": result.r2,
        "model_evaluations": result.nfev, "n_echoes_initial": result.n_echoes_initial,
        "echoes": echoes,
        "response": _response_curve(pulse.echo_model(config.model), pulse, result, spacing),
    }


def _response_curve(model: Model, pulse: SystemPulse, result, spacing: float) -> dict | None:
    """Under the system model, the instrument's response (unbroadened) at the strongest echo, on the background:
    what every echo's shape is made of."""
    if model is not Model.SYSTEM or result.status or result.amplitude.size == 0:
        return None
    response = pulse.echo_response()
    k = int(np.argmax(result.amplitude))
    # an echo's position is its response lobe's centroid, which lies that far after the response's peak
    return {"time_ps": (result.position[k] * spacing - lobe_centroid_ps(response) + response.times).tolist(),
            "counts": (result.background + result.amplitude[k] * response.response).tolist(),
            "source": response.source}


PASSED_OVER_M = 0.01  # a mode this far below the selected ground was passed over (mode_z is float32: 1e-4 m steps)
# the pulse row's columns that say what a shot is and what the products made of it (pipeline.tables), when present
SHOT_COLUMNS = ("shot_number", "lfid", "selected_algorithm", "top_z", "agbd", "agbd_se", "agbd_stratum",
                "agbd_reason")
SHOT_IDENTITY = {"shot_number", "lfid", "selected_algorithm", "agbd"}  # what makes a pulse a mission's shot


def _finite(value) -> float | None:
    return float(value) if value is not None and np.isfinite(float(value)) else None


def forest_markers(raw: RawPulse, row: dict) -> dict | None:
    """Where the pulse's ground, RH25/50/75/98 and detected modes lie on its waveform (ps from the first sample),
    from its row's ground_z, rh and (when the run wrote it) mode_z: a mode below the ground is one the selected
    L2A algorithm passed over. None where the run measured no ground."""
    ground, rh = _finite(row.get("ground_z")), row.get("rh")
    if ground is None or not np.isfinite(raw.metres_per_sample) or raw.metres_per_sample <= 0:
        return None

    def time_ps(z: float) -> float:
        return (raw.first_z - z) / raw.metres_per_sample * raw.sample_spacing_ps
    heights = [(k, _finite(rh[k])) for k in (25, 50, 75, 98)] if rh is not None and len(rh) > 98 else []
    listed = row.get("mode_z")
    modes = [z for z in (_finite(v) for v in ([] if listed is None else listed)) if z is not None]
    return {"ground_time_ps": time_ps(ground), "ground_z": ground,
            "rh": [{"k": k, "height_m": h, "time_ps": time_ps(ground + h)} for k, h in heights if h is not None],
            "modes": [{"z": z, "time_ps": time_ps(z), "passed_over": z < ground - PASSED_OVER_M} for z in modes]}


def shot_details(row: dict) -> dict | None:
    """What the products say of this shot, of the columns the run wrote with values (SHOT_COLUMNS): its shot number
    and LFID, the L2A algorithm whose ground and RH the row holds, its highest return, its biomass (L4A's agbd) or
    why there is none; None when none of SHOT_IDENTITY has a value (a LAS or PulseWaves run: its top_z and
    agbd_reason alone are no shot's products).
    Identities as decimal strings (exact)."""
    out = {}
    for name in SHOT_COLUMNS:
        value = row.get(name)
        if value is None or value == "" or (isinstance(value, float) and not np.isfinite(value)):
            continue
        if name in ("shot_number", "lfid"):
            out[name] = str(int(value))
        elif name in ("agbd_stratum", "agbd_reason"):
            out[name] = str(value)
        else:
            out[name] = int(value) if name == "selected_algorithm" else float(value)
    if not out.keys() & SHOT_IDENTITY:  # a small-footprint pulse: no mission shot, no product to show
        return None
    if "agbd_reason" in out:
        out.setdefault("agbd", None)  # no biomass, and why
    return out


def system_returns(raw: RawPulse) -> list[dict]:
    return [{"time_ps": float(t), "return_number": int(n), "intensity": int(i)}
            for t, n, i in zip(raw.return_location_ps, raw.return_number, raw.return_intensity)]


def reproduces(fit: dict, table_rows: list[dict], tolerance: float = 1e-6) -> bool:
    """Whether a refit gives the run's echoes: same count, amplitudes and times."""
    if len(fit["echoes"]) != len(table_rows):
        return False
    for e, row in zip(fit["echoes"], table_rows):
        for name in ("amplitude", "time_ps"):
            if abs(e[name] - float(row[name])) > tolerance * max(1.0, abs(float(row[name]))):
                return False
    return True


@functools.lru_cache(maxsize=4)
def _las_points(path: str) -> dict[str, np.ndarray]:
    """x, y, z, gps_time of every point (the system's returns) of a LAS/LAZ input, read in chunks."""
    import laspy

    parts = []
    with laspy.open(path) as reader:
        for chunk in reader.chunk_iterator(1_000_000):
            parts.append({"x": np.asarray(chunk.x), "y": np.asarray(chunk.y), "z": np.asarray(chunk.z),
                          "gps_time": np.asarray(chunk.gps_time)})
    return {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0) for k in ("x", "y", "z", "gps_time")}


def system_return_points(run: Path, box: tuple[float, float, float, float] | None, limit: int) -> dict:
    """The system's own returns of the run's pulses (by their gps times) inside the box, at most `limit`,
    evenly thinned."""
    xs, ys, zs = [], [], []
    frame = queries.frame(run)
    for name, path in run_inputs(run).items():
        times = queries.gps_time_range(run, name)
        if times is None or path.suffix.lower() not in (".las", ".laz"):
            continue  # PulseWaves keeps no separate return points
        p = _las_points(str(path))
        sel = (p["gps_time"] >= times[0]) & (p["gps_time"] <= times[1])
        px, py, pz = frame.apply(p["x"][sel], p["y"][sel], p["z"][sel])  # in the map's frame, as the echoes
        inside = np.ones(px.size, dtype=bool) if box is None else \
            (px >= box[0]) & (px <= box[1]) & (py >= box[2]) & (py <= box[3])
        xs.append(px[inside]), ys.append(py[inside]), zs.append(pz[inside])
    x, y, z = (np.concatenate(a) if a else np.zeros(0) for a in (xs, ys, zs))
    total = x.size
    if total > limit:
        keep = np.linspace(0, total - 1, limit).astype(np.int64)
        x, y, z = x[keep], y[keep], z[keep]
    return {"total": int(total), "x": x, "y": y, "z": z}
