"""Where a run's time goes: each range's stages, each file's plan and assembly, written as one log line each
(`timing {json}`) into the run's logs/, and read back from there (bench/bench_stages.py).

A worker logs its own lines, so the split is the real run's, on any runner whose workers write the output
folder's logs/ (the DirectRunner's processes, Dask's workers on this machine).
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
from pathlib import Path

LOG = logging.getLogger("fwl")
MARK = "timing "  # a timing line's message starts with this, then its JSON


class Laps:
    """Seconds per named stage, added up over the `with laps("name"):` blocks that ran."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.began = time.time()

    @contextlib.contextmanager
    def __call__(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start


def log_timing(kind: str, label: str, laps: Laps, **counts: int) -> None:
    """One timing line: what was timed (range, plan, assemble), which, when it began (Unix s), its stages."""
    LOG.info("%s%s", MARK, json.dumps({"kind": kind, "label": label, "began": laps.began, "ended": time.time(),
                                       "seconds": laps.seconds, **counts}))


def read_timings(logs: str | Path) -> list[dict]:
    """Every timing line under a run's logs/ folder, as the dicts log_timing wrote."""
    found = []
    for path in sorted(Path(logs).glob("*.log")):
        for line in path.read_text(errors="replace").splitlines():
            at = line.find(MARK + "{")
            if at >= 0:
                found.append(json.loads(line[at + len(MARK):]))
    return found
