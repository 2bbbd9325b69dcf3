"""Where a run's logs go: to logs/ under the output folder; the terminal gets our start line, a progress bar
and the summary, and of the rest only our warnings and anyone's errors (with --verbose, everything).

    quiet_imports()                 before Beam is imported: its import-time warnings go nowhere
    watched_logs(output, verbose)   the driver's: logs/driver.log, workers' prints to logs/workers.log
    log_to_file(output)             a worker's: logs/worker-<host>-<pid>.log
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
from pathlib import Path

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


def log_to_file(output: str | Path) -> None:
    """A worker's own log lines go to logs/ under the output folder (once per process and folder: a process
    that runs jobs for several folders, such as the driver's in-process jobs, logs each into its own)."""
    logger = logging.getLogger("fwl")
    logs = Path(output) / LOGS
    for h in [h for h in logger.handlers if getattr(h, "fwl_worker", None)]:
        if h.fwl_worker == str(logs) and Path(h.baseFilename).exists():  # not a replaced run's
            return
        logger.removeHandler(h)
        h.close()
    logs.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(logs / f"worker-{socket.gethostname()}-{os.getpid()}.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s %(message)s"))
    handler.fwl_worker = str(logs)
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False  # not to the runner's logging, which a terminal may show
