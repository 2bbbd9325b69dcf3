"""Planning on arrays and files; the stages on the DirectRunner with TestPipeline + assert_that."""

import errno
import shutil
from pathlib import Path

import apache_beam as beam
import pyarrow.parquet as pq
import pytest
from apache_beam.testing.test_pipeline import TestPipeline
from apache_beam.testing.util import assert_that, equal_to

from fwcore.engine.config import DecompositionConfig
from pipeline.faults import MachineFault, clear_faults, noted_faults
from pipeline.layout import progress_mark
from pipeline.outputs import InputNames
from pipeline.plan import InputToPlan, plan_input, plan_inputs as _plan_inputs, planned_pulses
from pipeline.records import RangePart
from pipeline.stages import RangeSettings, decompose_range, read_range, run_range
from pipeline.transforms import RangeStages


def plan_inputs(paths, config, points_per_range, limit=None):
    return _plan_inputs(paths, InputNames.of(paths), config, points_per_range, limit)


def test_read_and_decompose_count_every_pulse(leica_dir):
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], config, 600)
    decomposed = 0
    for task in tasks:
        pulses, rejected = read_range(task)
        result, not_decomposed = decompose_range(pulses, config)
        assert rejected == not_decomposed == []
        decomposed += int((result.result.status == 0).sum())
        assert result.config == config  # the method; the file's pulse is its own (task.source.pulse)
        assert result.result.sample_spacing_ps.size and task.source.pulse.fwhm_ps > 0
    assert decomposed == 924


def test_a_range_that_cannot_be_read_becomes_one_rejection_with_its_reason(tmp_path, leica_dir):
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / f"gone{suffix}")
    tasks, _ = plan_inputs([str(tmp_path / "gone.las")], DecompositionConfig(), 600)
    (tmp_path / "gone.wdp").unlink()  # after planning: reading the range fails
    settings = RangeSettings(str(tmp_path / "out"), DecompositionConfig(), frozenset({"parquet"}))
    outcomes = [run_range(task, settings) for task in tasks]
    assert [[(r.source_file, r.pulse_id, r.stage, r.reason.split(":")[0], "gone.wdp" in r.reason)
             for r in o.rejected] for o in outcomes] == \
        [[("gone.las", -1, "read", "points 0-600 (500 pulses)", True)],
         [("gone.las", -1, "read", "points 600-1125 (424 pulses)", True)]]
    assert [(o.part, o.pulses_read, o.problems, o.pulses_rejected) for o in outcomes] == [(None, 0, 1, 0)] * 2


def test_a_stage_that_fails_rejects_every_pulse_the_range_holds_with_the_stage(tmp_path, leica_dir):
    config = DecompositionConfig(optimizer="lm", lm_iterations=5)
    task = plan_inputs([str(leica_dir / "leica_a.las")], config, 300)[0][0]
    (tmp_path / "out").write_text("a file where the output folder should be")  # writing the parts fails
    outcome = run_range(task, RangeSettings(str(tmp_path / "out"), config, frozenset({"parquet"})))
    assert outcome.part is None and outcome.pulses_read == planned_pulses(task)
    assert len(outcome.rejected) == outcome.pulses_rejected == planned_pulses(task)
    assert {r.stage for r in outcome.rejected} == {"write"} and outcome.pulses_decomposed == 0
    assert all(r.reason.startswith("points 0-300: ") for r in outcome.rejected)


def _settings(output, config):
    return RangeSettings(output, config, frozenset({"parquet", "las"}))


def _summary(e):
    return (type(e).__name__, e.range_start, Path(e.las).name if isinstance(e, RangePart) else e.pulse_id)


def test_the_range_stages_dofn_gives_what_the_plain_functions_give(tmp_path, leica_dir):
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(leica_dir / "leica_a.las")], config, 400)
    plain, beamed = str(tmp_path / "plain"), str(tmp_path / "beam")
    expected = [("RangePart", start, f"leica_a-{start:012d}.las") for start in (0, 400, 800)]
    assert [_summary(run_range(t, _settings(plain, config)).part) for t in tasks] == expected
    with TestPipeline() as p:
        parts = p | beam.Create(tasks) | beam.ParDo(RangeStages(_settings(beamed, config)))
        assert_that(parts | beam.Map(_summary), equal_to(expected))
    for start in (0, 400, 800):
        name = f"leica_a-{start:012d}.parquet"
        a, b = pq.read_table(Path(plain) / "echoes" / name), pq.read_table(Path(beamed) / "echoes" / name)
        assert a.num_rows > 0 and a.equals(b)
    assert sum(pq.read_table(p).num_rows for p in (Path(beamed) / "pulses").glob("*.parquet")) == 924


def test_range_stages_write_a_failed_ranges_rejections_one_file_per_range(tmp_path, leica_dir):
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / f"gone{suffix}")
    config = DecompositionConfig(generations=3)
    tasks, _ = plan_inputs([str(tmp_path / "gone.las")], config, 600)
    (tmp_path / "gone.wdp").unlink()  # after planning: reading the range fails
    out = str(tmp_path / "out")
    with TestPipeline() as p:
        parts = p | beam.Create(tasks) | beam.ParDo(RangeStages(_settings(out, config)))
        assert_that(parts, equal_to([]))  # nothing of these ranges was written but their rejections
    written = sorted((tmp_path / "out" / "rejected").glob("*.parquet"))
    assert [f.name for f in written] == ["gone-000000000000.parquet", "gone-000000000600.parquet"]
    rows = [pq.read_table(f).to_pylist() for f in written]
    assert [[(r["source_file"], r["pulse_id"], r["stage"], r["reason"].split(":")[0]) for r in t] for t in rows] == \
        [[("gone.las", -1, "read", "points 0-600 (500 pulses)")], [("gone.las", -1, "read", "points 600-1125 (424 pulses)")]]


def test_a_full_disk_at_a_ranges_mark_ends_it_unmarked_noted_and_the_workers_next_ranges_untried(tmp_path, leica_dir,
                                                                                                  monkeypatch):
    config = DecompositionConfig(optimizer="lm", lm_iterations=5)
    first, second = plan_inputs([str(leica_dir / "leica_a.las")], config, 300)[0][:2]
    out = str(tmp_path / "out")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("pipeline.transforms.mark_range_done", full)
    stages = RangeStages(_settings(out, config))
    assert list(stages.process(first)) == []  # the job goes on: a failed bundle could hang the runner's workers
    assert not progress_mark(out, "leica_a", 0).exists()  # a resumed run redoes it
    assert [(f.code, f.path, f.where) for f in noted_faults(out)] == [("ENOSPC", out, "leica_a.las points 0-300")]
    monkeypatch.setattr("pipeline.transforms.run_range", lambda *a: pytest.fail("a range tried on a full disk"))
    assert list(stages.process(second)) == [] and not progress_mark(out, "leica_a", 300).exists()
    clear_faults(out)
    assert noted_faults(out) == [] and not list((tmp_path / "out" / "parts").glob("*.fault"))


def test_an_io_error_reading_an_input_to_plan_is_the_machines_not_the_files(leica_dir, monkeypatch):
    def lost(*args, **kwargs):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr("pipeline.plan.plan_file", lost)
    path = str(leica_dir / "leica_a.las")
    with pytest.raises(MachineFault) as caught:
        plan_input(InputToPlan(path, "leica_a.las", "leica_a"), DecompositionConfig(), 400)
    assert caught.value.said() == f"Input/output error (EIO) reading {path} (planning leica_a.las)"
    assert caught.value.remedy() == f"check the disk or network mount that holds {leica_dir}"
