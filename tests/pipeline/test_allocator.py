"""pipeline.allocator on real processes: page faults of numpy work inside and outside kept_memory, in a process
started with Dask's MALLOC_TRIM_THRESHOLD_ and in one started without it."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# arrays of 1.6 MB made and freed in turn: above the 128 KiB at which an environment-fixed glibc maps each one
FAULTS = """
import json, resource
import numpy as np
from pipeline.allocator import kept_memory, _RUNNING

def faults(inside):
    start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    rng = np.random.default_rng(0)
    if inside:
        with kept_memory():
            for _ in range(40):
                np.sort(rng.random(200_000))
    else:
        for _ in range(40):
            np.sort(rng.random(200_000))
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start

faults(False)  # the first arrays' pages: not what is compared
print(json.dumps({"before": faults(False), "inside": faults(True), "after": faults(False), "running": _RUNNING[0]}))
"""


def faults_in(env_trim: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    if env_trim is not None:
        env["MALLOC_TRIM_THRESHOLD_"] = env_trim
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", FAULTS], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_a_worker_told_to_trim_keeps_its_memory_for_the_task_and_trims_again_after():
    f = faults_in("65536")  # what a Dask nanny gives its worker
    assert f["before"] > 10_000  # 40 arrays of 391 pages, each faulted anew
    assert f["inside"] < f["before"] / 10
    assert f["after"] > f["before"] / 2  # the worker's own settings back
    assert f["running"] == 0


def test_a_process_not_told_to_trim_is_left_as_it_is():
    f = faults_in(None)
    assert 0.8 * f["before"] <= f["inside"] <= 1.2 * f["before"]  # glibc's own sliding thresholds, untouched
    assert f["running"] == 0
