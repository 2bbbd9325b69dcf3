"""Planning on arrays and files; the stages on the DirectRunner with TestPipeline + assert_that."""

import shutil

import apache_beam as beam
from apache_beam.testing.test_pipeline import TestPipeline
from apache_beam.testing.util import assert_that, equal_to

from fwcore.config import DecompositionConfig
from pipeline.outputs import InputNames
from pipeline.plan import plan_inputs as _plan_inputs, planned_pulses
from pipeline.records import DecomposedRange, Rejection
from pipeline.transforms import Decompose, ReadRange


def plan_inputs(paths, config, points_per_range, limit=None):
    return _plan_inputs(paths, InputNames.of(paths), config, points_per_range, limit)


def test_plan_covers_every_pulse_once_and_measures_the_pulse_width(leica_dir):
    tasks, rejected = plan_inputs([str(leica_dir / "leica_a.las")], DecompositionConfig(), 400)
    assert rejected == []
    assert [(t.point_range.start, t.point_range.stop, t.point_range.n_pulses) for t in tasks] == \
        [(0, 400, 342), (400, 800, 310), (800, 1125, 272)]  # 342 + 310 + 272 = 924
    assert {round(t.source.system_pulse_fwhm_ps) for t in tasks} == {10980}
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


def test_read_and_decompose_count_every_pulse(tmp_path, leica_dir):
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], config, 600)
    with TestPipeline() as p:
        results = (p | beam.Create(tasks) | beam.ParDo(ReadRange(str(tmp_path)))
                   | beam.ParDo(Decompose(str(tmp_path), config)))
        counts = results | beam.Map(lambda r: int((r.result.status == 0).sum()) if isinstance(r, DecomposedRange)
                                    else 0)
        assert_that(counts | beam.CombineGlobally(sum), equal_to([924]))


def test_rejections_pass_through_every_stage(tmp_path):
    rejected = Rejection("a.las", "a", 0, 7, "read", "packet beyond the end")
    with TestPipeline() as p:
        out = (p | beam.Create([rejected]) | beam.ParDo(ReadRange(str(tmp_path)))
               | beam.ParDo(Decompose(str(tmp_path), DecompositionConfig())))
        assert_that(out, equal_to([rejected]))


def test_a_failing_range_becomes_a_rejection_with_its_reason(tmp_path, leica_dir):
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / f"gone{suffix}")
    tasks, _ = plan_inputs([str(tmp_path / "gone.las")], DecompositionConfig(), 600)
    (tmp_path / "gone.wdp").unlink()  # after planning: reading the range fails
    with TestPipeline() as p:
        out = p | beam.Create(tasks) | beam.ParDo(ReadRange(str(tmp_path / "out")))
        assert_that(out | beam.Map(lambda r: (type(r).__name__, r.source_file, r.pulse_id, r.stage,
                                              r.reason.split(":")[0], "gone.wdp" in r.reason)),
                    equal_to([("Rejection", "gone.las", -1, "read", "points 0-600 (500 pulses)", True),
                              ("Rejection", "gone.las", -1, "read", "points 600-1125 (424 pulses)", True)]))
