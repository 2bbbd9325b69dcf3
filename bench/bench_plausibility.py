"""Plausibility benchmark (issue 50, item 4): kept echoes far under the ground, before and after the
under_ground rule (fwcore.plausibility), on the Leica sample and the simulated forest scenes.

    python bench/bench_plausibility.py

- Leica sample, the default preset as `fwl run` measures the file: kept echoes more than 5 m under the flight
  line's lowest return (the lowest system return of the file), under the lowest system return within 5 m
  horizontally, and under their own pulse's lowest return; the share of the system's returns with a kept echo
  within 0.5 m (recall); the echoes the rule filters.
- The default simulated flight (`fwl simulate --seed 7`): the true echoes the rule filters.
- The simulated forest scenes (fwcore.studies.forest, `fwl simulate --scene forest`): the true ground echoes the
  engine keeps, and how many of them the rule filters (it must be none), with the echoes it filters.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import read_pulses
from fwcore.plausibility import UNDER_GROUND_M, under_ground
from fwcore.pulses import echo_positions, echo_times_ps, pulse_waveforms
from fwcore.studies.evaluate import match_echoes
from fwcore.studies.forest import FOREST_SAMPLES, ForestConfig, forest_flight_scene, simulate_forest_chunks, terrain
from fwcore.studies.methods import compare_to_system
from fwcore.studies.simulate import SensorConfig, _concatenate, simulate_flight

LEICA = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"


def under_counts(pulses, result, xyz, kept) -> tuple[int, int, int]:
    """Kept echoes more than UNDER_GROUND_M under the flight line's lowest return, the lowest return within 5 m
    horizontally, their own pulse's lowest return."""
    returns = pulses.return_xyz
    z = xyz[kept, 2]
    line = int((z < returns[:, 2].min() - UNDER_GROUND_M).sum())
    near = cKDTree(returns[:, :2]).query_ball_point(xyz[kept, :2], 5.0)
    local = np.array([returns[n, 2].min() if n else np.inf for n in near])
    own = np.full(len(pulses), np.inf)
    np.minimum.at(own, pulses.return_pulse(), returns[:, 2])
    own_under = z < own[result.echo_waveform[kept]] - UNDER_GROUND_M
    return line, int((z < local - UNDER_GROUND_M).sum()), int(own_under.sum())


def leica_rows(config: DecompositionConfig = DecompositionConfig(), label: str = "default preset") -> None:
    pulses = read_pulses(LEICA)
    system = file_system_pulse(LEICA, pulses.return_xyz.shape[0], config)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, system, threads=1)
    xyz = echo_positions(pulses, result, system.range_offset_ps)
    times = echo_times_ps(pulses, result, system.range_offset_ps)
    mark = under_ground(pulses, result, xyz)
    print(f"Leica sample ({len(pulses)} pulses, {pulses.return_xyz.shape[0]} system returns), {label}")
    print(f"{'':7} {'kept':>6} {'> 5 m under line':>16} {'under local':>11} {'under own':>9} {'recall':>7}")
    for when, kept in (("before", result.reject == 0), ("after", (result.reject == 0) & ~mark)):
        line, local, own = under_counts(pulses, result, xyz, kept)
        points = compare_to_system(pulses, xyz[kept], times[kept], result.echo_waveform[kept])
        print(f"{when:7} {kept.sum():6d} {line:16d} {local:11d} {own:9d} "
              f"{points.matched_system / pulses.return_xyz.shape[0]:7.4f}")
    print(f"filtered under_ground: {mark.sum()}")


def forest_rows(n_pulses: int = 10_000) -> None:
    sensor = SensorConfig(samples_per_packet=FOREST_SAMPLES)
    print(f"Simulated forest scenes ({n_pulses} pulses, `fwl simulate --scene forest`): true ground echoes kept, "
          "those the rule filters (must be 0); kept echoes > 5 m under the true terrain before / after; filtered")
    for seed in (1, 2, 3):
        chunks = list(simulate_forest_chunks(n_pulses, sensor, forest_flight_scene(), ForestConfig(), seed))
        flight = chunks[0] if len(chunks) == 1 else _concatenate(chunks)
        pulses, truth = flight.pulses, flight.truth
        pulse = nominal_pulse(sensor.pulse_fwhm_ps)
        result = decompose_batch(pulse_waveforms(pulses, 0), DecompositionConfig(), pulse, threads=1)
        xyz = echo_positions(pulses, result, 0.0)
        mark = under_ground(pulses, result, xyz)
        times = result.position * pulses.sample_spacing_ps[result.echo_waveform]
        t_idx, f_idx = match_echoes(truth["pulse_id"], truth["time_ps"], pulses.pulse_id[result.echo_waveform],
                                    times, 1000.0)
        ground = f_idx[(truth["surface"][t_idx] == "ground") & (result.reject[f_idx] == 0)]
        under = xyz[:, 2] < terrain(xyz[:, 0], xyz[:, 1], ForestConfig()) - UNDER_GROUND_M
        kept = result.reject == 0
        print(f"  seed {seed}: {ground.size} true ground echoes kept, {mark[ground].sum()} filtered; "
              f"{(kept & under).sum()} / {(kept & under & ~mark).sum()} under the terrain; {mark.sum()} filtered")


def flight_rows(n_pulses: int = 10_000, seed: int = 7) -> None:
    """The default simulated flight (`fwl simulate --seed 7`): true echoes the rule filters, echoes it filters."""
    sensor = SensorConfig()
    flight = simulate_flight(n_pulses, sensor, seed=seed)
    pulses, truth = flight.pulses, flight.truth
    result = decompose_batch(pulse_waveforms(pulses, 0), DecompositionConfig(), nominal_pulse(sensor.pulse_fwhm_ps),
                             threads=1)
    mark = under_ground(pulses, result, echo_positions(pulses, result, 0.0))
    times = result.position * pulses.sample_spacing_ps[result.echo_waveform]
    t_idx, f_idx = match_echoes(truth["pulse_id"], truth["time_ps"], pulses.pulse_id[result.echo_waveform],
                                times, 1000.0)
    true_kept = f_idx[result.reject[f_idx] == 0]
    print(f"Simulated flight ({n_pulses} pulses, seed {seed}): {true_kept.size} true echoes kept, "
          f"{mark[true_kept].sum()} of them filtered; {mark.sum()} echoes filtered")


if __name__ == "__main__":
    leica_rows()
    leica_rows(DecompositionConfig(min_snr=2.0), "the filter's floor at 2 sigma (the default before 2026-12-05)")
    forest_rows()
    flight_rows()
