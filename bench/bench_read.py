"""Reading benchmark: pulses/s and MB/s for the Leica sample as LAS+WDP and LAZ+WDZ.

    python bench/bench_read.py [--repeat N]

MB/s counts the bytes of the point file plus its packet file. The first read
(numba compilation of the .wdz decoder) is not timed.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fwcore.io import read_pulses

DATA = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(f"{'input':16} {'pulses':>7} {'pulses/s':>10} {'MB/s':>7}")
    for points, packets in (("leica_a.las", "leica_a.wdp"), ("leica_a.laz", "leica_a.wdz")):
        read_pulses(DATA / points)
        best = float("inf")
        for _ in range(args.repeat):
            start = time.perf_counter()
            pulses = read_pulses(DATA / points)
            best = min(best, time.perf_counter() - start)
        size = ((DATA / points).stat().st_size + (DATA / packets).stat().st_size) / 1e6
        print(f"{points + '+' + packets[-3:]:16} {len(pulses):7d} {len(pulses) / best:10.0f} {size / best:7.1f}")


if __name__ == "__main__":
    main()
