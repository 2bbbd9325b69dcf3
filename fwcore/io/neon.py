"""Waveforms in the NEON CSV layout: `waveform_id, n_samples, s0, s1, ...`.

Valid samples are the non-zero ones; zeros are padding, and a zero gap
between two recorded segments keeps every valid sample at its own time.
NEON digitizes in 1 ns bins.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np

from fwcore.io.errors import ForeignCsvError, WaveformCsvError

NEON_SAMPLE_SPACING_PS = 1000.0
WANTED = "a NEON-layout waveform CSV (waveform_id, n_samples, s0, ...)"  # what the reader reads, in words


@dataclasses.dataclass(frozen=True)
class CsvWaveforms:
    waveform_id: np.ndarray  # int64
    samples: list[np.ndarray]  # float64, trailing padding removed
    valid: list[np.ndarray]  # bool


def read_neon_csv(path: str | Path) -> CsvWaveforms:
    """Read a NEON-layout waveform CSV; errors name the file, line and problem."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such waveform CSV")
    ids, samples, valid = [], [], []
    with open(path, "rb") as f:
        binary = b"\0" in f.read(64)  # no text holds a NUL: not even a first line to read
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        try:
            header = None if binary else next(reader, None)
        except (UnicodeDecodeError, csv.Error):
            header = None
        if not header or header[:3] != ["waveform_id", "n_samples", "s0"]:
            # another kind of file (a text file of another layout stays this message: fwcore.io.formats)
            raise ForeignCsvError(f"{path}: not a NEON waveform CSV (expected header waveform_id, n_samples, s0, ...)",
                                  path, WANTED)
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            try:
                values = np.array([float(v) if v not in ("", "NA") else np.nan for v in row[2:]])
                wid = int(float(row[0]))
            except ValueError as err:
                raise WaveformCsvError(f"{path}:{line}: unreadable value ({err})") from None
            present = (values != 0) & ~np.isnan(values)
            end = int(np.flatnonzero(present)[-1]) + 1 if present.any() else 0
            ids.append(wid)
            samples.append(values[:end])
            mask = values[:end] != 0  # NaN stays "valid" so that the engine reports it
            valid.append(mask)
    if not ids:
        raise WaveformCsvError(f"{path}: no waveforms")
    return CsvWaveforms(np.array(ids, dtype=np.int64), samples, valid)
