"""Timing lines: what a worker logs of its stages is what the benchmark reads back from the run's logs/."""

import json
import time

from pipeline.cli import main
from pipeline.timing import Laps, log_timing, read_timings


def test_laps_add_up_each_stage_and_read_back_from_a_log(tmp_path):
    import logging

    laps = Laps()
    for _ in range(2):
        with laps("sleep"):
            time.sleep(0.02)
    handler = logging.FileHandler(tmp_path / "worker-x.log")
    logging.getLogger("fwl").addHandler(handler)
    logging.getLogger("fwl").setLevel(logging.INFO)
    try:
        log_timing("range", "a.las points 0-10", laps, pulses=10)
    finally:
        logging.getLogger("fwl").removeHandler(handler)
        handler.close()
    (found,) = read_timings(tmp_path)
    assert found["kind"] == "range" and found["pulses"] == 10 and 0.04 <= found["seconds"]["sleep"] < 0.5
    assert found["began"] <= found["ended"]


def test_a_run_logs_every_range_its_plan_and_its_jobs(tmp_path, leica_dir):
    out = tmp_path / "out"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--limit", "200",
                 "--points-per-range", "100", "--generations", "3", "--formats", "parquet,las,mcap"]) == 0
    timings = read_timings(out / "logs")
    ranges = [t for t in timings if t["kind"] == "range"]
    assert len(ranges) == json.loads((out / "run.json").read_text())["ranges"]
    assert sum(t["pulses"] for t in ranges) == 200
    assert {"read", "decompose", "tables", "write las", "write mcap"} <= set(ranges[0]["seconds"])
    assert {t["kind"] for t in timings} >= {"plan", "assemble", "jobs"}
