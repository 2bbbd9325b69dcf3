"""Transform tests on the DirectRunner with TestPipeline + assert_that."""

import apache_beam as beam
import numpy as np
from apache_beam.testing.test_pipeline import TestPipeline
from apache_beam.testing.util import assert_that, equal_to

from fwcore.config import DecompositionConfig
from pipeline.records import ReadTask, RejectedPulse
from pipeline.transforms import Decompose, PlanRanges, ReadPulses


def test_plan_ranges_covers_every_point_and_measures_the_pulse(leica_dir):
    with TestPipeline() as p:
        tasks = p | beam.Create([str(leica_dir / "leica_a.las")]) | PlanRanges(DecompositionConfig(), 400)
        summary = (tasks | beam.Map(lambda t: (t.point_range.start, t.point_range.stop, t.point_range.n_pulses,
                                               round(t.system_pulse_fwhm_ps))))
        assert_that(summary, equal_to([(0, 400, 342, 10980), (400, 800, 310, 10980), (800, 1125, 272, 10980)]))
        # 342 + 310 + 272 = 924: every pulse in exactly one range
        assert_that(summary | beam.Map(lambda r: r[2]) | beam.CombineGlobally(sum), equal_to([924]), label='all')


def test_plan_ranges_rejects_an_unreadable_file_with_its_reason(tmp_path):
    bad = tmp_path / "broken.las"
    bad.write_bytes(b"LASF" + bytes(50))
    with TestPipeline() as p:
        out = p | beam.Create([str(bad)]) | PlanRanges(DecompositionConfig())
        assert_that(out | beam.Map(lambda r: (type(r).__name__, r.source_file, r.stage, "not a readable" in r.reason)),
                    equal_to([("RejectedPulse", "broken.las", "open", True)]))


def test_limit_caps_the_pulses_of_a_file(leica_dir):
    with TestPipeline() as p:
        tasks = p | beam.Create([str(leica_dir / "leica_a.las")]) | PlanRanges(DecompositionConfig(), 400, limit=500)
        assert_that(tasks | beam.Map(lambda t: t.point_range.max_pulses), equal_to([342, 158]))


def test_read_and_decompose_count_every_pulse(leica_dir):
    config = DecompositionConfig(generations=3, system_pulse_fwhm_ps=10980.0)
    with TestPipeline() as p:
        tasks = p | beam.Create([str(leica_dir / "leica_a.las")]) | PlanRanges(config, 600)
        results = tasks | beam.ParDo(ReadPulses()) | beam.ParDo(Decompose(config))
        counts = results | beam.Map(lambda r: 0 if isinstance(r, RejectedPulse) else int((r[3].status == 0).sum()))
        assert_that(counts | beam.CombineGlobally(sum), equal_to([924]))


def test_rejected_records_pass_through_every_stage():
    rejected = RejectedPulse("a.las", 7, "read", "packet beyond the end")
    with TestPipeline() as p:
        out = p | beam.Create([rejected]) | beam.ParDo(ReadPulses()) | beam.ParDo(Decompose(DecompositionConfig()))
        assert_that(out, equal_to([rejected]))


def test_read_task_is_a_plain_record():
    from fwcore.io.reader import PointRange
    task = ReadTask(PointRange("a.las", 0, 10), 4000.0)
    assert task.system_pulse_fwhm_ps == 4000.0 and task.point_range.stop == 10
    assert np.isclose(ReadTask(*task).system_pulse_fwhm_ps, 4000.0)
