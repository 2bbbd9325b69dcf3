"""The engine on every sensor it reads, with Sylva beside on every file Sylva reads: one table.

    python bench/bench_sensors.py [--shots 600] [--only leica,riegl,...] [--workdir DIR]

One thread each, read outside the timing, after compilation, the fastest of 3 decompositions (bench_engine.timed;
Sylva: bench_instrument.sylva_rate, sylva-rs with RAYON_NUM_THREADS=1, in the same process). Per file: shots
decomposed, the median samples a shot, the model `--model auto` chooses, our default's and `fast`'s shots/s, the
default's model evaluations and kept echoes a shot, Sylva's shots/s and echoes a shot on the same file where it
reads it (LAS and PulseWaves), or on the same pulses written as PulseWaves (GEDI's and LVIS's HDF5:
fwcore.io.pulsewaves_writer, GEDI's float samples rounded to whole DN; not NEON's CSV), and the ratios.

Files: the Leica sample (LAS 1.3); RIEGL Q680, Optech, GeoLas and LVIS in PulseWaves (the bundled samples: LVIS's
is a real 432-sample LVIS flight line in PulseWaves, which Sylva reads); a RIEGL-like 16-bit LAS 1.4 flight
(bench_instrument.write_riegl_like); NEON's CSV waveforms; the shared LVIS L1B of tropical forest (Mondah, 1024
samples) repeated to `--shots`; the bundled GEDI L1B's real savanna beams (its first `--shots`); a GEDI granule
of simulated tall forest (bench_long.repeat_gedi, 15-60 m canopies, `--shots` shots).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("RAYON_NUM_THREADS", "1")  # Sylva's thread pool, read when it is first imported

import sys  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_engine import timed  # noqa: E402
from bench_instrument import config_of, sylva_rate, write_riegl_like  # noqa: E402
from bench_long import GEDI_L1B, repeat_gedi, repeat_lvis  # noqa: E402
from fwcore.engine.config import DecompositionConfig  # noqa: E402
from fwcore.engine.records import WaveformBatch  # noqa: E402
from fwcore.instrument.measure import csv_system_pulse, file_system_pulse  # noqa: E402
from fwcore.instrument.pulse import PulseOverrides, SystemPulse  # noqa: E402
from fwcore.io import PointRange, read_pulses  # noqa: E402
from fwcore.io.neon import read_neon_csv  # noqa: E402
from fwcore.io.pulsewaves_writer import write_pulsewaves  # noqa: E402
from fwcore.pulses import pulse_waveforms  # noqa: E402
from fwcore.rng import pulse_seed  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
PULSEWAVES = DATA / "pulsewaves"
LVIS_MONDAH = DATA / "lvis" / "LVIS_Mondah_level1b.SPLIT.8.h5"


@dataclass(frozen=True)
class Case:
    """One row: what a user would call the sensor, how the file was made, and the batch both engines see."""

    sensor: str
    source: str
    batch: WaveformBatch
    pulse: SystemPulse  # `--model auto`'s choice for the file, as fwl run measures it
    sylva_reads: Path | None  # the file Sylva decomposes, where it reads the format


def file_case(sensor: str, source: str, path: Path, shots: int | None, sylva: bool, export: Path | None = None
              ) -> Case:
    """A file as fwl run reads it: its first `shots` pulses, the system pulse measured on it. Sylva decomposes the
    file itself (`sylva`), or, for formats it does not read, the same pulses written as PulseWaves to `export`
    (fwcore.io.pulsewaves_writer; samples rounded to whole DN: GEDI's are float)."""
    pulses = read_pulses(PointRange(str(path), 0, shots) if shots else path)
    pulse = file_system_pulse(path, len(pulses), config_of("default", "auto"))
    if export is not None:
        write_pulsewaves(export, pulses, round_samples=True)
    return Case(sensor, source, pulse_waveforms(pulses, 0), pulse, path if sylva else export)


def neon_case() -> Case:
    """NEON's CSV waveforms (1 ns), the pulse measured on the returns alone as `fwl run` does without --outgoing."""
    waveforms = read_neon_csv(DATA / "neon_harvard" / "return_waveforms.csv")
    batch = WaveformBatch.from_waveforms(waveforms.samples, 1000.0,
                                         [pulse_seed(0, int(i)) for i in waveforms.waveform_id], waveforms.valid)
    pulse = csv_system_pulse(waveforms.samples, waveforms.valid, 1000.0, DecompositionConfig(), PulseOverrides(),
                             None)
    return Case("NEON (Optech Gemini)", "examples/data/neon_harvard CSV", batch, pulse, None)


def cases(work: Path, shots: int, only: set[str]) -> list[tuple[str, callable]]:
    """The rows, each made only when asked for (its key in `only`)."""
    made = [
        ("leica", lambda: file_case("Leica ALS", "leica_a.las (LAS 1.3, .wdp)", DATA / "leica_als" / "leica_a.las",
                                    None, True)),
        ("riegl", lambda: file_case("RIEGL Q680", "riegl_example3.pls", PULSEWAVES / "riegl_example3.pls", None,
                                    True)),
        ("riegl-las", lambda: file_case("RIEGL-like, 16 bit", "simulated LAS 1.4 (write_riegl_like)",
                                        write_riegl_like(work / "riegl_like.las"), None, True)),
        ("optech", lambda: file_case("Optech", "optech_example1.pls", PULSEWAVES / "optech_example1.pls", None,
                                     True)),
        ("geolas", lambda: file_case("GeoLas", "geolas_example1.pls", PULSEWAVES / "geolas_example1.pls", None,
                                     True)),
        ("neon", neon_case),
        ("lvis-pls", lambda: file_case("LVIS", "lvis_example1.pls (PulseWaves, 432 samples)",
                                       PULSEWAVES / "lvis_example1.pls", None, True)),
        ("lvis", lambda: file_case("LVIS, tropical forest", f"Mondah L1B (1024 samples) repeated to {shots}",
                                   _made(work / "lvis_mondah.h5", lambda p: repeat_lvis(LVIS_MONDAH, p, shots)),
                                   None, False, work / "lvis_mondah.pls")),
        ("gedi", lambda: file_case("GEDI, savanna", "bundled L1B's real beams", GEDI_L1B, None, False,
                                   work / "gedi_savanna.pls")),
        ("gedi-tall", lambda: file_case("GEDI, tall forest", f"simulated 15-60 m canopies, {shots} shots",
                                        _made(work / "gedi_tall.h5",
                                              lambda p: repeat_gedi(GEDI_L1B, p, shots, tall=True)), None, False,
                                        work / "gedi_tall.pls")),
    ]
    return [(key, make) for key, make in made if not only or key in only]


def _made(path: Path, write) -> Path:
    write(path)
    return path


def row(case: Case) -> str:
    """The case decomposed by both, as one table row."""
    lengths = np.diff(case.batch.offsets)
    result, default_rate = timed(case.batch, config_of("default", "auto"), case.pulse)
    _, fast_rate = timed(case.batch, config_of("fast", "auto"), case.pulse)
    n = len(result)
    kept = (result.reject == 0).sum() / n
    sylva = sylva_rate(case.sylva_reads) if case.sylva_reads else None
    theirs = f"{sylva[0]:10,.0f} {sylva[1]:6.2f} {default_rate / sylva[0]:7.2f}x {fast_rate / sylva[0]:7.2f}x" \
        if sylva else f"{'-':>10} {'-':>6} {'-':>8} {'-':>8}"
    return (f"| {case.sensor:24} | {case.source:48} | {n:6d} | {int(np.median(lengths)):5d} | {case.pulse.model:11} | "
            f"{default_rate:9,.0f} | {fast_rate:9,.0f} | {result.nfev.mean():6.1f} | {kept:5.2f} | {theirs} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shots", type=int, default=600, help="shots of the LVIS and GEDI HDF5 files")
    parser.add_argument("--only", default="", help="comma-separated keys: leica, riegl, riegl-las, optech, geolas, "
                                                  "neon, lvis-pls, lvis, gedi, gedi-tall")
    parser.add_argument("--workdir", type=Path, default=None)
    args = parser.parse_args()
    only = {k for k in args.only.split(",") if k}
    work = args.workdir or Path(tempfile.mkdtemp(prefix="fwl-sensors-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"one thread each, the fastest of 3; Sylva: sylva-rs, RAYON_NUM_THREADS={os.environ['RAYON_NUM_THREADS']}")
    print(f"| {'sensor':24} | {'file':48} | {'shots':>6} | {'samples':>5} | {'model':11} | {'default/s':>9} | "
          f"{'fast/s':>9} | {'evals':>6} | {'kept':>5} | {'Sylva/s':>10} {'echoes':>6} {'default':>8} {'fast':>8} |")
    for _, make in cases(work, args.shots, only):
        print(row(make()), flush=True)
    with open("/proc/loadavg") as f:
        print(f"load {f.read().strip()}")


if __name__ == "__main__":
    main()
