"""Planning on arrays and files; the stages on the DirectRunner with TestPipeline + assert_that."""

import shutil
from pathlib import Path

import apache_beam as beam
import pyarrow.parquet as pq
from apache_beam.testing.test_pipeline import TestPipeline
from apache_beam.testing.util import assert_that, equal_to

from fwcore.config import DecompositionConfig
from pipeline.outputs import InputNames
from pipeline.plan import plan_inputs as _plan_inputs, planned_pulses
from pipeline.records import DecomposedRange, RangePart, Rejection
from pipeline.transforms import (Decompose, Geolocate, RangeStages, ReadRange, WriteRange, assemble_file,
                                 written_parts)


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


def _stages(output, config):
    return [ReadRange(output), Decompose(output, config), Geolocate(output, False),
            WriteRange(output, frozenset({"parquet", "las"}))]


def _summary(e):
    return (type(e).__name__, e.range_start, Path(e.las).name if isinstance(e, RangePart) else e.pulse_id)


def test_range_stages_in_one_pardo_give_what_the_four_pardos_give(tmp_path, leica_dir):
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], config, 400)
    chained, one = str(tmp_path / "chained"), str(tmp_path / "one")
    expected = [("RangePart", start, f"leica_a-{start:012d}.las") for start in (0, 400, 800)]
    with TestPipeline() as p:
        out = p | "Tasks" >> beam.Create(tasks)
        for i, stage in enumerate(_stages(chained, config)):
            out = out | f"Stage{i}" >> beam.ParDo(stage)
        assert_that(out | "Chained" >> beam.Map(_summary), equal_to(expected), label="chained")
        together = p | "Tasks2" >> beam.Create(tasks) | beam.ParDo(RangeStages(one, *_stages(one, config)))
        assert_that(together | "One" >> beam.Map(_summary), equal_to(expected), label="one")
    for start in (0, 400, 800):
        name = f"leica_a-{start:012d}.parquet"
        a, b = pq.read_table(Path(chained) / "echoes" / name), pq.read_table(Path(one) / "echoes" / name)
        assert a.num_rows > 0 and a.equals(b)
    assert sum(pq.read_table(p).num_rows for p in (Path(one) / "pulses").glob("*.parquet")) == 924


def test_range_stages_write_a_failed_ranges_rejections_one_file_per_range(tmp_path, leica_dir):
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / f"gone{suffix}")
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(tmp_path / "gone.las")], config, 600)
    (tmp_path / "gone.wdp").unlink()  # after planning: reading the range fails, the later stages pass it on
    out = str(tmp_path / "out")
    with TestPipeline() as p:
        parts = p | beam.Create(tasks) | beam.ParDo(RangeStages(out, *_stages(out, config)))
        assert_that(parts, equal_to([]))  # nothing of these ranges was written but their rejections
    written = sorted((tmp_path / "out" / "rejected").glob("*.parquet"))
    assert [f.name for f in written] == ["gone-000000000000.parquet", "gone-000000000600.parquet"]
    rows = [pq.read_table(f).to_pylist() for f in written]
    assert [[(r["source_file"], r["pulse_id"], r["stage"], r["reason"].split(":")[0]) for r in t] for t in rows] == \
        [[("gone.las", -1, "read", "points 0-600 (500 pulses)")], [("gone.las", -1, "read", "points 600-1125 (424 pulses)")]]


def test_the_files_second_job_finds_the_written_ranges_parts_in_order(tmp_path, leica_dir):
    """The ranges' job ends at the parts; written_parts lists them from parts/ for the files' job (assemble_file)."""
    import laspy

    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], config, 400)
    out = str(tmp_path / "out")
    with TestPipeline() as p:  # the middle range is not written: it must not be looked for
        p | beam.Create([tasks[2], tasks[0]]) | beam.ParDo(RangeStages(out, *_stages(out, config)))
    files = written_parts(out, tasks, frozenset({"parquet", "las"}))
    assert [(stem, [(r.range_start, Path(r.las).name, r.mcap) for r in parts]) for stem, parts in files] == \
        [("leica_a", [(0, "leica_a-000000000000.las", ""), (800, "leica_a-000000000800.las", "")])]
    points = [laspy.read(r.las).header.point_count for r in files[0][1]]
    assert assemble_file(files[0], out, False) == "leica_a"
    assembled = laspy.read(tmp_path / "out" / "las" / "leica_a.las")
    assert points[0] > 0 and assembled.header.point_count == sum(points)
    assert not list((tmp_path / "out" / "parts").glob("*.las"))  # the parts are removed once in the file
