"""A run a person can watch: quiet logs, a progress bar on the driver.

Everything Beam, Dask and the workers log goes to logs/ under the output
folder. The terminal gets our start line, a progress bar and the summary;
of the rest only our warnings and anyone's errors (with --verbose,
everything).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import Iterable, TextIO

from pipeline.layout import LOGS

# Beam and its dependencies' warnings that say nothing about the run.
HARMLESS = ("apitools not found", "Discarding unparseable args", "semi_persistent_directory",
            "The new default partition size", "Make sure that locally built Python SDK docker image",
            "No iterator is returned by the process method")


class _Harmless(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(h in message for h in HARMLESS)


OURS = ("pipeline", "fwcore", "fwl")  # the loggers whose warnings are the user's business


class _OursOrErrors(logging.Filter):
    """On the terminal: our warnings and anyone's errors; a library's warnings (laspy's about a damaged file,
    Beam's about its workers, forwarded in 300-character lines) stay in logs/."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.name.split(".", 1)[0] in OURS:
            return True
        # a fault of the machine, as a runner logs it (a traceback): fwl run says it once, with the remedy
        return record.levelno >= logging.ERROR and "machine fault " not in record.getMessage()


def quiet_imports() -> None:
    """Before Beam is imported: its import-time warnings go nowhere unless a real handler is set later."""
    root = logging.getLogger()
    if not root.handlers:
        handler = logging.StreamHandler()
        handler.setLevel(logging.WARNING)
        handler.addFilter(_Harmless())
        handler.fwl_quiet = True
        root.addHandler(handler)


@contextlib.contextmanager
def watched_logs(output: Path, verbose: bool):
    """Logs of the run to output/logs/ (driver.log: the driver's records; workers.log: what worker processes
    print); yields the terminal's stdout and stderr for the start line and the progress bar. With verbose, the terminal gets everything too."""
    logs = output / LOGS
    logs.mkdir(parents=True, exist_ok=True)
    root = logging.getLogger()
    saved_level, saved_handlers = root.level, list(root.handlers)
    for h in saved_handlers:
        if getattr(h, "fwl_quiet", False):
            root.removeHandler(h)
    sys.stdout.flush(), sys.stderr.flush()
    say = os.fdopen(os.dup(1), "w", buffering=1)
    terminal = os.fdopen(os.dup(2), "w", buffering=1)
    redirected = []
    if not verbose:
        # worker processes of the DirectRunner print to the driver's stdout and stderr: send those to a file
        workers = os.open(logs / "workers.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        for fd in (1, 2):
            redirected.append((fd, os.dup(fd)))
            os.dup2(workers, fd)
        os.close(workers)
    file_handler = logging.FileHandler(logs / "driver.log")
    file_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s"))
    console = logging.StreamHandler(terminal)
    console.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    console.setLevel(logging.INFO if verbose else logging.WARNING)
    if not verbose:
        console.addFilter(_Harmless())
        console.addFilter(_OursOrErrors())
    root.addHandler(file_handler)
    root.addHandler(console)
    root.setLevel(logging.INFO)
    for noisy in ("numba",):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        yield say, terminal
    finally:
        sys.stdout.flush(), sys.stderr.flush()
        for fd, saved in redirected:
            os.dup2(saved, fd)
            os.close(saved)
        root.removeHandler(file_handler)
        root.removeHandler(console)
        file_handler.close()
        root.setLevel(saved_level)
        for h in saved_handlers:
            if h not in root.handlers:
                root.addHandler(h)
        terminal.close()
        say.close()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class ProgressBar:
    """Pulses done of the planned total, from the marks that ranges leave when they end (any runner:
    the marks are files in the shared output folder). Drawn in place on a terminal; elsewhere a line
    now and then."""

    def __init__(self, marks: Path, total: int, stream: TextIO, interactive: bool | None = None,
                 every: float = 0.5, line_every: float = 60.0, already: Iterable[str] = ()):
        self.marks, self.total, self.stream = marks, total, stream
        self.interactive = stream.isatty() if interactive is None else interactive
        self.every, self.line_every = every, line_every
        self.done = self.rejected = 0
        self._seen: set[str] = set(already)  # the marks of ranges an earlier run finished: not in the total
        self._began = time.perf_counter()
        self._last_line = self._began
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def poll(self) -> None:
        import json
        try:
            names = [n for n in os.listdir(self.marks) if n.endswith(".json") and n not in self._seen]
        except FileNotFoundError:
            return
        for name in names:
            try:
                mark = json.loads((self.marks / name).read_text())
            except (OSError, ValueError):  # being written: next time
                continue
            self._seen.add(name)
            self.done += int(mark["pulses"])
            self.rejected += int(mark["rejected"])

    def line(self) -> str:
        elapsed = time.perf_counter() - self._began
        rate = self.done / elapsed if elapsed > 0 else 0.0
        share = self.done / self.total if self.total else 1.0
        width = 24
        bar = "#" * int(width * min(share, 1.0))
        eta = _duration((self.total - self.done) / rate) if rate > 0 and self.done < self.total else "--:--"
        return (f"[{bar:<{width}}] {self.done:,}/{self.total:,} pulses {share:4.0%}  {rate:,.0f} pulses/s  "
                f"ETA {eta}  rejected {self.rejected:,}")

    def draw(self, final: bool = False) -> None:
        now = time.perf_counter()
        if self.interactive:
            self.stream.write("\r" + self.line() + ("\n" if final else ""))
            self.stream.flush()
        elif not final and now - self._last_line >= self.line_every:
            self._last_line = now
            self.stream.write(self.line() + "\n")
            self.stream.flush()

    def _loop(self) -> None:
        while not self._stop.wait(self.every):
            self.poll()
            self.draw()

    def __enter__(self) -> "ProgressBar":
        self.draw()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.poll()
        if self.interactive:
            self.draw(final=True)
