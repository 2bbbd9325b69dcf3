"""The ranges' job started before the plans are made: its workers start (a process each, Beam and numba's
kernels loaded: 3-7 s on 2 cores) while the driver plans, then take the ranges the driver hands over.

    hand_over(output, tasks)   the driver: the ranges to run (an empty list: none, the job ends), atomically
    await_ranges(output)       a worker: waits for them, then returns them
    claimed_ranges(output)     a worker: waits for them, then takes them one at a time, each range the first
                               worker's to claim it: the workers share them as each finishes its last
    withdraw(output)           the driver, after the job: the handed-over file and the claims removed

The hand-over is a file under parts/ (the workers of the DirectRunner share the driver's disk): ReadTasks
pickled, as Beam itself would pickle them into a Create. A claim is a file created exclusively (O_EXCL) beside
it: no shuffle between the wait and the ranges, whose stage would start only once every worker's wait ended.
"""

from __future__ import annotations

import os
import pickle
import shutil
import time
from pathlib import Path
from typing import Iterator

from pipeline.layout import PARTS
from pipeline.records import ReadTask
from pipeline.sinks import temporary_path

HANDOFF = "ranges-handed-over.pickle"
CLAIMS = "ranges-claimed"
POLL_S = 0.05


def handoff_path(output: str | Path) -> Path:
    return Path(output) / PARTS / HANDOFF


def claims_path(output: str | Path) -> Path:
    return Path(output) / PARTS / CLAIMS


def hand_over(output: str | Path, tasks: list[ReadTask]) -> None:
    """The ranges the waiting job is to run, written whole before a worker can see them (an interrupted run's
    claims gone first)."""
    shutil.rmtree(claims_path(output), ignore_errors=True)
    path = handoff_path(output)
    tmp = temporary_path(path)
    tmp.write_bytes(pickle.dumps(list(tasks)))
    tmp.replace(path)


def await_ranges(output: str | Path, poll: float = POLL_S) -> list[ReadTask]:
    """The ranges the driver handed over, once it has (polled every `poll` seconds)."""
    path = handoff_path(output)
    while not path.exists():
        time.sleep(poll)
    return pickle.loads(path.read_bytes())


def claimed_ranges(output: str | Path, poll: float = POLL_S) -> Iterator[ReadTask]:
    """The handed-over ranges this worker takes, claimed one at a time when it asks for the next: a range is
    the first worker's to create its claim, so each range runs once and a worker takes the next as it finishes."""
    tasks = await_ranges(output, poll)
    claims = claims_path(output)
    claims.mkdir(parents=True, exist_ok=True)
    for index, task in enumerate(tasks):
        try:
            os.close(os.open(claims / str(index), os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644))
        except FileExistsError:  # another worker's
            continue
        yield task


def withdraw(output: str | Path) -> None:
    handoff_path(output).unlink(missing_ok=True)
    shutil.rmtree(claims_path(output), ignore_errors=True)
