"""The driver's progress bar: pulses done of the planned total, counted from the marks ranges leave when they
end (pipeline.marks), drawn in place on a terminal or as a line now and then elsewhere. Where the logs go is
pipeline.logs."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Iterable, TextIO


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
