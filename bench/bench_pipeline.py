"""Pipeline benchmark: pulses/s end to end (DirectRunner, 2 workers) against the engine alone on 2 cores.

    python bench/bench_pipeline.py [--copies 109] [--generations 20 | --preset fast] [--workdir DIR]

Makes a file of copies x 924 pulses by repeating the Leica sample (shifted in
space and time, each copy its own packets), then times (1) the engine alone:
decompose_batch over all pulses on 2 numba threads, and (2) `fwl run` on the
file with --formats parquet,las. Peak memory is the largest sum of RSS over
the process and all its children, sampled every 0.2 s.
"""

from __future__ import annotations

import abc
import argparse
import dataclasses
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

from fwcore.engine.config import PRESETS, DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.io import PulseBatch, input_summary, read_pulses
from fwcore.io.writer import write_waveform_las
from fwcore.pulses import pulse_waveforms
from fwcore.instrument.measure import file_system_pulse

SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"


def repeated(pulses: PulseBatch, copies: int) -> PulseBatch:
    """The pulses `copies` times, copy k shifted by k x 100 m in x and by k x the time span."""
    span = float(np.ptp(pulses.gps_time)) + 1.0
    n, m = len(pulses), pulses.return_xyz.shape[0]

    def tile(a):
        return np.concatenate([a] * copies)

    shift_pulse = np.repeat(np.arange(copies), n)
    shift_return = np.repeat(np.arange(copies), m)
    anchor = tile(pulses.anchor) + np.stack([shift_pulse * 100.0, np.zeros(n * copies), np.zeros(n * copies)], 1)
    returns = tile(pulses.return_xyz) + np.stack([shift_return * 100.0, np.zeros(m * copies), np.zeros(m * copies)], 1)

    def offsets(o):
        return np.concatenate([[0], np.cumsum(np.tile(np.diff(o), copies))])

    # per row or per return where the file records them (the Leica sample: each return's number_of_returns)
    optional = {name: tile(getattr(pulses, name)) for name in ("number_of_returns", "sensor_location_ps", "rgb", "nir")
                if getattr(pulses, name) is not None}
    return dataclasses.replace(
        pulses, **optional, pulse_id=np.arange(n * copies), packet_offset=tile(pulses.packet_offset),
        descriptor_index=tile(pulses.descriptor_index), classification=tile(pulses.classification),
        channel=tile(pulses.channel), segment=tile(pulses.segment),
        gps_time=tile(pulses.gps_time) + shift_pulse * span, anchor=anchor,
        anchor_location_ps=tile(pulses.anchor_location_ps), direction=tile(pulses.direction),
        scan_angle=tile(pulses.scan_angle), point_source_id=tile(pulses.point_source_id),
        scan_direction_flag=tile(pulses.scan_direction_flag), edge_of_flight_line=tile(pulses.edge_of_flight_line),
        user_data=tile(pulses.user_data), sample_spacing_ps=tile(pulses.sample_spacing_ps),
        digitizer_gain=tile(pulses.digitizer_gain), digitizer_offset=tile(pulses.digitizer_offset),
        bits_per_sample=tile(pulses.bits_per_sample), samples=tile(pulses.samples),
        sample_offsets=offsets(pulses.sample_offsets), return_xyz=returns, return_number=tile(pulses.return_number),
        return_intensity=tile(pulses.return_intensity), return_location_ps=tile(pulses.return_location_ps),
        return_offsets=offsets(pulses.return_offsets))


class Sampler(abc.ABC):
    """Calls `sample()` every `every` seconds in a thread while the `with` block runs."""

    every = 0.2

    def __init__(self):
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    @abc.abstractmethod
    def sample(self) -> None:
        """One measurement (a subclass's)."""

    def _loop(self):
        while not self._stop.is_set():
            self.sample()
            time.sleep(self.every)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


class PeakMemory(Sampler):
    """Largest total RSS of this process and its children (Beam's workers), sampled in a thread."""

    def __init__(self):
        super().__init__()
        self.peak = 0
        self._me = psutil.Process()

    def sample(self):
        total = 0
        for p in [self._me, *self._me.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        self.peak = max(self.peak, total)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=109, help="924 pulses each (109: 100,716 pulses)")
    parser.add_argument("--generations", type=int, default=20, help="MDE's G (without --preset)")
    parser.add_argument("--preset", choices=sorted(PRESETS), help="a named configuration instead of MDE at G")
    parser.add_argument("--workdir", default=None)
    args = parser.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="fwl-bench-"))
    sample = read_pulses(SAMPLE)
    big = repeated(sample, args.copies)
    path = write_waveform_las(work / "flight.las", big, "las13-wdp", 8)
    if args.preset:
        base, method = PRESETS[args.preset].config(), f"preset {args.preset}"
    else:
        base, method = DecompositionConfig(generations=args.generations), f"MDE NP 60, G {args.generations}"
    system = file_system_pulse(path, input_summary(path).records, base)  # what fwl run measures on the file
    config = base
    print(f"{len(big)} pulses in {path} ({path.stat().st_size / 1e6:.0f} MB + "
          f"{path.with_suffix('.wdp').stat().st_size / 1e6:.0f} MB packets); {method}, "
          f"model {system.echo_model(config.model).value}")

    pulses = read_pulses(path)
    decompose_batch(pulse_waveforms(pulses, 0), config.replace(generations=1), system, threads=2)  # compile
    with PeakMemory() as engine_memory:
        start = time.perf_counter()
        decompose_batch(pulse_waveforms(pulses, 0), config, system, threads=2)
        engine = len(pulses) / (time.perf_counter() - start)
    del pulses

    from pipeline.run import run
    with PeakMemory() as pipeline_memory:
        start = time.perf_counter()
        summary = run([str(path)], work / "out", base, ("parquet", "las"), points_per_range=5000, watch=False)
        pipeline = summary["counts"]["pulses_read"] / (time.perf_counter() - start)
    print(f"{'':34} {'pulses/s':>9} {'peak RSS MiB':>13}")
    print(f"{'engine alone, 2 threads':34} {engine:9.1f} {engine_memory.peak / 2**20:13.0f}")
    print(f"{'fwl run, DirectRunner 2 workers':34} {pipeline:9.1f} {pipeline_memory.peak / 2**20:13.0f}")
    print(f"pipeline / engine: {pipeline / engine:.0%} (pulses read {summary['counts']['pulses_read']}, "
          f"decomposed {summary['counts']['pulses_decomposed']})")


if __name__ == "__main__":
    main()
