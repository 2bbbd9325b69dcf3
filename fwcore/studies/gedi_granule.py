"""GEDI L1B granules written in NASA's layout, for tests and benchmarks: beams of simulated shots (a ground
return with the transmitted pulse's extended Gaussian shape under a canopy of Gaussian layers, on the digitizer's
noise) with the variants real granules hold: shots without samples, stale returns, missing geolocation.

    write_granule(path, shots_per_beam, seed, beams=...) -> GranuleTruth (per shot: beam, shot number, ground
    sample, canopy top sample, what the reader must reject and why)
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

BEAMS = ("BEAM0000", "BEAM0001", "BEAM0010", "BEAM0011", "BEAM0101", "BEAM0110", "BEAM1000", "BEAM1011")
TX_SAMPLES = 128
NOISE_MEAN, NOISE_SD = 205.0, 3.3
METRES_PER_SAMPLE = 0.1499


@dataclasses.dataclass(frozen=True)
class GranuleTruth:
    beam: np.ndarray  # str per shot
    shot_number: np.ndarray
    ground_index: np.ndarray  # the ground return's centre, samples from the first
    top_index: np.ndarray
    reject: np.ndarray  # '' or "samples" | "stale" | "geolocation"


def _extended_gaussian(x, area, centre, sigma, gamma):
    from scipy.special import erfc

    spread = gamma * sigma * sigma
    return area * 0.5 * gamma * np.exp(gamma * (centre + 0.5 * spread - x)) * \
        erfc((centre + spread - x) / (np.sqrt(2.0) * sigma))


def _beam(rng: np.random.Generator, index: int, shots: int, samples: int, faults: bool) -> tuple[dict, dict]:
    count = np.full(shots, samples, dtype=np.uint16)
    ground = rng.uniform(0.55, 0.75, shots) * samples
    top = ground - rng.uniform(0, 200, shots)  # canopies of 0-30 m
    stale = np.zeros(shots, np.uint8)
    z0 = 800.0 + rng.normal(0, 5, shots).cumsum() * 0.1 + ground * METRES_PER_SAMPLE
    reject = np.full(shots, "", dtype=object)
    if faults and shots >= 4:
        count[1], reject[1] = 0, "samples"
        stale[2], reject[2] = 1, "stale"
        z0[3], reject[3] = np.nan, "geolocation"
    rx = []
    x = np.arange(samples, dtype=np.float64)
    for i in range(shots):
        if not count[i]:
            continue
        wave = _extended_gaussian(x, rng.uniform(3000, 15000), ground[i] - 4, 4.3, 0.13)
        for _ in range(rng.integers(0, 4) if ground[i] - top[i] > 20 else 0):  # canopy layers above the ground
            centre = rng.uniform(top[i], ground[i] - 10)
            wave += rng.uniform(10, 120) * np.exp(-0.5 * ((x - centre) / rng.uniform(4, 12)) ** 2)
        rx.append(wave + NOISE_MEAN + rng.normal(0, NOISE_SD, samples))
    tx_x = np.arange(TX_SAMPLES, dtype=np.float64)
    tx = [_extended_gaussian(tx_x, 20000.0, 50.0, 4.3, 0.13) + 205 + rng.normal(0, 2, TX_SAMPLES) for _ in range(shots)]
    lon0 = -44.14 + index * 0.005 + np.arange(shots) * 4e-4
    lat0 = -13.72 + np.arange(shots) * 5e-4
    start = np.r_[1, 1 + np.cumsum(count[:-1].astype(np.int64))].astype(np.uint64)
    start[count == 0] = 0
    shot_number = (np.uint64(19640100000000000 + index * 10**11) + np.arange(shots, dtype=np.uint64))
    group = {
        "shot_number": shot_number, "beam": np.full(shots, int(BEAMS[index][4:], 2), np.uint16),
        "rx_sample_count": count, "rx_sample_start_index": start,
        "rxwaveform": np.concatenate(rx).astype(np.float32) if rx else np.zeros(0, np.float32),
        "tx_sample_count": np.full(shots, TX_SAMPLES, np.uint16),
        "tx_sample_start_index": (1 + np.arange(shots) * TX_SAMPLES).astype(np.uint64),
        "txwaveform": np.concatenate(tx).astype(np.float32),
        "noise_mean_corrected": np.full(shots, NOISE_MEAN), "noise_stddev_corrected": np.full(shots, NOISE_SD),
        "stale_return_flag": stale, "tx_egsigma": np.full(shots, 4.3, np.float32),
        "tx_egsigma_error": np.full(shots, 0.004, np.float32), "tx_eggamma": np.full(shots, 0.13, np.float32),
        "tx_eggamma_error": np.full(shots, 0.0002, np.float32),
    }
    span = (count.astype(np.float64) - 1) * METRES_PER_SAMPLE
    geolocation = {
        "elevation_bin0": z0, "elevation_lastbin": z0 - span, "latitude_bin0": lat0, "latitude_lastbin": lat0 + 1e-7,
        "longitude_bin0": lon0, "longitude_lastbin": lon0 + 1e-7, "degrade": np.zeros(shots, np.int8),
        "local_beam_elevation": np.full(shots, 1.5, np.float32), "delta_time": 4.0e7 + np.arange(shots) * 0.0167,
    }
    return {**group, "geolocation": geolocation}, {"ground": ground, "top": top, "reject": reject,
                                                   "shot_number": shot_number}


def write_granule(path: str | Path, shots_per_beam: int, seed: int, beams: tuple[str, ...] = BEAMS,
                  samples: int = 800, faults: bool = True) -> GranuleTruth:
    """A granule of `beams`, `shots_per_beam` shots each, in GEDI L1B's layout; with `faults`, each beam's shots
    1, 2 and 3 have no samples, a stale return and no geolocation. Written a beam at a time: any size fits."""
    import h5py

    rng = np.random.default_rng(seed)
    truth = {"beam": [], "shot_number": [], "ground": [], "top": [], "reject": []}
    with h5py.File(path, "w") as f:
        for name in beams:
            group, known = _beam(rng, BEAMS.index(name), shots_per_beam, samples, faults)
            g = f.create_group(name)
            for key, value in group.pop("geolocation").items():
                g.create_dataset(f"geolocation/{key}", data=value)
            for key, value in group.items():
                g.create_dataset(key, data=value)
            truth["beam"].append(np.full(shots_per_beam, name))
            for key in ("shot_number", "ground", "top", "reject"):
                truth[key].append(known[key])
    joined = {k: np.concatenate(v) for k, v in truth.items()}
    return GranuleTruth(joined["beam"], joined["shot_number"].astype(np.int64), joined["ground"], joined["top"],
                        joined["reject"])
