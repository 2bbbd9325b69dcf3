"""The ranges' job started before the plans are made: its workers start (a process each, Beam and numba's
kernels loaded: 3-7 s on 2 cores) while the driver plans, then take the ranges the driver hands over.

    hand_over(output, tasks)   the driver: the ranges to run (an empty list: none, the job ends), atomically
    await_ranges(output)       a worker: waits for them, then returns them
    withdraw(output)           the driver, after the job: the handed-over file removed

The hand-over is a file under parts/ (the workers of the DirectRunner share the driver's disk): ReadTasks
pickled, as Beam itself would pickle them into a Create.
"""

from __future__ import annotations

import pickle
import time
from pathlib import Path

from pipeline.layout import PARTS
from pipeline.records import ReadTask
from pipeline.sinks import temporary_path

HANDOFF = "ranges-handed-over.pickle"
POLL_S = 0.05


def handoff_path(output: str | Path) -> Path:
    return Path(output) / PARTS / HANDOFF


def hand_over(output: str | Path, tasks: list[ReadTask]) -> None:
    """The ranges the waiting job is to run, written whole before a worker can see them."""
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


def withdraw(output: str | Path) -> None:
    handoff_path(output).unlink(missing_ok=True)
