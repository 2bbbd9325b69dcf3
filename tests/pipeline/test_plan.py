"""A file's plan: one pass over its packet keys (every pulse in exactly one range), its system pulse measured once,
an unreadable file rejected with its reason; the plan kept as JSON for a resumed run."""

import json

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import PulseOverrides
from pipeline.layout import plan_path
from pipeline.outputs import InputNames
from pipeline.plan import FilePlan, InputToPlan, inputs_to_plan, plan_input, plan_inputs as _plan_inputs, planned_pulses


def plan_inputs(paths, config, points_per_range, limit=None):
    return _plan_inputs(paths, InputNames.of(paths), config, points_per_range, limit)


def test_plan_covers_every_pulse_once_and_measures_the_pulse_width(leica_dir):
    tasks, rejected = plan_inputs([str(leica_dir / "leica_a.las")], DecompositionConfig(), 400)
    assert rejected == []
    assert [(t.point_range.start, t.point_range.stop, t.point_range.n_pulses) for t in tasks] == \
        [(0, 400, 342), (400, 800, 310), (800, 1125, 272)]  # 342 + 310 + 272 = 924
    # --model auto gives the Leica sample echoes of its measured pulse, and the pulse width is that pulse's
    assert {round(t.source.pulse.fwhm_ps) for t in tasks} == {10337}
    assert {t.source.pulse.model for t in tasks} == {"system"}
    assert not tasks[0].source.adjusted_standard_gps_time  # the Leica sample stores GPS week time


def test_plan_rejects_an_unreadable_file_with_its_reason(tmp_path, leica_dir):
    bad = tmp_path / "broken.las"
    bad.write_bytes(b"LASF" + bytes(50))
    tasks, rejected = plan_inputs([str(bad), str(leica_dir / "leica_a.las")], DecompositionConfig(), 5000)
    assert len(tasks) == 1 and tasks[0].source.name == "leica_a.las"
    assert [(r.source_file, r.stage, r.pulse_id) for r in rejected] == [("broken.las", "open", -1)]
    assert "not a readable" in rejected[0].reason


def test_limit_caps_the_pulses_of_a_file(leica_dir):
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], DecompositionConfig(), 400, limit=500)
    assert [planned_pulses(t) for t in tasks] == [342, 158]


def test_the_inputs_to_plan_carry_their_names_and_what_the_user_gave_of_the_pulse(tmp_path, leica_dir):
    paths = [str(tmp_path / "a" / "leica_a.las"), str(tmp_path / "b" / "leica_a.las")]
    given = PulseOverrides(fwhm_ps=9000.0)
    inputs = inputs_to_plan(paths, InputNames.of(paths), None, given)
    assert [(i.name, i.stem, i.overrides) for i in inputs] == [("a/leica_a.las", "a__leica_a", given),
                                                               ("b/leica_a.las", "b__leica_a", given)]
    plan = plan_input(InputToPlan(str(leica_dir / "leica_a.las"), "leica_a.las", "leica_a", None, given),
                      DecompositionConfig(), 400)
    assert {(t.source.pulse.fwhm_ps, t.source.pulse.fwhm_source) for t in plan.tasks} == {(9000.0, "configured")}
    assert plan_path(tmp_path, "leica_a") == tmp_path / "parts" / "plans" / "leica_a.json"
    again = FilePlan.from_json(json.loads(json.dumps(plan.to_json())))  # as a resumed run reads it back
    assert again.tasks == plan.tasks and sum(planned_pulses(t) for t in again.tasks) == 924


def test_a_gedi_l1b_plans_its_l2a_algorithms(tmp_path):
    """Without an L2A granule beside it: L2A's six algorithms as data, algorithm 1 (or the one --l2a-algorithms
    names) for every shot; the noise's origin said."""
    import argparse

    import pytest

    from fwcore.metrics.algorithms import L2A_ALGORITHMS
    from fwcore.studies.gedi_granule import write_granule
    from pipeline.options import l2a_algorithms
    from pipeline.plan import file_metric_settings

    path = tmp_path / "GEDI01_B_written.h5"
    write_granule(path, 4, seed=1, beams=("BEAM0101",), samples=300, faults=False)
    planned, said = file_metric_settings(str(path))
    assert planned["default"] == 1 and planned["each_shot"] and not planned["every"]
    assert planned["algorithms"]["2"] == L2A_ALGORITHMS[2].to_dict() and planned["noise"].startswith("L1B")
    assert said == "GEDI L2A algorithm 1's (no L2A granule beside the L1B)"
    named, said = file_metric_settings(str(path), "5")
    assert named["default"] == 5 and not named["each_shot"] and "--l2a-algorithms" in said
    assert file_metric_settings(str(tmp_path / "x.las"), "all") == (None, "")
    assert l2a_algorithms(" ALL ") == "all" and l2a_algorithms("3") == "3"
    with pytest.raises(argparse.ArgumentTypeError, match="not '7'"):
        l2a_algorithms("7")
