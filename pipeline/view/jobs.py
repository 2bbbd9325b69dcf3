"""Background decompositions of inputs picked in the viewer: `fwl run` itself, in a child process.

A child process, not a thread: the run is exactly what `fwl run INPUT
--output DIR` does (same engine, configuration and Beam runner with its own
worker processes), and the server stays responsive meanwhile. Progress is
what `fwl run`'s own progress bar counts: the pulses of the ranges that ended
(their marks in the output folder), of the file's pulses.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from pipeline.layout import PARTS, RUN_JSON
from pipeline.progress import ProgressBar
from pipeline.view.catalog import is_complete_run

POINTS_PER_RANGE = 5000  # fwl run's default unit of work
MAX_NAMESAKES = 100  # inputs of one name (in different folders) that may have runs side by side


def _claim(output: Path) -> Path:
    """The file naming the input a run folder belongs to, written before the run starts."""
    return output.with_name(output.name + ".input")


def _owner(output: Path) -> Path | None:
    """The input a run folder belongs to: its claim file's path, else (a run made elsewhere) run.json's only input."""
    claim = _claim(output)
    if claim.is_file():
        return Path(claim.read_text().strip())
    if (output / RUN_JSON).is_file():
        try:
            inputs = json.loads((output / RUN_JSON).read_text()).get("inputs", [])
        except (OSError, ValueError):
            return Path("/")  # unreadable: someone's, not to be replaced
        paths = [e["path"] if isinstance(e, dict) else e for e in inputs]
        return Path(os.path.abspath(paths[0])) if len(paths) == 1 else Path("/")
    return None


@dataclasses.dataclass
class Job:
    input: Path
    output: Path
    pulses: int  # in the file (a run with --limit ends before)
    process: subprocess.Popen | None
    started: float = dataclasses.field(default_factory=time.time)

    def __post_init__(self):
        # never started: only its poll(), which reads the marks of ranges that ended
        self.marks = ProgressBar(self.output / PARTS, self.pulses, io.StringIO(), interactive=False)

    @property
    def log(self) -> Path:
        return self.output.with_name(self.output.name + ".log")

    def state(self) -> dict:
        code = self.process.poll()
        self.marks.poll()
        if code is None:
            status = "running"
        elif is_complete_run(self.output):  # exit code 0, or the partial run's code: some pulses rejected
            status = "done"
        else:
            status = "failed"
        log = self.log
        tail = log.read_text(errors="replace").strip().splitlines()[-3:] if status == "failed" and log.exists() else []
        done = self.pulses if status == "done" else min(self.marks.done, self.pulses)
        return {"input": self.input.name, "status": status, "pulses_done": done, "pulses": self.pulses,
                "progress": done / self.pulses if self.pulses else 1.0,
                "seconds": round(time.time() - self.started, 1), "message": " ".join(tail)}


class Jobs:
    """One decomposition per input at a time; each input path has a run folder of its own under runs_dir:
    <stem>, or <stem>-2, -3, ... when another input of the same name holds <stem>."""

    def __init__(self, runs_dir: Path, run_args: list[str] | None = None, points_per_range: int = POINTS_PER_RANGE):
        self.runs_dir = runs_dir
        self.run_args = list(run_args or [])  # more `fwl run` options (tests: --limit, Beam options)
        self.points_per_range = points_per_range
        self._jobs: dict[Path, Job] = {}
        self._lock = threading.Lock()

    def output_for(self, path: Path) -> Path:
        """The input's own run folder: the first of <stem>, <stem>-2, ... that is free or already its own
        (its claim file names this path), so one input never replaces another's run."""
        path = Path(os.path.abspath(path))
        for n in range(1, MAX_NAMESAKES + 1):
            output = self.runs_dir / (path.stem if n == 1 else f"{path.stem}-{n}")
            owner = _owner(output)
            if owner == path or (owner is None and not output.exists() and not _claim(output).exists()):
                return output
        raise ValueError(f"{path.name}: {MAX_NAMESAKES} other inputs of that name already have runs in "
                         f"{self.runs_dir}; give the viewer another --runs-dir")

    def start(self, path: Path) -> Job:
        from fwcore.io import plan_point_ranges

        with self._lock:
            job = self._jobs.get(path)
            if job is not None and job.process.poll() is None:
                return job
            output = self.output_for(path)
            # read the plan before writing anything: a file that cannot be decomposed leaves no folder behind
            pulses = sum(r.n_pulses for r in plan_point_ranges(path, self.points_per_range))
            output.parent.mkdir(parents=True, exist_ok=True)
            _claim(output).write_text(os.path.abspath(path) + "\n")
            command = [sys.executable, "-m", "pipeline.cli", "run", str(path), "--output", str(output),
                       "--points-per-range", str(self.points_per_range), *self.run_args]
            job = Job(path, output, pulses, None)
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
