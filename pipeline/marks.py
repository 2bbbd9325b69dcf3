"""A range's mark: the last file a range writes (its planned pulses, those rejected, and every file it wrote
with its size), what the progress bar counts and a resumed run trusts.

    mark_range_done(output, task, planned, rejected)   written last, atomically, by the range's worker
    range_is_complete(output, task)                    its mark there, and every file it lists at its size
    remove_range_files(output, task)                   a range to be redone loses what an earlier attempt left

A part without its mark is never trusted: a resumed run keeps a range whose mark and files are there, and
redoes every other from scratch. The names are pipeline.layout's.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.layout import FAULT_SUFFIX, progress_mark, range_files
from pipeline.records import ReadTask
from pipeline.sinks import remove_parts, write_json


MARK_COUNTS = ("pulses_decomposed", "echoes_kept", "echoes_spurious")  # what only the tables hold otherwise


def mark_range_done(output: str | Path, task: ReadTask, planned: int, rejected: int,
                    counts: dict[str, int] | None = None) -> Path:
    """The range's end: its planned pulses, those rejected, what it decomposed and kept (`counts`, MARK_COUNTS:
    a run without Parquet tables counts from them) and the files it wrote with their sizes (written last,
    atomically)."""
    written = {p.relative_to(output).as_posix(): p.stat().st_size for p in range_files(output, task) if p.exists()}
    return write_json(progress_mark(output, task.source.stem, task.start),
                      {"pulses": planned, "rejected": rejected, "counts": counts or {}, "files": written})


def counts_from_marks(output: str | Path, tasks: list[ReadTask]) -> dict[str, dict[str, int]]:
    """Per input name, MARK_COUNTS summed over its ranges' marks (those there: a range that did not end has none)."""
    totals: dict[str, dict[str, int]] = {}
    for task in tasks:
        try:
            counts = json.loads(progress_mark(output, task.source.stem, task.start).read_text()).get("counts", {})
        except (OSError, ValueError, AttributeError):
            continue
        into = totals.setdefault(task.source.name, dict.fromkeys(MARK_COUNTS, 0))
        for key in MARK_COUNTS:
            into[key] += int(counts.get(key, 0))
    return totals


def range_is_complete(output: str | Path, task: ReadTask) -> bool:
    """Whether a range ended (its mark is there) and every file it wrote is still there, at its size."""
    try:
        mark = json.loads(progress_mark(output, task.source.stem, task.start).read_text())
        return all((Path(output) / f).stat().st_size == size for f, size in mark["files"].items())
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def remove_range_files(output: str | Path, task: ReadTask) -> None:
    """A range to be redone loses what an earlier attempt left of it: a part without a mark is never trusted."""
    mark = progress_mark(output, task.source.stem, task.start)
    remove_parts(range_files(output, task) + [mark, mark.with_suffix(FAULT_SUFFIX)])
