"""The method comparison: every optimizer on the same waveforms, their point clouds, the evaluation budget.

Pure functions over a WaveformBatch (and, for LAS input, its PulseBatch);
`fwl compare` (fwcore.studies.comparison) writes the tables and figures. Every
optimizer sees the same initial estimate, bounds and fit error; the
population methods of the method's comparison (GA, PSO, DE) run at its
100 x 100, MDE at the paper's 60 x 80.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Iterable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from fwcore.engine.config import DecompositionConfig, Model, Optimizer
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import SystemPulse
from fwcore.io.records import PulseBatch
from fwcore.engine.records import BatchDecomposition, WaveformBatch

# The comparison's settings per optimizer (on top of the caller's configuration): the method's fixed
# budgets, every generation run (tol 0), as its Table 1 was measured.
COMPARISON_SETTINGS: dict[Optimizer, dict] = {
    Optimizer.GA: dict(population=100, generations=100),
    Optimizer.PSO: dict(population=100, generations=100),
    Optimizer.DE: dict(population=100, generations=100, tol=0.0, atol=0.0),
    Optimizer.MDE: dict(population=60, generations=80, tol=0.0, atol=0.0),
    Optimizer.MDE_LM: dict(population=60, generations=80, tol=0.0, atol=0.0),
    Optimizer.LM_MDE: dict(population=60, generations=80, tol=0.0, atol=0.0),
}


@dataclasses.dataclass(frozen=True)
class MethodRun:
    """One optimizer and model over the batch: its configuration, result and wall time."""

    label: str
    config: DecompositionConfig
    result: BatchDecomposition
    seconds: float
    threads: int

    def row(self) -> dict:
        """The comparison table's row (the method's Table 1 plus our columns)."""
        r = self.result
        ok = r.status == 0
        n = int(ok.sum())
        counts = np.diff(r.echo_offsets)
        kept = np.bincount(r.echo_waveform[r.reject == 0], minlength=len(r))
        return {
            "optimizer": self.label, "model": self.config.model.value, "waveforms": n,
            "fit_error": float(r.fit_error[ok].mean()), "fit_error_raw": float(r.fit_error_raw[ok].mean()),
            "rmse": float(r.rmse[ok].mean()), "r2": float(r.r2[ok].mean()),
            "echoes": float(counts[ok].mean()), "echoes_kept": float(kept[ok].mean()),
            "evaluations": float(r.nfev[ok].mean()), "seconds": self.seconds,
            "waveforms_per_second": n / self.seconds if self.seconds > 0 else float("inf"),
            "threads": self.threads,
        }


def _warm_up(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse) -> None:
    """Compile outside the timed call (numba compiles on first use and caches)."""
    first = WaveformBatch(batch.samples[:batch.offsets[1]], batch.valid[:batch.offsets[1]], batch.offsets[:2],
                          batch.sample_spacing_ps[:1], batch.seeds[:1])
    decompose_batch(first, config, pulse, threads=1)


def run_method(batch: WaveformBatch, config: DecompositionConfig, pulse: SystemPulse, label: str | None = None,
               threads: int = 1) -> MethodRun:
    """Decompose the batch with one configuration and the waveforms' system pulse, timed after compilation."""
    _warm_up(batch, config, pulse)
    start = time.perf_counter()
    result = decompose_batch(batch, config, pulse, threads=threads)
    return MethodRun(label or config.optimizer.value, config, result, time.perf_counter() - start, threads)


def compare_methods(batch: WaveformBatch, base: DecompositionConfig, pulse: SystemPulse,
                    optimizers: Sequence[Optimizer], models: Sequence[Model], threads: int = 1) -> list[MethodRun]:
    """Every optimizer x model on the batch, each at the comparison's settings."""
    runs = []
    for model in models:
        for optimizer in optimizers:
            config = base.replace(optimizer=optimizer, model=model, **COMPARISON_SETTINGS.get(optimizer, {}))
            runs.append(run_method(batch, config, pulse, threads=threads))
    return runs


@dataclasses.dataclass(frozen=True)
class PointComparison:
    """Decomposed points (kept echoes) against the system's own returns, within `distance` metres."""

    distance: float
    system_points: int
    decomposed_points: int
    matched_system: int  # system points with a decomposed point within the distance
    missed_system: int  # the rest: matched_system + missed_system = system_points
    matched_decomposed: int  # decomposed points with a system point within the distance
    new_points: int  # the rest: matched_decomposed + new_points = decomposed_points
    mean_distance: float  # over matched system points, to their nearest decomposed point
    median_distance: float
    p95_distance: float
    dead_zone: float  # the system's smallest separation of two returns of one pulse (m; 0 when unknown)
    new_in_dead_zone: int  # new points within dead_zone of a return of their own pulse (<= new_points)
    # new points standing for returns the system reported and the file omits (compare_to_system, which
    # then counts new_in_dead_zone among the others: omitted + in dead zone <= new points)
    new_at_omitted_returns: int = 0

    @property
    def extra_points(self) -> int:
        """New points that stand for no return the system reported (omitted ones do)."""
        return self.new_points - self.new_at_omitted_returns

    @property
    def extra_beyond_dead_zone(self) -> int:
        """Extra points where the system could have reported a return: outside its dead zone."""
        return self.extra_points - self.new_in_dead_zone

    def row(self) -> dict:
        return dataclasses.asdict(self)


def system_dead_zone(system_xyz: np.ndarray, system_pulse: np.ndarray) -> float:
    """The smallest distance (m) between two consecutive returns of one pulse: a discrete-return
    detector is blind for a while after it triggers, so it never reports two returns closer than
    this (Leica sample: 3.57 m). 0 when no pulse has two returns."""
    system_xyz = np.asarray(system_xyz, dtype=float).reshape(-1, 3)
    same = np.asarray(system_pulse)[1:] == np.asarray(system_pulse)[:-1]
    if not same.any():
        return 0.0
    return float(np.linalg.norm(np.diff(system_xyz, axis=0)[same], axis=1).min())


def _nearest_in_own_pulse(points: np.ndarray, pulse: np.ndarray, others: np.ndarray,
                          other_pulse: np.ndarray) -> np.ndarray:
    """For each point, the distance to the nearest of `others` with the same pulse (inf when none)."""
    distance = np.full(len(points), np.inf)
    order = np.argsort(other_pulse, kind="stable")
    sorted_pulse = np.asarray(other_pulse)[order]
    lo = np.searchsorted(sorted_pulse, pulse, side="left")
    hi = np.searchsorted(sorted_pulse, pulse, side="right")
    # a pulse holds a handful of returns: a loop over the widest pulse, vectorised over the points
    for step in range(int((hi - lo).max()) if len(points) else 0):
        has = lo + step < hi
        other = others[order[lo[has] + step]]
        distance[has] = np.minimum(distance[has], np.linalg.norm(points[has] - other, axis=1))
    return distance


def _in_dead_zone(points: np.ndarray, pulse: np.ndarray, system_xyz: np.ndarray,
                  system_pulse: np.ndarray) -> tuple[float, int]:
    """(the system's dead zone, how many of `points` lie within it of a return of their own pulse)."""
    dead_zone = system_dead_zone(system_xyz, system_pulse)
    own = _nearest_in_own_pulse(points, pulse, system_xyz, np.asarray(system_pulse))
    return dead_zone, int((own < dead_zone).sum())


def compare_points(system_xyz: np.ndarray, decomposed_xyz: np.ndarray, distance: float = 0.5,
                   system_pulse: np.ndarray | None = None,
                   decomposed_pulse: np.ndarray | None = None) -> PointComparison:
    """Nearest-neighbour matching both ways between the system's returns and the decomposed points.
    With each point's pulse, the new points are also counted where the system could not have
    reported them: within its dead zone of one of the pulse's returns."""
    system_xyz = np.asarray(system_xyz, dtype=float).reshape(-1, 3)
    decomposed_xyz = np.asarray(decomposed_xyz, dtype=float).reshape(-1, 3)
    if len(system_xyz) and len(decomposed_xyz):
        to_ours, _ = cKDTree(decomposed_xyz).query(system_xyz)
        to_system, _ = cKDTree(system_xyz).query(decomposed_xyz)
    else:
        to_ours = np.full(len(system_xyz), np.inf)
        to_system = np.full(len(decomposed_xyz), np.inf)
    matched = to_ours <= distance
    close = to_ours[matched]
    stat = (lambda f: float(f(close))) if close.size else (lambda f: float("nan"))
    new = to_system > distance
    dead_zone, in_dead_zone = 0.0, 0
    if system_pulse is not None and decomposed_pulse is not None:
        dead_zone, in_dead_zone = _in_dead_zone(decomposed_xyz[new], np.asarray(decomposed_pulse)[new],
                                                system_xyz, system_pulse)
    return PointComparison(
        distance=distance, system_points=len(system_xyz), decomposed_points=len(decomposed_xyz),
        matched_system=int(matched.sum()), missed_system=int((~matched).sum()),
        matched_decomposed=int((~new).sum()), new_points=int(new.sum()),
        mean_distance=stat(np.mean), median_distance=stat(np.median),
        p95_distance=stat(lambda d: np.percentile(d, 95)), dead_zone=dead_zone, new_in_dead_zone=in_dead_zone)


def omitted_returns_found(pulses: PulseBatch, time_ps: np.ndarray, pulse: np.ndarray) -> np.ndarray:
    """Which of the points (`time_ps` within the packet, on the system's range reference; `pulse`, their
    rows) stand for a return the system reported but the file omits (PulseBatch.omitted_returns): one
    of their pulse's points after its held returns numbered below the omitted one and before those
    numbered above, each point standing for one omitted return at most."""
    time_ps, pulse = np.asarray(time_ps, dtype=float), np.asarray(pulse)
    found = np.zeros(time_ps.size, dtype=bool)
    for i in np.flatnonzero(pulses.omitted_returns()):
        lo, hi = pulses.return_offsets[i], pulses.return_offsets[i + 1]
        numbers = pulses.return_number[lo:hi].astype(int)
        times = pulses.return_location_ps[lo:hi].astype(float)
        mine = np.flatnonzero(pulse == i)
        mine = mine[np.argsort(time_ps[mine], kind="stable")]
        # in return-number order the windows only move later, so the earliest free point is the best choice
        for j in sorted(set(range(1, int(pulses.number_of_returns[lo:hi].max()) + 1)) - set(numbers.tolist())):
            after = times[numbers < j].max() if (numbers < j).any() else -np.inf
            before = times[numbers > j].min() if (numbers > j).any() else np.inf
            free = mine[~found[mine] & (time_ps[mine] > after) & (time_ps[mine] < before)]
            if free.size:
                found[free[0]] = True
    return found


def extra_points(pulses: PulseBatch, xyz: np.ndarray, time_ps: np.ndarray, pulse: np.ndarray,
                 distance: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(new, at omitted returns): the decomposed points (`xyz`; `time_ps`, their times within the packet on
    the system's range reference; `pulse`, their rows) farther than `distance` from every return of the
    file, and among those the ones that stand for returns the system reported but the file omits."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    if not len(pulses.return_xyz) or not len(xyz):
        return np.ones(len(xyz), dtype=bool), np.zeros(len(xyz), dtype=bool)
    to_system, _ = cKDTree(pulses.return_xyz).query(xyz)
    new = to_system > distance
    omitted = np.zeros(len(xyz), dtype=bool)
    omitted[new] = omitted_returns_found(pulses, np.asarray(time_ps, dtype=float)[new], np.asarray(pulse)[new])
    return new, omitted


def compare_to_system(pulses: PulseBatch, xyz: np.ndarray, time_ps: np.ndarray, pulse: np.ndarray,
                      distance: float = 0.5) -> PointComparison:
    """compare_points of decomposed points (as extra_points) against the file's own returns. The new points
    split into those standing for returns the system reported but the file omits, those in its dead zone,
    and the rest."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    pulse = np.asarray(pulse)
    points = compare_points(pulses.return_xyz, xyz, distance)
    new, omitted = extra_points(pulses, xyz, time_ps, pulse, distance)
    rest = new & ~omitted
    dead_zone, in_dead_zone = _in_dead_zone(xyz[rest], pulse[rest], pulses.return_xyz, pulses.return_pulse())
    return dataclasses.replace(points, dead_zone=dead_zone, new_in_dead_zone=in_dead_zone,
                               new_at_omitted_returns=int(omitted.sum()))


BELOW, BETWEEN, ABOVE, NO_RETURN_NEAR = -1, 0, 1, 2


def height_among_returns(xyz: np.ndarray, system_xyz: np.ndarray, radius: float = 5.0,
                         tolerance: float = 0.5) -> np.ndarray:
    """Where each point lies against the system's returns within `radius` m of it horizontally: BELOW the
    lowest of them (by more than `tolerance`), ABOVE the highest, BETWEEN, or NO_RETURN_NEAR. A surface the
    system did not report lies between (the canopy, the understory, the ground); an echo fitted to noise
    anywhere in a packet mostly lies below the ground, where most of a packet's span is."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    system_xyz = np.asarray(system_xyz, dtype=float).reshape(-1, 3)
    where = np.full(len(xyz), NO_RETURN_NEAR, dtype=np.int8)
    if not len(xyz) or not len(system_xyz):
        return where
    for i, near in enumerate(cKDTree(system_xyz[:, :2]).query_ball_point(xyz[:, :2], radius)):
        if near:
            z = system_xyz[near, 2]
            where[i] = (BELOW if xyz[i, 2] < z.min() - tolerance else ABOVE if xyz[i, 2] > z.max() + tolerance
                        else BETWEEN)
    return where


# ---------------------------------------------------------------- the evaluation budget

@dataclasses.dataclass(frozen=True)
class BudgetSetting:
    """One point of the budget study: a label and the configuration changes it makes."""

    family: str
    label: str
    changes: dict


def budget_settings(generations: Iterable[int] = (10, 20, 40, 80),
                    lm_iterations: Iterable[int] = (3, 5, 10, 20, 50)) -> list[BudgetSetting]:
    """MDE with k x t = 1, 5, 10; DE generational and immediate; LM; MDE + LM polish; every
    population method for exactly its G (tol 0), so that the budget is the setting."""
    out = []
    for g in generations:
        for k in (1, 5, 10):
            out.append(BudgetSetting(f"mde k x t = {k}", f"G {g}",
                                     dict(optimizer="mde", chaos_seeds=1, chaos_iterations=k, generations=g, tol=0.0)))
        for immediate in (False, True):
            family = "de immediate" if immediate else "de generational"
            out.append(BudgetSetting(family, f"G {g * 5}", dict(optimizer="de", population=60, generations=g * 5,
                                                                 tol=0.0, immediate=immediate)))
        out.append(BudgetSetting("mde-lm", f"G {g}", dict(optimizer="mde-lm", generations=g, tol=0.0)))
    for n in lm_iterations:
        out.append(BudgetSetting("lm", f"{n} iterations", dict(optimizer="lm", lm_iterations=n)))
    return out


def budget_study(batch: WaveformBatch, base: DecompositionConfig, pulse: SystemPulse,
                 settings: Sequence[BudgetSetting], threads: int = 1) -> list[dict]:
    """Mean fit error against model evaluations and seconds for each setting."""
    rows = []
    for s in settings:
        run = run_method(batch, base.replace(**s.changes), pulse, label=s.family, threads=threads)
        row = run.row()
        rows.append({"family": s.family, "setting": s.label, **{k: row[k] for k in (
            "evaluations", "seconds", "waveforms_per_second", "fit_error", "fit_error_raw", "rmse", "r2")},
            "threads": threads})
    return rows


def choose_fast_preset(rows: Sequence[dict], reference_error: float, tolerance: float = 0.05) -> dict:
    """The budget row with the highest throughput whose fit error is within `tolerance` of the reference."""
    eligible = [r for r in rows if r["fit_error"] <= (1.0 + tolerance) * reference_error]
    if not eligible:
        raise ValueError("no setting of the budget study keeps the fit error within the tolerance")
    return max(eligible, key=lambda r: r["waveforms_per_second"])
