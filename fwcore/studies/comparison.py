"""`fwl compare`: every optimizer on the same waveforms, as tables, figures and point-cloud statistics.

Reads a full-waveform LAS/LAZ file or a NEON-layout CSV, runs fwcore.studies.methods,
and writes into the output directory:
    compare.csv, compare.md      one row per optimizer and model (the method's Table 1 + ours)
    points.csv                   (LAS input) decomposed points against the system's returns
    budget.csv, budget.md        (--budget) fit error against evaluations and seconds
    fit_pulse_<id>.png           each chosen pulse with every optimizer's model and echoes
    methods.png, budget.png      bars of fit error and speed; the budget curves
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Sequence

import numpy as np

from fwcore.studies.methods import (MethodRun, budget_settings, budget_study, choose_fast_preset, compare_methods,
                            compare_to_system)
from fwcore.engine.config import DecompositionConfig, Model, Optimizer
from fwcore.instrument.measure import file_system_pulse, read_csv_input
from fwcore.instrument.pulse import PulseOverrides, SystemPulse
from fwcore.io import read_pulses
from fwcore.io.formats import NEON_CSV, format_of
from fwcore.pulses import echo_positions, echo_times_ps, pulse_waveforms
from fwcore.engine.records import WaveformBatch


@dataclasses.dataclass(frozen=True)
class ComparisonInput:
    """The waveforms to compare on, their ids, their system pulse, and (LAS input) the pulses for the point
    comparison."""

    batch: WaveformBatch
    pulse_id: np.ndarray
    pulse: SystemPulse
    pulses: object | None = None  # fwcore.io.records.PulseBatch for LAS input


def load_input(path: str | Path, config: DecompositionConfig, limit: int | None = None,
               outgoing: str | Path | None = None, overrides: PulseOverrides = PulseOverrides()) -> ComparisonInput:
    """A LAS/LAZ file (system pulse measured on its single-return pulses, as `fwl run`) or a NEON CSV
    (as `fwl decompose-csv`: fwcore.instrument.measure.read_csv_input)."""
    if format_of(path) is NEON_CSV:
        csv = read_csv_input(path, config, overrides, outgoing, limit=limit)
        return ComparisonInput(csv.batch, csv.waveform_id, csv.pulse)
    pulses = read_pulses(path)
    if limit is not None and limit < len(pulses):
        pulses = _first_pulses(pulses, limit)
    pulse = file_system_pulse(path, len(pulses.return_xyz), config, overrides)  # as fwl run measures it
    return ComparisonInput(pulse_waveforms(pulses, config.seed), pulses.pulse_id, pulse, pulses)


def _first_pulses(pulses, n: int):
    """The first n pulses of a PulseBatch, with their samples and system returns."""
    s_end, r_end = pulses.sample_offsets[n], pulses.return_offsets[n]
    per_pulse = {f.name for f in dataclasses.fields(pulses)} - {
        "source_file", "samples", "sample_offsets", "return_xyz", "return_number", "return_intensity",
        "return_location_ps", "return_offsets", "rejected", "outgoing", "outgoing_offsets", "number_of_returns"}
    changes = {name: getattr(pulses, name)[:n] for name in per_pulse if getattr(pulses, name) is not None}
    if pulses.outgoing is not None:  # PulseWaves: the recorded outgoing waveforms, flat like the samples
        changes.update(outgoing=pulses.outgoing[:pulses.outgoing_offsets[n]],
                       outgoing_offsets=pulses.outgoing_offsets[:n + 1])
    return dataclasses.replace(
        pulses, **changes, samples=pulses.samples[:s_end], sample_offsets=pulses.sample_offsets[:n + 1],
        return_xyz=pulses.return_xyz[:r_end], return_number=pulses.return_number[:r_end],
        return_intensity=pulses.return_intensity[:r_end], return_location_ps=pulses.return_location_ps[:r_end],
        return_offsets=pulses.return_offsets[:n + 1],
        number_of_returns=None if pulses.number_of_returns is None else pulses.number_of_returns[:r_end])


# ---------------------------------------------------------------- writing

TABLE_COLUMNS = [("optimizer", "optimizer", "{}"), ("model", "model", "{}"), ("waveforms", "waveforms", "{}"),
                 ("fit_error", "fit error (Eq. 9)", "{:.1f}"), ("fit_error_raw", "vs raw", "{:.1f}"),
                 ("rmse", "RMSE", "{:.2f}"), ("r2", "R2", "{:.4f}"), ("echoes", "echoes", "{:.2f}"),
                 ("echoes_kept", "kept", "{:.2f}"), ("evaluations", "evaluations", "{:.0f}"),
                 ("seconds", "seconds", "{:.2f}"), ("waveforms_per_second", "waveforms/s", "{:.1f}")]


PAPER_MDE = ("mde k x t = 5", "G 80")  # the budget study's row for MDE at the paper's settings


def write_csv(path: Path, rows: Sequence[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def markdown_table(rows: Sequence[dict], columns: Sequence[tuple[str, str, str]]) -> str:
    lines = ["| " + " | ".join(title for _, title, _ in columns) + " |",
             "|" + "|".join("---" for _ in columns) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(fmt.format(row[key]) for key, _, fmt in columns) + " |")
    return "\n".join(lines) + "\n"


def complex_pulses(run: MethodRun, count: int = 3) -> list[int]:
    """Batch indices of the pulses with the most kept echoes (ties: the larger fit error)."""
    r = run.result
    kept = np.bincount(r.echo_waveform[r.reject == 0], minlength=len(r))
    order = np.lexsort((-r.fit_error, -kept))
    return [int(i) for i in order[:count]]


def plot_pulse_fits(path: Path, batch: WaveformBatch, index: int, pulse_id: int, runs: Sequence[MethodRun]) -> None:
    """One panel per optimizer: the raw samples, the fitted model and each echo (kept solid, spurious dashed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = batch.offsets[index], batch.offsets[index + 1]
    y = batch.samples[lo:hi]
    valid = batch.valid[lo:hi]
    t = np.arange(y.size)
    fine = np.linspace(0, y.size - 1, 8 * y.size)
    cols = 3
    rows = (len(runs) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.2 * rows), sharex=True, sharey=True, squeeze=False)
    for ax, run in zip(axes.flat, runs):
        d = run.result.waveform(index)
        ax.plot(t[valid], y[valid], ".", color="0.5", ms=3, label="samples")
        if d.status == "":
            ax.plot(fine, d.model(fine), color="C3", lw=1.2, label="model")
            for k in range(d.amplitude.size):
                ax.plot(fine, d.background + d.echo(k, fine), lw=0.8, color="C0",
                        ls="-" if d.reject_reason[k] == "" else "--")
        ax.set_title(f"{run.label} ({run.config.model.value}): Eq. 9 {d.fit_error:.0f}, "
                     f"{int(d.kept.sum())}/{d.amplitude.size} kept", fontsize=9)
    for ax in axes.flat[len(runs):]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("sample")
    fig.suptitle(f"pulse {pulse_id}: samples (grey), model (red), echoes (blue; dashed: spurious)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_method_bars(path: Path, rows: Sequence[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['optimizer']}\n{r['model']}" for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(max(8, 0.9 * len(rows) * 2), 4))
    a.bar(labels, [r["fit_error"] for r in rows], color="C0")
    a.set_ylabel("mean fit error (Eq. 9)")
    b.bar(labels, [r["waveforms_per_second"] for r in rows], color="C1")
    b.set_ylabel("waveforms per second")
    b.set_yscale("log")
    for ax in (a, b):
        ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_budget(path: Path, rows: Sequence[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for family in dict.fromkeys(r["family"] for r in rows):
        part = [r for r in rows if r["family"] == family]
        a.plot([r["evaluations"] for r in part], [r["fit_error"] for r in part], "o-", label=family)
        b.plot([r["seconds"] for r in part], [r["fit_error"] for r in part], "o-", label=family)
    a.set_xlabel("model evaluations per waveform (LM: Jacobians)")
    b.set_xlabel("seconds for the batch")
    a.set_ylabel("mean fit error (Eq. 9)")
    for ax in (a, b):
        ax.set_xscale("log")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run_comparison(input_path: str | Path, output: str | Path, base: DecompositionConfig,
                   optimizers: Sequence[Optimizer], models: Sequence[Model], limit: int | None = None,
                   pulses: Sequence[int] | None = None, distance: float = 0.5, budget: bool = False,
                   threads: int = 1, outgoing: str | Path | None = None,
                   overrides: PulseOverrides = PulseOverrides()) -> dict:
    """The whole `fwl compare`; returns what it wrote and the rows."""
    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    # the system model's rows need the file's response: measured as fwl run --model system measures it
    measured = base.replace(model=Model.SYSTEM if Model.SYSTEM in models else Model.GENERALIZED)
    data = load_input(input_path, measured, limit, outgoing, overrides)
    runs = compare_methods(data.batch, base, data.pulse, optimizers, models, threads)
    rows = [run.row() for run in runs]
    write_csv(output / "compare.csv", rows)
    header = (f"# Method comparison on {Path(input_path).name}\n\n{len(data.batch)} waveforms, "
              f"{threads} thread(s), system pulse FWHM {data.pulse.fwhm_ps:.0f} ps. GA, PSO and DE at "
              f"NP 100 x G 100, MDE at 60 x 80; LM and L-BFGS are our numba implementations (bounded).\n\n")
    (output / "compare.md").write_text(header + markdown_table(rows, TABLE_COLUMNS))
    written = ["compare.csv", "compare.md"]
    point_rows = _write_points(output, data, runs, distance) if data.pulses is not None else []
    if point_rows:
        written.append("points.csv")
    if pulses:
        index_of = {int(p): i for i, p in enumerate(data.pulse_id)}
        missing = [p for p in pulses if p not in index_of]
        if missing:
            raise ValueError(f"{input_path}: no pulse with id {missing} among the compared ones")
        chosen = [index_of[p] for p in pulses]
    else:
        # the most complex pulses by the reference method, MDE (else the last method run)
        chosen = complex_pulses(next((r for r in runs if r.config.optimizer is Optimizer.MDE), runs[-1]))
    for i in chosen:
        name = f"fit_pulse_{int(data.pulse_id[i])}.png"
        plot_pulse_fits(output / name, data.batch, i, int(data.pulse_id[i]), runs)
        written.append(name)
    plot_method_bars(output / "methods.png", rows)
    written.append("methods.png")
    summary = {"rows": rows, "points": point_rows, "written": written}
    if budget:
        summary.update(_write_budget(output, Path(input_path).name, data, base, threads))
        written += ["budget.csv", "budget.md", "budget.png"]
    return summary


def _write_points(output: Path, data: ComparisonInput, runs: Sequence[MethodRun], distance: float) -> list[dict]:
    """points.csv and compare.md's section: each run's kept echoes against the system's returns."""
    point_rows = []
    for run in runs:
        kept = run.result.reject == 0
        xyz = echo_positions(data.pulses, run.result, data.pulse.range_offset_ps)[kept]
        times = echo_times_ps(data.pulses, run.result, data.pulse.range_offset_ps)[kept]
        point_rows.append({"optimizer": run.label, "model": run.config.model.value,
                           **compare_to_system(data.pulses, xyz, times, run.result.echo_waveform[kept],
                                               distance).row()})
    write_csv(output / "points.csv", point_rows)
    point_columns = [("optimizer", "optimizer", "{}"), ("model", "model", "{}"),
                     ("system_points", "system points", "{}"), ("decomposed_points", "decomposed", "{}"),
                     ("matched_system", "matched", "{}"), ("missed_system", "missed", "{}"),
                     ("new_points", "new", "{}"), ("new_at_omitted_returns", "at omitted returns", "{}"),
                     ("new_in_dead_zone", "new in dead zone", "{}"),
                     ("mean_distance", "mean d (m)", "{:.3f}"),
                     ("median_distance", "median d (m)", "{:.3f}"), ("p95_distance", "p95 d (m)", "{:.3f}")]
    with open(output / "compare.md", "a") as f:
        f.write(f"\n## Points against the system's returns (matched within {distance} m)\n\n"
                f"{int(data.pulses.omitted_returns().sum())} returns the system reported are not in the "
                "file (its pulses number more returns than it holds: it was clipped); new points at "
                "omitted returns lie where one of them must, between their pulse's held returns. "
                f"Of the other new points, those in the dead zone lie within {point_rows[0]['dead_zone']:.2f} m "
                "of a return of their own pulse, the smallest separation at which the system ever reports "
                "two returns: it could not have reported them.\n\n")
        f.write(markdown_table(point_rows, point_columns))
    return point_rows


def _write_budget(output: Path, name: str, data: ComparisonInput, base: DecompositionConfig, threads: int) -> dict:
    """budget.csv, budget.md and budget.png: the evaluation budget study; its rows and the fast choice."""
    budget_rows = budget_study(data.batch, base, data.pulse, budget_settings(), threads)
    paper = next(r["fit_error"] for r in budget_rows if (r["family"], r["setting"]) == PAPER_MDE)
    fast = choose_fast_preset(budget_rows, paper)
    write_csv(output / "budget.csv", budget_rows)
    budget_columns = [("family", "method", "{}"), ("setting", "setting", "{}"),
                      ("evaluations", "evaluations", "{:.0f}"), ("seconds", "seconds", "{:.2f}"),
                      ("waveforms_per_second", "waveforms/s", "{:.1f}"), ("fit_error", "fit error", "{:.1f}"),
                      ("fit_error_raw", "vs raw", "{:.1f}")]
    (output / "budget.md").write_text(
        f"# Evaluation budget on {name}\n\n{len(data.batch)} waveforms, {threads} thread(s). "
        f"MDE at the paper's settings: fit error {paper:.1f}. Fastest within 5%: {fast['family']} "
        f"{fast['setting']} ({fast['fit_error']:.1f}, {fast['waveforms_per_second']:.1f} waveforms/s).\n\n"
        + markdown_table(budget_rows, budget_columns))
    plot_budget(output / "budget.png", budget_rows)
    return {"budget": budget_rows, "fast": fast, "paper_fit_error": paper}
