"""Viewer benchmark: how long the page's requests take on a run of N echoes (default one million).

    python bench/bench_view.py [--echoes 1000000] [--repeat 3] [--workdir DIR]

The run folder is made here: echo and pulse tables in the schema `fwl run`
writes, 10,000 echoes per part file, positions spread over a 2 km x 2 km
block (decomposing a million echoes for a timing of the queries would take
an hour on this machine). The viewer then serves it in this process, and
each request the page makes is timed end to end over HTTP (best of
--repeat, the server's answer cache emptied before each): the whole map, a
zoomed box, the 3D sample, the summary, the pulse list. Bytes are the JSON
the page receives.

Then the server under load: --parallel map requests at once (the same view,
as many pages reloading, and as many different boxes), their latencies'
median, 95th percentile and worst, and how many were not answered 200; and
one request's time while --idle connections are open and silent.
"""

from __future__ import annotations

import argparse
import http.client
import json
import socket
import tempfile
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.view.server import make_server, serve_in_thread, url_of

PART_ECHOES = 10_000
ECHOES_PER_PULSE = 4


def make_run(folder: Path, n_echoes: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    (folder / "echoes").mkdir(parents=True)
    (folder / "pulses").mkdir()
    n_pulses = n_echoes // ECHOES_PER_PULSE
    for part, first in enumerate(range(0, n_pulses, PART_ECHOES // ECHOES_PER_PULSE)):
        pulse_id = np.arange(first, min(n_pulses, first + PART_ECHOES // ECHOES_PER_PULSE), dtype=np.int64)
        n = pulse_id.size * ECHOES_PER_PULSE
        owner = np.repeat(pulse_id, ECHOES_PER_PULSE)
        ground = rng.normal(100.0, 5.0, pulse_id.size)
        kept = rng.random(n) < 0.7
        echoes = pa.table({
            "source_file": ["flight.las"] * n, "pulse_id": owner,
            "gps_time": owner * 1e-5, "echo_index": np.tile(np.arange(ECHOES_PER_PULSE, dtype=np.int32), pulse_id.size),
            "echo_count": np.full(n, ECHOES_PER_PULSE, np.int32),
            "time_ps": rng.uniform(0, 2e5, n), "amplitude": rng.gamma(2.0, 20.0, n),
            "sigma_chauve": rng.uniform(1e3, 3e3, n),
            "alpha": rng.uniform(1.0, 2.6, n), "fwhm_ps": rng.uniform(2e3, 8e3, n), "energy": rng.uniform(1e4, 1e6, n),
            "x": np.repeat(rng.uniform(0, 2000, pulse_id.size), ECHOES_PER_PULSE),
            "y": np.repeat(rng.uniform(0, 2000, pulse_id.size), ECHOES_PER_PULSE),
            "z": np.repeat(ground, ECHOES_PER_PULSE) + rng.uniform(0, 25, n),
            "kept": kept, "reject_reason": np.where(kept, "", "weak").tolist(),
            "fit_error": np.repeat(rng.gamma(2.0, 50.0, pulse_id.size), ECHOES_PER_PULSE),
            "rmse": np.ones(n), "r2": np.full(n, 0.99),
        })
        pq.write_table(echoes, folder / "echoes" / f"flight-{part:012d}.parquet")
        n_kept = np.add.reduceat(kept, np.arange(0, n, ECHOES_PER_PULSE))
        pulses = pa.table({
            "source_file": ["flight.las"] * pulse_id.size, "pulse_id": pulse_id, "gps_time": pulse_id * 1e-5,
            "fit_error": echoes["fit_error"].to_numpy()[::ECHOES_PER_PULSE], "rmse": np.ones(pulse_id.size),
            "r2": rng.uniform(0.9, 1.0, pulse_id.size), "n_echoes": np.full(pulse_id.size, ECHOES_PER_PULSE, np.int32),
            "n_echoes_kept": n_kept.astype(np.int32), "n_system_returns": np.ones(pulse_id.size, np.int32),
            "system_pulse_fwhm_ps": np.full(pulse_id.size, 4000.0),
        })
        pq.write_table(pulses, folder / "pulses" / f"flight-{part:012d}.parquet")
    counts = {"pulses_read": n_pulses, "pulses_decomposed": n_pulses, "pulses_rejected": 0, "files_rejected": 0,
              "echoes_kept": None, "echoes_spurious": None}
    (folder / "run.json").write_text(json.dumps({"inputs": [], "points_per_range": 5000, "config": {},
                                                 "counts": counts, "seconds": None}))


def timed(url: str, repeat: int, server) -> tuple[float, int]:
    best, size = float("inf"), 0
    for _ in range(repeat):
        server.viewer.answers.clear()  # the tables read again, not the last answer
        start = time.perf_counter()
        with urllib.request.urlopen(url, timeout=600) as r:
            size = len(r.read())
        best = min(best, time.perf_counter() - start)
    return best, size


def _get(host: str, port: int, path: str) -> tuple[int, float]:
    start = time.perf_counter()
    try:
        con = http.client.HTTPConnection(host, port, timeout=120)
        con.request("GET", path)
        response = con.getresponse()
        response.read()
        con.close()
        return response.status, time.perf_counter() - start
    except OSError:  # reset or refused: what a short listen backlog gives
        return 0, time.perf_counter() - start


def load(server, parallel: int, idle: int) -> None:
    host, port = server.server_address[:2]
    server.viewer.answers.clear()
    same = ["/api/echoes?run=0/&colour=height&limit=60000"] * parallel
    boxes = [f"/api/echoes?run=0/&colour=height&limit=20000&box={x},{x + 400},{y},{y + 400}"
             for x, y in ((100 * (i % 16), 100 * (i // 16 % 16)) for i in range(parallel))]
    print(f"\n{parallel} map requests at once     {'median s':>9} {'p95 s':>7} {'worst s':>8} {'not 200':>8} "
          f"{'all s':>6}")
    for name, paths in (("the same view", same), ("different boxes", boxes)):
        start = time.perf_counter()
        with ThreadPoolExecutor(parallel) as pool:
            answers = list(pool.map(lambda p: _get(host, port, p), paths))
        seconds = np.array([s for _, s in answers])
        failed = sum(status != 200 for status, _ in answers)
        print(f"  {name:29} {np.median(seconds):9.2f} {np.percentile(seconds, 95):7.2f} {seconds.max():8.2f} "
              f"{failed:8d} {time.perf_counter() - start:6.1f}")
    sockets = [socket.create_connection((host, port), timeout=30) for _ in range(idle)]
    status, seconds = _get(host, port, "/api/summary?run=0/")
    print(f"one request with {idle} idle connections open: {status} in {seconds:.2f} s")
    for s in sockets:
        s.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--echoes", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workdir")
    parser.add_argument("--parallel", type=int, default=200, help="map requests at once")
    parser.add_argument("--idle", type=int, default=300, help="silent connections held open")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        run = Path(tmp) / "run"
        began = time.perf_counter()
        make_run(run, args.echoes)
        print(f"made a run of {args.echoes} echoes in {time.perf_counter() - began:.1f} s")
        server = make_server([run], port=0, runs_dir=Path(tmp) / "runs")
        serve_in_thread(server)
        base = url_of(server) + "api/"
        requests = [
            ("map, whole run (60,000 echoes)", "echoes?run=0/&colour=height&limit=60000"),
            ("map, zoomed 200 m box", "echoes?run=0/&colour=amplitude&box=900,1100,900,1100&limit=60000"),
            ("3D sample (25,000 echoes)", "echoes?run=0/&colour=height&limit=25000"),
            ("run summary", "summary?run=0/"),
            ("pulse list (40, worst fit)", "pulses?run=0/&order=fit_error&limit=40"),
        ]
        print(f"{'request':34} {'seconds':>8} {'KB':>8}")
        for name, path in requests:
            seconds, size = timed(base + path, args.repeat, server)
            print(f"{name:34} {seconds:8.3f} {size / 1e3:8.0f}")
        load(server, args.parallel, args.idle)
        server.shutdown()
        server.server_close()


if __name__ == "__main__":
    main()
