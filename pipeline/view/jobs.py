"""Background decompositions of inputs picked in the viewer: `fwl run` itself, in a child process.

A child process, not a thread: the run is exactly what `fwl run INPUT
--output DIR` does (same engine, configuration and Beam runner with its own
worker processes), and the server stays responsive meanwhile. Progress is the
share of the file's point ranges whose pulse tables are written.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
import time
from pathlib import Path

from pipeline.view.catalog import is_complete_run

POINTS_PER_RANGE = 5000  # fwl run's default unit of work


@dataclasses.dataclass
class Job:
    input: Path
    output: Path
    ranges: int
    process: subprocess.Popen | None
    started: float = dataclasses.field(default_factory=time.time)

    @property
    def log(self) -> Path:
        return self.output.with_name(self.output.name + ".log")

    def state(self) -> dict:
        code = self.process.poll()
        written = len(list((self.output / "pulses").glob("*.parquet"))) if (self.output / "pulses").is_dir() else 0
        if code is None:
            status = "running"
        elif is_complete_run(self.output):  # exit code 0, or the partial run's code: some pulses rejected
            status = "done"
        else:
            status = "failed"
        log = self.log
        tail = log.read_text(errors="replace").strip().splitlines()[-3:] if status == "failed" and log.exists() else []
        done = self.ranges if status == "done" else min(written, self.ranges)
        return {"input": self.input.name, "status": status, "ranges_done": done, "ranges": self.ranges,
                "progress": done / self.ranges if self.ranges else 1.0, "seconds": round(time.time() - self.started, 1),
                "message": " ".join(tail)}


class Jobs:
    """One decomposition per input at a time; runs go to runs_dir/<input stem>."""

    def __init__(self, runs_dir: Path, run_args: list[str] | None = None, points_per_range: int = POINTS_PER_RANGE):
        self.runs_dir = runs_dir
        self.run_args = list(run_args or [])  # more `fwl run` options (tests: --limit, Beam options)
        self.points_per_range = points_per_range
        self._jobs: dict[Path, Job] = {}
        self._lock = threading.Lock()

    def output_for(self, path: Path) -> Path:
        return self.runs_dir / path.stem

    def start(self, path: Path) -> Job:
        from fwcore.io import plan_point_ranges

        with self._lock:
            job = self._jobs.get(path)
            if job is not None and job.process.poll() is None:
                return job
            output = self.output_for(path)
            output.parent.mkdir(parents=True, exist_ok=True)
            ranges = len(plan_point_ranges(path, self.points_per_range))
            command = [sys.executable, "-m", "pipeline.cli", "run", str(path), "--output", str(output),
                       "--points-per-range", str(self.points_per_range), *self.run_args]
            job = Job(path, output, ranges, None)
            with open(job.log, "w") as log:
                job.process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
            self._jobs[path] = job
            return job

    def states(self) -> dict[Path, dict]:
        with self._lock:
            return {p: j.state() for p, j in self._jobs.items()}

    def stop_all(self) -> None:
        """Stop the runs this server started (its own children only)."""
        with self._lock:
            for job in self._jobs.values():
                if job.process.poll() is None:
                    job.process.terminate()
                    try:
                        job.process.wait(10)
                    except subprocess.TimeoutExpired:
                        job.process.kill()
