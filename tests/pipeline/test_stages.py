"""A range's stages: a fault of the machine at any sink fails the range without rejecting a pulse; echoes under
the ground leave the geolocate stage as spurious, with their reason."""

import errno
import logging
import os

import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.faults import MEMORY, MachineFault
from pipeline.layout import part_name
from pipeline.outputs import InputNames
from pipeline.plan import plan_inputs
from pipeline.stages import RangeSettings, run_range

CONFIG = DecompositionConfig(optimizer="lm", lm_iterations=5)
FORMATS = frozenset({"parquet", "las", "mcap"})
# each sink of write_range, and the part it writes
SINKS = {"write_echo_part": "echoes/{}.parquet", "write_part": "pulses/{}.parquet",
         "write_point_cloud": "parts/{}.las", "write_mcap": "parts/{}.mcap"}


@pytest.fixture(scope="module")
def task(leica_dir):
    paths = [str(leica_dir / "leica_a.las")]
    return plan_inputs(paths, InputNames.of(paths), CONFIG, 300)[0][0]


def _failing(number):
    def write(*args, **kwargs):
        raise OSError(number, os.strerror(number))
    return write


@pytest.mark.parametrize("number", [errno.ENOSPC, errno.EACCES, errno.EIO])
@pytest.mark.parametrize("sink", sorted(SINKS))
def test_a_machine_fault_at_each_sink_fails_the_range_names_the_part_and_leaves_nothing(tmp_path, monkeypatch, task,
                                                                                       caplog, sink, number):
    monkeypatch.setattr(f"pipeline.stages.{sink}", _failing(number))
    out = tmp_path / "out"
    with caplog.at_level(logging.INFO, logger="fwl"), pytest.raises(MachineFault) as caught:
        run_range(task, RangeSettings(str(out), CONFIG, FORMATS))
    fault = caught.value
    assert (fault.code, fault.doing, fault.where) == (errno.errorcode[number], "writing", "leica_a.las points 0-300")
    assert fault.path == str(out / SINKS[sink].format(part_name("leica_a", 0)))
    assert [p for p in out.rglob("*") if p.is_file()] == []  # a range is written whole or not at all
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert said == [f"leica_a.las points 0-300: write stopped: {fault.said()}"]  # one line, no repr of the task


def test_no_memory_while_decomposing_is_the_machines_fault_too(tmp_path, monkeypatch, task):
    def out_of_memory(*args, **kwargs):
        raise MemoryError()

    monkeypatch.setattr("pipeline.stages.decompose_batch", out_of_memory)
    with pytest.raises(MachineFault) as caught:
        run_range(task, RangeSettings(str(tmp_path / "out"), CONFIG, FORMATS))
    assert (caught.value.code, caught.value.doing, caught.value.path) == (MEMORY, "reading", task.source.path)


def test_a_data_fault_still_rejects_the_ranges_pulses_in_one_log_line(tmp_path, monkeypatch, task, caplog):
    def damaged(*args, **kwargs):
        raise ValueError("non-finite samples")

    monkeypatch.setattr("pipeline.stages.decompose_batch", damaged)
    with caplog.at_level(logging.INFO, logger="fwl"):
        outcome = run_range(task, RangeSettings(str(tmp_path / "out"), CONFIG, FORMATS))
    assert outcome.pulses_rejected == outcome.pulses_read == 265 and outcome.part is None
    assert {(r.stage, r.reason) for r in outcome.rejected} == \
        {("decompose", "points 0-300: ValueError: non-finite samples")}
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert said == ["leica_a.las points 0-300: decompose failed: ValueError: non-finite samples"]


def test_echoes_under_the_ground_go_to_the_spurious_echoes_with_their_reason(tmp_path):
    import pyarrow.parquet as pq

    from tests.fwcore.test_plausibility import _bumped_flight

    path, _, _, bumped = _bumped_flight(tmp_path)
    paths = [str(path)]
    task = plan_inputs(paths, InputNames.of(paths), DecompositionConfig(), 100_000)[0][0]
    outcome = run_range(task, RangeSettings(str(tmp_path / "out"), DecompositionConfig(), frozenset({"parquet"})))
    echoes = pq.read_table(next((tmp_path / "out" / "echoes").glob("*.parquet"))).to_pandas()
    under = echoes[echoes.reject_reason == "under_ground"]
    assert 0.5 * bumped.size <= len(under) and not under.kept.any()
    assert outcome.echoes_kept + outcome.echoes_spurious == len(echoes)
    assert outcome.echoes_spurious == int((~echoes.kept).sum()) >= len(under)
    assert ((echoes.reject_reason == "") == echoes.kept).all()


def _decomposed(task):
    from fwcore.pulses import echo_positions
    from pipeline.stages import decompose_range, read_range

    item, _ = decompose_range(read_range(task)[0], CONFIG)
    return item, echo_positions(item.pulses, item.result, task.source.pulse.range_offset_ps)


def test_a_small_footprints_metrics_come_from_its_echoes_unless_the_full_ones_are_asked_for(task):
    import numpy as np

    from fwcore.metrics.pulses import batch_metrics
    from pipeline.stages import range_metrics

    item, xyz = _decomposed(task)
    (echoes, none, _), (full, _, _) = range_metrics(item, xyz), range_metrics(item, xyz, "full")
    assert none is None  # no L2A algorithm for an airborne pulse
    kept = item.result.reject == 0
    last = np.array([np.flatnonzero(kept[lo:hi])[-1] + lo for lo, hi in zip(item.result.echo_offsets[:-1],
                                                                              item.result.echo_offsets[1:])])
    assert np.array_equal(echoes.ground_z, xyz[last, 2])  # each pulse's last kept echo
    expected = batch_metrics(item.pulses, item.result, task.source.pulse)
    assert np.array_equal(full.ground_z, expected.ground_z, equal_nan=True)
    assert np.array_equal(full.rg, expected.rg, equal_nan=True)


def test_a_gedi_shots_metrics_stay_nasas_whatever_is_asked(tmp_path):
    import numpy as np

    from fwcore.metrics.algorithms import AlgorithmPlan
    from pipeline.stages import range_metrics
    from tests.fwcore.metrics.conftest import L1B

    paths = [str(L1B)]
    gedi = plan_inputs(paths, InputNames.of(paths), CONFIG, 40, limit=40)[0][0]
    item, xyz = _decomposed(gedi)
    expected, algorithms, _ = AlgorithmPlan.from_dict(gedi.source.metric_settings).metrics(item.pulses, item.result,
                                                                                           gedi.source.pulse)
    for asked in ("echoes", "full"):
        got, chosen, _ = range_metrics(item, xyz, asked)
        assert np.array_equal(got.ground_z, expected.ground_z, equal_nan=True)
        assert np.array_equal(got.rh, expected.rh, equal_nan=True)
        assert np.array_equal(chosen, algorithms)
    assert np.isfinite(expected.ground_z).sum() > 10
