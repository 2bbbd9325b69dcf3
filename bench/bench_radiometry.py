"""Radiometry benchmark: accuracy on a simulated flight, coverage and range normalisation on RIEGL, and its cost.

    python bench/bench_radiometry.py [--sections simulated,riegl,cost] [--pulses 40000] [--workdir DIR]

simulated  `fwl simulate --radiometry` (16-bit, reflectances 0.05-0.6, a flight climbing 300 m so that ranges
           vary ~1.7x, incidence from terrain and scan angle), then `fwl run SIM.las --trajectory
           SIM.trajectory.csv --calibration-reference SIM.calibration.json --beam-divergence-mrad 0.5`
           (default preset). Over the extended true echoes matched by a kept echo: median and 90th percentile
           of |rho / rho_true - 1|; over every matched echo: median |range error|. Targets 3%, 10%, 2 cm.
           Over every kept echo: the share with a reflectance (>= 50%) and how many exceed 1.5 (none).
riegl      `fwl run` on the bundled RIEGL Q680 PulseWaves file (ranges from its optical centre, beam divergence
           from its scanner record): the share of kept echoes with a range (target >= 99%); over single returns
           with a local plane at most 20 deg off the beam (open, flat ground and roofs), the spread across range
           of the raw amplitude and of the backscatter coefficient: the bin medians' range over five range bins,
           over the overall median, and the slope of log(value) against log(range) (amplitude: -2 for
           extended targets; gamma: 0).
cost       The simulated flight through `fwl run --formats parquet,las` with and without radiometry (the
           trajectory and a calibration constant, against no trajectory: a LAS without one has none), run
           alternately twice each: pulses/s over the wall time (within this machine's noise); and in one
           process, the radiometry's share of the time a range's stages take. Target: radiometry costs <= 10%.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds

ROOT = Path(__file__).resolve().parents[1]
RIEGL = ROOT / "examples" / "data" / "pulsewaves" / "riegl_example3.pls"
FWL = [sys.executable, "-m", "pipeline.cli"]


def fwl(*args: str) -> float:
    start = time.perf_counter()
    subprocess.run([*FWL, *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def simulate(workdir: Path, pulses: int) -> Path:
    las = workdir / "sim" / "SIM.las"
    if not las.exists():
        las.parent.mkdir(parents=True, exist_ok=True)
        fwl("simulate", "--radiometry", "--pulses", str(pulses), "--seed", "11", "--output", str(las))
    return las


def simulated(workdir: Path, pulses: int) -> None:
    from fwcore.studies.evaluate import evaluate_radiometry

    las = simulate(workdir, pulses)
    out = workdir / "simulated"
    seconds = fwl("run", str(las), "--output", str(out), "--formats", "parquet",
                  "--trajectory", str(las.with_name("SIM.trajectory.csv")),
                  "--calibration-reference", str(las.with_name("SIM.calibration.json")), "--beam-divergence-mrad", "0.5")
    r = evaluate_radiometry(out, las.with_name("SIM.truth.parquet"))
    calibration = json.loads((out / "run.json").read_text())["radiometry"]["calibration"]
    truth = ds.dataset(str(las.with_name("SIM.truth.parquet"))).to_table(columns=["range_m"]).column(0).to_numpy()
    print(f"simulated: {pulses} pulses, ranges {truth.min():.0f}-{truth.max():.0f} m ({truth.max() / truth.min():.2f}x), "
          f"run {seconds:.0f} s; C_cal from {calibration['n']} single returns, spread {100 * calibration['spread']:.1f}%")
    print(f"  extended echoes {r['extended']} (with a local plane {100 * r['extended_with_plane']:.0f}%): "
          f"|rho/rho_true - 1| median {100 * r['reflectance_error_median']:.2f}% (target <= 3%), "
          f"p90 {100 * r['reflectance_error_p90']:.2f}% (target <= 10%)")
    print(f"  matched echoes {r['matched']}: |range error| median {r['range_error_median_cm']:.2f} cm "
          f"(target <= 2 cm), bias {r['range_bias_cm']:+.2f} cm; with a range {100 * r['with_range']:.1f}%")
    print(f"  kept echoes {r['kept']}: with a reflectance {100 * r['kept_with_reflectance']:.1f}% (target >= 50%), "
          f"largest {r['reflectance_max']:.3f}, above 1.5: {r['reflectance_above_1_5']} (target 0)", flush=True)


def _spread(values: np.ndarray, range_m: np.ndarray, bins: int = 5) -> tuple[float, float]:
    edges = np.quantile(range_m, np.linspace(0, 1, bins + 1))
    which = np.clip(np.searchsorted(edges, range_m, side="right") - 1, 0, bins - 1)
    medians = np.array([np.median(values[which == b]) for b in range(bins)])
    slope = np.polyfit(np.log(range_m), np.log(values), 1)[0]
    return float(np.ptp(medians) / np.median(values)), float(slope)


def riegl(workdir: Path) -> None:
    out = workdir / "riegl"
    seconds = fwl("run", str(RIEGL), "--output", str(out), "--formats", "parquet")
    echoes = ds.dataset(str(out / "echoes")).to_table(
        columns=["pulse_id", "channel", "kept", "echo_count", "amplitude", "range_m", "incidence_deg",
                 "backscatter_coefficient"]).to_pandas()
    kept = echoes[echoes.kept]
    with_range = kept.range_m.notna().mean()
    per_pulse = kept.groupby(["pulse_id", "channel"]).size()
    single = kept.set_index(["pulse_id", "channel"]).loc[per_pulse[per_pulse == 1].index].reset_index()
    flat = single[(single.incidence_deg < 20) & single.backscatter_coefficient.notna()]
    r = flat.range_m.to_numpy()
    amplitude, amplitude_slope = _spread(flat.amplitude.to_numpy(), r)
    gamma, gamma_slope = _spread(flat.backscatter_coefficient.to_numpy(), r)
    print(f"riegl: {len(kept)} kept echoes, {100 * with_range:.2f}% with a range (target >= 99%), "
          f"ranges {kept.range_m.min():.0f}-{kept.range_m.max():.0f} m; run {seconds:.0f} s")
    print(f"  {len(flat)} single returns on planes within 20 deg of the beam: spread across five range bins "
          f"amplitude {100 * amplitude:.1f}% (log-log slope {amplitude_slope:+.2f}), backscatter coefficient "
          f"{100 * gamma:.1f}% (slope {gamma_slope:+.2f}): gamma spreads less: {gamma < amplitude}", flush=True)


def cost(workdir: Path, pulses: int) -> None:
    las = simulate(workdir, pulses)
    with_radiometry = ["--trajectory", str(las.with_name("SIM.trajectory.csv")), "--calibration-constant", "1e-16",
                       "--beam-divergence-mrad", "0.5"]
    times = {"without": [], "with": []}
    for _ in range(2):
        for label, extra in (("without", []), ("with", with_radiometry)):
            out = workdir / f"cost-{label}"
            times[label].append(fwl("run", str(las), "--output", str(out), "--formats", "parquet,las", *extra))
    rate = {k: pulses / min(v) for k, v in times.items()}
    print(f"cost: {pulses} pulses, parquet+las, DirectRunner 2 workers, best of 2: without radiometry "
          f"{rate['without']:.0f} pulses/s, with {rate['with']:.0f} pulses/s: costs "
          f"{100 * (1 - rate['with'] / rate['without']):.1f}% (target <= 10%)", flush=True)
    share = stage_share(las, with_radiometry)
    print(f"  in one process, over {share['pulses']} pulses: radiometry {share['radiometry']:.2f} s of "
          f"{share['total']:.2f} s a range's stages take (read, decompose, geolocate, tables): "
          f"{100 * share['radiometry'] / share['total']:.1f}% (target <= 10%)", flush=True)


def stage_share(las: Path, flags: list[str], ranges: int = 6) -> dict:
    """The time of a range's stages in this process, the radiometry's apart (the same functions as the
    pipeline's stages call), over the first `ranges` ranges of the file."""
    from fwcore.engine.config import DecompositionConfig
    from fwcore.engine.decompose import decompose_batch
    from fwcore.radiometry.flight import file_radiometry, range_radiometry
    from fwcore.io import read_pulses
    from fwcore.pulses import decomposed_echoes, echo_positions, pulse_waveforms
    from fwcore.radiometry.equations import RadiometryConfig
    from pipeline.outputs import InputNames
    from pipeline.plan import plan_inputs
    from pipeline.tables import pulse_tables

    radiometry = RadiometryConfig(trajectory=flags[1], calibration_constant=float(flags[3]),
                                  beam_divergence_mrad=float(flags[5]))
    tasks, _ = plan_inputs([str(las)], InputNames.of([str(las)]), DecompositionConfig(), 5000)
    clock = {"read": 0.0, "decompose": 0.0, "radiometry": 0.0, "geolocate": 0.0}
    n = 0
    for task in tasks[:ranges]:
        s = task.source
        config = DecompositionConfig()
        t0 = time.perf_counter()
        pulses = read_pulses(task.point_range)
        t1 = time.perf_counter()
        result = decompose_batch(pulse_waveforms(pulses, config.seed), config, s.pulse, threads=1)
        t2 = time.perf_counter()
        file = file_radiometry(s.path, s.adjusted_standard_gps_time, radiometry)
        xyz = echo_positions(pulses, result, s.pulse.range_offset_ps)
        t3 = time.perf_counter()
        columns = range_radiometry(pulses, result, xyz, s.pulse.range_offset_ps, file, radiometry)
        t4 = time.perf_counter()
        pulse_tables(s.name, pulses, result, config, s.pulse, xyz, result.status == 0, columns)
        decomposed_echoes(pulses, result, xyz)
        t5 = time.perf_counter()
        clock["read"] += t1 - t0
        clock["decompose"] += t2 - t1
        clock["radiometry"] += t4 - t3
        clock["geolocate"] += (t3 - t2) + (t5 - t4)
        n += len(pulses)
    return {**clock, "total": sum(clock.values()), "pulses": n}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default="simulated,riegl,cost")
    parser.add_argument("--pulses", type=int, default=40000)
    parser.add_argument("--workdir")
    args = parser.parse_args()
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-bench-radiometry-"))
    print(f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {os.getloadavg()[0]:.1f}, "
          f"workdir {workdir}", flush=True)
    sections = args.sections.split(",")
    if "simulated" in sections:
        simulated(workdir, args.pulses)
    if "riegl" in sections:
        if RIEGL.exists():
            riegl(workdir)
        else:
            print(f"riegl: {RIEGL} is not here: skipped")
    if "cost" in sections:
        cost(workdir, args.pulses)


if __name__ == "__main__":
    main()
