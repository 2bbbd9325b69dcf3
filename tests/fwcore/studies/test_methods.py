"""The method comparison's parts on arrays and the Leica sample: runs of one method, point comparisons with the
system's returns (dead zone, omitted returns, heights among returns), the budget study's settings and the fast
preset's choice."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.records import WaveformBatch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import read_pulses
from fwcore.studies.methods import (ABOVE, BELOW, BETWEEN, NO_RETURN_NEAR, budget_settings, choose_fast_preset,
                                    compare_points, compare_to_system, height_among_returns, omitted_returns_found,
                                    run_method, system_dead_zone)


def test_a_method_run_is_its_decomposition_and_its_table_row():
    t = np.arange(80.0)
    one = 10 + 100 * np.exp(-0.5 * ((t - 30.0) / 2.0) ** 2)
    two = 10 + 80 * np.exp(-0.5 * ((t - 20.0) / 2.0) ** 2) + 60 * np.exp(-0.5 * ((t - 50.0) / 2.0) ** 2)
    batch = WaveformBatch(samples=np.concatenate([one, two]), valid=np.ones(160, bool), offsets=np.array([0, 80, 160]),
                          sample_spacing_ps=np.full(2, 1000.0), seeds=np.array([1, 2], np.uint64))
    run = run_method(batch, DecompositionConfig(optimizer="lm", model="gaussian"), nominal_pulse(4710.0))
    row = run.row()
    assert (row["optimizer"], row["model"], row["waveforms"], row["threads"]) == ("lm", "gaussian", 2, 1)
    assert row["echoes"] == 1.5 and row["echoes_kept"] == 1.5  # noiseless: one echo and two, each found
    assert row["r2"] > 0.999 and row["seconds"] > 0
    np.testing.assert_allclose(np.sort(run.result.position[run.result.echo_waveform == 1]), [20.0, 50.0], atol=1e-3)


def test_the_budget_settings_are_every_family_at_every_budget():
    settings = budget_settings(generations=(10, 20), lm_iterations=(3, 5))
    # per G: MDE at k x t = 1, 5, 10, DE generational and immediate, MDE-LM; then LM once per iteration count
    assert len(settings) == 2 * 6 + 2
    assert [s.label for s in settings if s.family == "de immediate"] == ["G 50", "G 100"]
    assert settings[-1].changes == dict(optimizer="lm", lm_iterations=5)
    assert all(s.changes.get("tol", 0.0) == 0.0 for s in settings)  # exactly its budget, no early stop


def test_compare_points_by_hand():
    system = np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0]], float)
    ours = np.array([[0.1, 0, 0], [10, 0.3, 0], [30, 0, 0], [40, 0, 0]], float)
    c = compare_points(system, ours, 0.5)
    assert (c.matched_system, c.missed_system, c.matched_decomposed, c.new_points) == (2, 1, 2, 2)
    assert c.mean_distance == pytest.approx(0.2)


def test_new_points_in_the_dead_zone_by_hand():
    # pulse 0: returns 4 m apart (the dead zone); pulse 1: one return
    system = np.array([[0, 0, 0], [0, 0, 4], [100, 0, 0]], float)
    system_pulse = np.array([0, 0, 1])
    # new points: 2 m from pulse 0's return (in its dead zone); 5 m from it (beyond); 1 m from pulse 1's
    # return but in pulse 0 (another pulse's return does not blind this one); 3 m from pulse 1's return
    ours = np.array([[0, 0, 0.1], [0, 0, -2], [0, 0, 9], [101, 0, 0], [100, 0, 3]], float)
    ours_pulse = np.array([0, 0, 0, 0, 1])
    c = compare_points(system, ours, 0.5, system_pulse, ours_pulse)
    assert c.dead_zone == pytest.approx(4.0)
    assert (c.new_points, c.new_in_dead_zone) == (4, 2)
    assert compare_points(system, ours, 0.5).new_in_dead_zone == 0  # without pulses: not counted


def test_leica_system_never_reports_two_returns_closer_than_its_dead_zone(leica_dir):
    pulses = read_pulses(leica_dir / "leica_a.las")
    # 201 consecutive pairs of returns in 182 multi-return pulses; the closest is 3.57 m apart
    assert system_dead_zone(pulses.return_xyz, pulses.return_pulse()) == pytest.approx(3.575, abs=0.001)
    assert system_dead_zone(pulses.return_xyz[:1], np.zeros(1, int)) == 0.0


def test_fast_preset_choice_is_the_fastest_within_tolerance():
    rows = [dict(fit_error=100.0, waveforms_per_second=50.0), dict(fit_error=104.0, waveforms_per_second=400.0),
            dict(fit_error=110.0, waveforms_per_second=900.0)]
    assert choose_fast_preset(rows, 100.0)["waveforms_per_second"] == 400.0
    with pytest.raises(ValueError, match="within the tolerance"):
        choose_fast_preset(rows, 50.0)
    families = {s.family for s in budget_settings()}
    assert families == {"mde k x t = 1", "mde k x t = 5", "mde k x t = 10", "de generational", "de immediate",
                        "mde-lm", "lm"}


def test_the_leica_sample_omits_returns_its_pulses_had(leica_dir):
    """Clipped to a plot, the sample keeps a pulse's returns inside it only: 16 pulses number returns the
    file does not hold (pulse 182 holds only return 3 of 3)."""
    pulses = read_pulses(leica_dir / "leica_a.las")
    omitted = pulses.omitted_returns()
    assert (omitted.sum(), int((omitted > 0).sum())) == (21, 16)
    lo, hi = pulses.return_offsets[182], pulses.return_offsets[183]
    assert pulses.return_number[lo:hi].tolist() == [3] and pulses.number_of_returns[lo:hi].tolist() == [3]
    assert omitted[182] == 2


def test_omitted_returns_are_found_only_where_they_must_lie(leica_dir):
    """Pulse 182 holds return 3 of 3 at 155 ns: its returns 1 and 2 lay before it, one point each."""
    pulses = read_pulses(leica_dir / "leica_a.las")
    t3 = float(pulses.return_location_ps[pulses.return_offsets[182]])
    rows = np.full(4, 182)
    found = omitted_returns_found(pulses, np.array([t3 - 40_000, t3 - 60_000, t3 - 20_000, t3 + 30_000]), rows)
    assert found.tolist() == [True, True, False, False]  # the two earliest; none after return 3
    assert not omitted_returns_found(pulses, np.array([1000.0]), np.array([0])).any()  # pulse 0 omits none


def test_compare_to_system_splits_the_new_points(leica_dir):
    """Every return itself matches; a point before pulse 182's held return stands for an omitted one, a point
    1 m beyond a return of pulse 0 is in the dead zone: the new points split between them."""
    pulses = read_pulses(leica_dir / "leica_a.las")
    lo = pulses.return_offsets[182]
    metres_per_ps = np.linalg.norm(pulses.direction[[182, 0]], axis=1)
    up_the_ray = pulses.direction[[182, 0]] / metres_per_ps[:, None]  # position = anchor + (L0 - t) direction
    xyz = np.vstack([pulses.return_xyz, pulses.return_xyz[lo] + 8.0 * up_the_ray[0],
                     pulses.return_xyz[0] + 1.0 * up_the_ray[1]])
    times = np.concatenate([pulses.return_location_ps, [pulses.return_location_ps[lo] - 8.0 / metres_per_ps[0],
                                                        pulses.return_location_ps[0] - 1.0 / metres_per_ps[1]]])
    rows = np.concatenate([pulses.return_pulse(), [182, 0]])
    c = compare_to_system(pulses, xyz, times, rows)
    assert (c.matched_system, c.new_points) == (1125, 2)
    assert (c.new_at_omitted_returns, c.new_in_dead_zone) == (1, 1)


def test_height_among_returns_by_hand():
    """Returns at 10 m and 30 m height around (0, 0), one at 20 m 8 m away: a point within 5 m horizontally is
    between, below or above the two near ones (0.5 m of tolerance); one 20 m away has none near."""
    system = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 30.0], [8.0, 0.0, 20.0]])
    points = np.array([[0.0, 1.0, 20.0], [0.0, 1.0, 9.6], [0.0, 1.0, 9.4], [0.0, 1.0, 31.0], [20.0, 0.0, 20.0]])
    assert height_among_returns(points, system).tolist() == [BETWEEN, BETWEEN, BELOW, ABOVE, NO_RETURN_NEAR]
    assert height_among_returns(points, system, radius=10.0)[4] == NO_RETURN_NEAR  # 12 m from the nearest
    assert height_among_returns(points[:1], system[2:], radius=10.0).tolist() == [BETWEEN]  # 20 m exactly
