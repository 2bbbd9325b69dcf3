"""COPC sink benchmark: copc/<stem>.copc.laz against las/<stem>.las from the same range parts, echoes/s and peak
memory, for flights of growing size.

    python bench/bench_copc.py [--sizes 20000,200000,2000000] [--workdir DIR]

For each size, the LAS parts of a flight of that many pulses are written first (not timed) by the range
stage's own writer (fwcore.io.writer.write_point_cloud), 5,000 pulses a part as `fwl run` writes them: a
flight line 60 m/s, 100 kHz, a 300 m zigzag swath over terrain and canopy, 1-4 echoes a pulse (2.1 on
average, as the 200,000-pulse simulated flight's 422,133 echoes), every Extra Bytes column of the run. Each
sink then assembles the parts in a fresh process: the LAS sink (pipeline.sinks.assemble_las, uncompressed
and LAZ) and the COPC sink (pipeline.copc.assemble_copc); the time is the assembly's, the peak memory the
process's maximum RSS (with its imports: about 100 MiB of Python, numpy, laspy and copclib).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PULSES_PER_PART = 5000
PULSE_RATE_HZ, SPEED_M_S, SWATH_M, SCAN_HZ = 100_000, 60.0, 300.0, 50.0


def flight_echoes(first: int, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The echoes of pulses first..first+n of the synthetic flight, in pulse order, with the run's columns."""
    t = (first + np.arange(n)) / PULSE_RATE_HZ
    x = 500_000.0 + SPEED_M_S * t
    y = 5_500_000.0 + SWATH_M / 2 * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * SCAN_HZ * t))
    ground = 300.0 + 10 * np.sin(x / 200.0) + 5 * np.cos(y / 150.0)
    returns = np.minimum(rng.geometric(0.48, n), 4)
    pulse = np.repeat(np.arange(n), returns)
    index = np.arange(pulse.size) - np.repeat(np.cumsum(returns) - returns, returns)
    canopy = rng.uniform(2, 30, n)[pulse]
    z = ground[pulse] + np.where(index == returns[pulse] - 1, 0.0, canopy * (1 - index / returns[pulse]))
    m = pulse.size
    return {"x": x[pulse] + rng.normal(0, 0.05, m), "y": y[pulse] + rng.normal(0, 0.05, m), "z": z,
            "gps_time": t[pulse], "return_number": index + 1, "number_of_returns": returns[pulse],
            "intensity": rng.integers(0, 4000, m), "scan_angle": (y[pulse] - 5_500_000.0) / 500.0 * 57.3,
            "scan_direction_flag": np.zeros(m, int), "edge_of_flight_line": np.zeros(m, int),
            "point_source_id": np.ones(m, int), "user_data": np.zeros(m, int),
            "amplitude": rng.uniform(5, 200, m), "echo_width": rng.uniform(3000, 9000, m),
            "alpha": np.full(m, np.sqrt(2)), "echo_energy": rng.uniform(1e4, 1e6, m),
            "fit_error": rng.uniform(10, 300, m), "channel": np.zeros(m), "range_m": rng.uniform(480, 560, m),
            "incidence_deg": rng.uniform(0, 40, m), "backscatter_cross_section_m2": rng.uniform(0, 1, m),
            "backscatter_coefficient": rng.uniform(0, 1, m), "reflectance": rng.uniform(0, 1, m),
            "radiometry": np.full(m, "relative")}


def write_parts(folder: Path, pulses: int) -> list[Path]:
    from fwcore.io.writer import write_point_cloud

    import laspy
    import pyproj

    template = folder / "template.las"
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.full(3, 0.001), np.array([500_000.0, 5_500_000.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(25832))
    laspy.LasData(header).write(template)
    rng = np.random.default_rng(7)
    parts = []
    for first in range(0, pulses, PULSES_PER_PART):
        part = folder / "parts" / f"flight-{first:012d}.las"
        write_point_cloud(part, template, flight_echoes(first, min(PULSES_PER_PART, pulses - first), rng))
        parts.append(part)
    return parts


def sink(kind: str, parts_folder: str, path: str) -> None:
    """Run one sink over the parts (in a fresh process: its peak RSS is the sink's); print its seconds."""
    parts = sorted(Path(parts_folder).glob("flight-*.las"))
    import laspy  # noqa: F401  imports before the clock, as a worker has them
    from pipeline.copc import assemble_copc
    from pipeline.sinks import assemble_las

    began = time.perf_counter()
    if kind == "copc":
        assemble_copc(parts, Path(path))
    else:
        assemble_las(parts, Path(path), laz=kind == "laz")
    print(time.perf_counter() - began)


def measure(kind: str, parts: Path, out: Path) -> tuple[float, float]:
    """(seconds, peak RSS MiB) of one sink in its own process."""
    child = subprocess.Popen([sys.executable, __file__, "--sink", kind, str(parts), str(out)],
                             stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    output = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    if status:
        raise RuntimeError(f"the {kind} sink failed")
    return float(output.split()[-1]), usage.ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", default="20000,200000,2000000")
    parser.add_argument("--workdir")
    parser.add_argument("--sink", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.sink:
        return sink(*args.sink)
    print("| pulses | echoes | sink | s | echoes/s | peak MiB | file MiB |")
    print("| ---: | ---: | --- | ---: | ---: | ---: | ---: |")
    for pulses in (int(s) for s in args.sizes.split(",")):
        with tempfile.TemporaryDirectory(dir=args.workdir) as work:
            work = Path(work)
            parts = write_parts(work, pulses)
            import laspy
            echoes = sum(laspy.open(p).header.point_count for p in parts)
            for kind, name in (("las", "flight.las"), ("laz", "flight.laz"), ("copc", "flight.copc.laz")):
                seconds, peak = measure(kind, parts[0].parent, work / kind / name)
                size = (work / kind / name).stat().st_size / 2**20
                print(f"| {pulses:,} | {echoes:,} | {kind} | {seconds:.2f} | {echoes / seconds:,.0f} | {peak:.0f} "
                      f"| {size:.1f} |", flush=True)


if __name__ == "__main__":
    main()
