"""The dead letter's way out: Rejections (pipeline.records) into rejected/ Parquet files, one a range and one a
file, so that a bad file's rows stay bounded.

    write_rejections(output, task, rows)   a range's -> rejected/<stem>-<range>.parquet
    write_file_rejection(output, r)        a file that could not be planned -> rejected/<stem>.parquet
    write_empty_rejected(output, stems)    rejected/<stem>.parquet without rows for an input nothing of which was
                                           rejected (every input has its rejected/ table)
"""

from __future__ import annotations

from pathlib import Path

from pipeline.layout import REJECTED, part_name, rejected_files
from pipeline.records import ReadTask, Rejection
from pipeline.sinks import write_part
from pipeline.tables import empty_rejected_table, rejected_table


def write_rejections(output: str | Path, task: ReadTask, rows: list[Rejection]) -> Path:
    """A range's Rejections -> rejected/<stem>-<range>.parquet (one file per range, so a bad file stays bounded)."""
    rows = sorted(rows, key=lambda r: (r.pulse_id, r.stage))
    return write_part(rejected_table(rows), Path(output) / REJECTED, part_name(task.source.stem, task.start))


def write_file_rejection(output: str | Path, rejection: Rejection) -> Path:
    """A file that could not be planned -> rejected/<stem>.parquet."""
    return write_part(rejected_table([rejection]), Path(output) / REJECTED, rejection.stem)


def write_empty_rejected(output: Path, stems: list[str]) -> None:
    """rejected/<stem>.parquet without rows for every input of which nothing was rejected."""
    for stem in stems:
        if not any(p.exists() for p in rejected_files(output, stem)):
            write_part(empty_rejected_table(), output / REJECTED, stem)
