"""Reading benchmark: pulses/s and MB/s of fwcore.io.read_pulses, one core, per encoding.

    flock $LOCK python bench/bench_read.py [--repeat N] [--copies K]

Inputs: the Leica sample as .las+.wdp and .laz+.wdz (924 pulses each); the Leica
sample tiled K times and written by our writer as LAS 1.3 + .wdp and as LAS 1.4
with internal packets (the per-file costs of opening vanish there); every
PulseWaves sample. A read is a whole file as one range: points/pulses, packets
or waves, samples and geolocation inputs. MB/s counts the point/pulse file plus
its packet file. The first read (numba compilation, page cache) is not timed.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from fwcore.io import read_pulses  # noqa: E402
from fwcore.io.writer import write_waveform_las  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "examples" / "data"
PULSEWAVES = ("las13fwf_example1", "geolas_example1", "lvis_example1", "optech_example1", "riegl_example3")


def tiled(pulses, copies: int):
    """The sample repeated `copies` times, each copy shifted 100 m east and later in time."""
    n, m = len(pulses), pulses.return_xyz.shape[0]
    span = float(np.ptp(pulses.gps_time)) + 1.0

    def tile(a):
        return np.concatenate([a] * copies)

    def offsets(o):
        return np.concatenate([[0], np.cumsum(np.tile(np.diff(o), copies))])

    shift_p, shift_r = np.repeat(np.arange(copies), n) * 100.0, np.repeat(np.arange(copies), m) * 100.0
    per_pulse = ("pulse_id", "packet_offset", "descriptor_index", "anchor_location_ps", "direction", "scan_angle",
                 "point_source_id", "scan_direction_flag", "edge_of_flight_line", "user_data", "sample_spacing_ps",
                 "digitizer_gain", "digitizer_offset", "bits_per_sample", "classification", "channel", "segment")
    return dataclasses.replace(
        pulses, **{f: tile(getattr(pulses, f)) for f in per_pulse},
        gps_time=tile(pulses.gps_time) + np.repeat(np.arange(copies), n) * span,
        anchor=tile(pulses.anchor) + np.c_[shift_p, np.zeros((n * copies, 2))],
        samples=tile(pulses.samples), sample_offsets=offsets(pulses.sample_offsets),
        return_xyz=tile(pulses.return_xyz) + np.c_[shift_r, np.zeros((m * copies, 2))],
        return_number=tile(pulses.return_number), return_intensity=tile(pulses.return_intensity),
        return_location_ps=tile(pulses.return_location_ps), return_offsets=offsets(pulses.return_offsets))


def measure(path: Path, packets: list[Path], repeat: int) -> tuple[int, float, float]:
    """(pulses, pulses/s, MB/s), best of `repeat`."""
    read_pulses(path)
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        batch = read_pulses(path)
        best = min(best, time.perf_counter() - start)
    pulses = np.unique(batch.pulse_id).size
    size = sum(p.stat().st_size for p in [path, *packets]) / 1e6
    return pulses, pulses / best, size / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--copies", type=int, default=100, help="tiles of the Leica sample for the large LAS rows")
    args = parser.parse_args()
    leica = DATA / "leica_als"
    rows = [("leica_a .las+.wdp", leica / "leica_a.las", [leica / "leica_a.wdp"]),
            ("leica_a .laz+.wdz", leica / "leica_a.laz", [leica / "leica_a.wdz"])]
    with tempfile.TemporaryDirectory() as tmp:
        big = tiled(read_pulses(leica / "leica_a.las"), args.copies)
        wdp = write_waveform_las(Path(tmp) / "tiled13.las", big, "las13-wdp")
        internal = write_waveform_las(Path(tmp) / "tiled14.las", big, "las14-internal")
        rows += [(f"leica x{args.copies} .las+.wdp", wdp, [wdp.with_suffix(".wdp")]),
                 (f"leica x{args.copies} LAS 1.4 internal", internal, [])]
        rows += [(f"{name} .pls+.wvs", DATA / "pulsewaves" / f"{name}.pls", [DATA / "pulsewaves" / f"{name}.wvs"])
                 for name in PULSEWAVES]
        print(f"{'input':30} {'pulses':>8} {'pulses/s':>10} {'MB/s':>7}")
        for label, path, packets in rows:
            pulses, rate, mbs = measure(path, packets, args.repeat)
            print(f"{label:30} {pulses:8d} {rate:10.0f} {mbs:7.1f}")


if __name__ == "__main__":
    main()
