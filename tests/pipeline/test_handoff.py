"""The ranges' job started before the plans: it waits for the ranges the driver hands over, runs exactly those,
and its outputs are those of the job started after the plans."""

import threading
import time

import apache_beam as beam
import pyarrow.parquet as pq

from fwcore.engine.config import DecompositionConfig
from fwcore.radiometry.equations import RadiometryConfig
from pipeline.forest_settings import ForestSettings
from pipeline.handoff import await_ranges, claimed_ranges, claims_path, hand_over, handoff_path, withdraw
from pipeline.options import check_beam_args
from pipeline.outputs import InputNames
from pipeline.plan import plan_inputs
from pipeline.run import EarlyRanges, Jobs
from pipeline.transforms import DecomposeFlight

CONFIG = DecompositionConfig(optimizer="lm", lm_iterations=5)
WORKERS = ["--direct_num_workers=2", "--direct_running_mode=multi_processing"]


def _tasks(leica_dir):
    paths = [str(leica_dir / "leica_a.las")]
    return plan_inputs(paths, InputNames.of(paths), CONFIG, 300)[0]


def test_a_worker_waits_for_the_ranges_handed_over(tmp_path, leica_dir):
    tasks = _tasks(leica_dir)
    got = []
    waiting = threading.Thread(target=lambda: got.extend(await_ranges(tmp_path, poll=0.01)))
    waiting.start()
    time.sleep(0.1)
    assert waiting.is_alive() and not got  # nothing handed over yet
    hand_over(tmp_path, tasks)
    waiting.join(5)
    assert got == tasks and len(tasks) == 4
    withdraw(tmp_path)
    assert not handoff_path(tmp_path).exists()


def test_workers_claim_each_handed_over_range_once_as_they_ask(tmp_path, leica_dir):
    """Two workers taking ranges in turn share them: every range once, the next to whoever asks; a new hand-over
    clears an interrupted run's claims, and withdraw removes them."""
    tasks = _tasks(leica_dir)
    (claims_path(tmp_path) / "0").parent.mkdir(parents=True)
    (claims_path(tmp_path) / "0").touch()  # an interrupted run's claim
    hand_over(tmp_path, tasks)
    first, second = claimed_ranges(tmp_path, poll=0.01), claimed_ranges(tmp_path, poll=0.01)
    taken = [next(first), next(second), next(second), next(first)]
    assert taken == tasks and list(first) == [] and list(second) == []
    withdraw(tmp_path)
    assert not claims_path(tmp_path).exists() and not handoff_path(tmp_path).exists()


def test_the_early_job_writes_what_the_ranges_job_writes(tmp_path, leica_dir):
    tasks = _tasks(leica_dir)
    formats = frozenset({"parquet"})
    early = EarlyRanges(check_beam_args(WORKERS), tmp_path / "early", CONFIG, formats, RadiometryConfig())
    time.sleep(0.5)  # the workers starting: the plans are being made
    early.finish(tasks)
    late = tmp_path / "late"
    Jobs(check_beam_args(WORKERS)).run(len(tasks), lambda p: p | beam.Create(tasks) | DecomposeFlight(
        CONFIG, str(late), formats))
    for table in ("pulses", "echoes"):
        a = pq.read_table(tmp_path / "early" / table).sort_by("pulse_id")
        b = pq.read_table(late / table).sort_by("pulse_id")
        assert a.num_rows == b.num_rows and a.num_rows > 900
        assert a.drop_columns(["source_file"]).equals(b.drop_columns(["source_file"]))


def test_the_early_job_gives_a_gedi_shot_its_biomass_as_the_ranges_job_does(tmp_path):
    """--stratum reaches the early job's workers: the same agbd, none of it null."""
    from tests.fwcore.metrics.conftest import L1B

    paths = [str(L1B)]
    tasks = plan_inputs(paths, InputNames.of(paths), CONFIG, 20, limit=40)[0]
    formats = frozenset({"parquet"})
    early = EarlyRanges(check_beam_args(WORKERS), tmp_path / "early", CONFIG, formats, RadiometryConfig(),
                        ForestSettings(stratum="ENT_NAm"))
    early.finish(tasks)
    late = tmp_path / "late"
    Jobs(check_beam_args(WORKERS)).run(len(tasks), lambda p: p | beam.Create(tasks) | DecomposeFlight(
        CONFIG, str(late), formats, forest=ForestSettings(stratum="ENT_NAm")))
    a = pq.read_table(tmp_path / "early" / "pulses").sort_by("pulse_id").to_pandas()
    b = pq.read_table(late / "pulses").sort_by("pulse_id").to_pandas()
    assert len(a) == 40 and a.agbd.notna().all() and (a.agbd_stratum == "ENT_NAm").all()
    assert a.agbd.tolist() == b.agbd.tolist() and a.agbd_se.tolist() == b.agbd_se.tolist()


def test_an_abandoned_early_job_ends_with_nothing_run(tmp_path):
    early = EarlyRanges(check_beam_args(WORKERS), tmp_path, CONFIG, frozenset({"parquet"}), RadiometryConfig(), "echoes")
    early.abandon(wait=True)
    assert not early.thread.is_alive() and early.error is None
    assert not (tmp_path / "pulses").exists() and not handoff_path(tmp_path).exists()


def RadiometryConfig():
    from fwcore.radiometry.equations import RadiometryConfig

    return RadiometryConfig()


def test_a_run_whose_ranges_job_starts_early_writes_what_it_wrote_before(tmp_path, leica_dir, monkeypatch):
    from pipeline.run import run

    las = [str(leica_dir / "leica_a.las")]
    before = run(las, tmp_path / "before", CONFIG, ("parquet",), None, 300, watch=False, beam_args=WORKERS)
    monkeypatch.setattr("pipeline.run.IN_PROCESS_BYTES", 0)  # the sample counts as big: the job starts early
    early = run(las, tmp_path / "early", CONFIG, ("parquet",), None, 300, watch=False, beam_args=WORKERS)
    assert early["counts"] == before["counts"] and early["counts"]["pulses_read"] == 924
    for table, order in (("pulses", ["pulse_id"]), ("echoes", ["pulse_id", "echo_index"])):
        keys = [(k, "ascending") for k in order]
        assert pq.read_table(tmp_path / "early" / table).sort_by(keys).equals(
            pq.read_table(tmp_path / "before" / table).sort_by(keys))
    assert not handoff_path(tmp_path / "early").exists()
    timings = (tmp_path / "early" / "logs").glob("*.log")
    assert any("awaiting ranges" in f.read_text() for f in timings)  # the workers warmed up before the ranges
