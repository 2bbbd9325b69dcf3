"""Where a run's jobs run: a small run under the default runner in the driver's process, real work on workers."""

import os
import socket
from pathlib import Path

from pipeline.options import check_beam_args, runner_given
from pipeline.run import IN_PROCESS_PULSES, THREADED_POINTS, Jobs, _runner_name


def test_a_small_job_runs_in_process_only_under_the_default_runner():
    default = Jobs(check_beam_args([]), small_in_process=not runner_given([]))
    assert default.in_process(2, small=True) and not default.in_process(2, small=False)
    assert default.in_process(1)  # one file to plan or assemble: always here
    given = ["--direct_num_workers=2", "--direct_running_mode=multi_processing"]
    chosen = Jobs(check_beam_args(given), small_in_process=not runner_given(given))
    assert runner_given(given) and not chosen.in_process(2, small=True)  # the determinism tests' workers stay
    assert not runner_given(["--crs", "EPSG:25832"]) and runner_given(["--runner=DirectRunner"])
    assert 1000 < IN_PROCESS_PULSES < 10_000  # a few seconds of work, less than starting two workers


def test_a_job_run_here_is_its_calls_and_elsewhere_its_pipeline(tmp_path):
    """Jobs.each: a job that would run in this process calls the plain function on each element, without building
    a pipeline; one the runner runs elsewhere (here Beam's in-memory runner, chosen on the command line) is the
    pipeline `build` makes."""
    import apache_beam as beam

    called, built = [], []
    default = Jobs(check_beam_args([]), small_in_process=True)
    default.each(["a"], called.append, built.append)
    default.each(["b", "c"], called.append, built.append, small=True)
    assert called == ["a", "b", "c"] and built == []

    def write_each(p):
        return p | beam.Create(["x", "y"]) | beam.Map(lambda name: (tmp_path / name).write_text(name))

    memory = Jobs(check_beam_args(["--direct_running_mode=in_memory", "--direct_num_workers=1"]))
    memory.each(["x", "y"], called.append, write_each)
    assert called == ["a", "b", "c"] and sorted(p.name for p in tmp_path.iterdir()) == ["x", "y"]


def test_a_run_of_few_points_runs_its_ranges_workers_as_threads_only_under_the_default_runner(tmp_path):
    """Jobs.threaded: the inputs' point records (from their headers) at most THREADED_POINTS, and no runner given;
    a threads job's pipeline runs in this process (its workers write this process's files)."""
    import apache_beam as beam

    leica = str(Path(__file__).resolve().parents[2] / "examples" / "data" / "leica_als" / "leica_a.las")  # 1,125 points
    default = Jobs(check_beam_args([]), small_in_process=True)
    assert default.threaded([leica]) and default.threaded([leica, str(tmp_path / "gone.las")])  # unreadable: 0
    assert 100_000 < THREADED_POINTS < 1_000_000
    given = ["--direct_num_workers=2", "--direct_running_mode=multi_processing"]
    assert not Jobs(check_beam_args(given), small_in_process=False).threaded([leica])
    assert _runner_name(default.options, threads=True) == "DirectRunner, 2 worker threads"
    assert _runner_name(default.options) == "DirectRunner, 2 workers"

    def write_each(p):
        return (p | beam.Create(["x", "y", "z"]) | beam.Reshuffle()
                | beam.Map(lambda name: (tmp_path / name).write_text(str(os.getpid()))))

    default.run(3, write_each, threads=True)
    pids = {(tmp_path / n).read_text() for n in "xyz"}
    assert pids == {str(os.getpid())}  # no worker process: this one's threads


def test_a_run_on_threads_writes_what_worker_processes_write(tmp_path, monkeypatch):
    """The default runner's threads (the Leica sample in ranges of 300 points, counted as no small run) against
    2 worker processes given on the command line: the same tables, and no worker process's log."""
    import pyarrow.parquet as pq

    from fwcore.engine.config import DecompositionConfig
    from pipeline.run import run

    las = [str(Path(__file__).resolve().parents[2] / "examples" / "data" / "leica_als" / "leica_a.las")]
    given = ["--direct_num_workers=2", "--direct_running_mode=multi_processing"]
    processes = run(las, tmp_path / "processes", DecompositionConfig(), ("parquet",), None, 300, watch=False,
                    beam_args=given)
    monkeypatch.setattr("pipeline.run.IN_PROCESS_PULSES", 0)
    threads = run(las, tmp_path / "threads", DecompositionConfig(), ("parquet",), None, 300, watch=False)
    assert threads["counts"] == processes["counts"] and threads["counts"]["pulses_read"] == 924
    for table, order in (("pulses", ["pulse_id"]), ("echoes", ["pulse_id", "echo_index"])):
        keys = [(k, "ascending") for k in order]
        assert pq.read_table(tmp_path / "threads" / table).sort_by(keys).equals(
            pq.read_table(tmp_path / "processes" / table).sort_by(keys))
    logs = {p.name for p in (tmp_path / "threads" / "logs").glob("worker-*.log")}
    assert logs == {f"worker-{socket.gethostname()}-{os.getpid()}.log"}  # this process's only
    driver = (tmp_path / "threads" / "logs" / "driver.log").read_text()
    assert driver.count("apache_beam.runners.worker.sdk_worker Control channel established") == 2  # 2 harnesses here
