"""LVIS L1B files written from the product's data dictionary (LFID, SHOTNUMBER, TIME, LON0/LAT0/Z0, LON<k>/LAT<k>/
Z<k>, INCIDENTANGLE, SIGMEAN, TXWAVE, RXWAVE), with a forest's waveform per shot: canopy, then the ground."""

import h5py
import numpy as np

STEP_M = 0.15  # 1 ns of two-way travel at nadir


def write_lvis(path, shots: int, samples: int = 1024, tx_samples: int = 128, seed: int = 0, east_of_180=False,
               with_sigmean=True, bad_shot: int | None = None, lfid=1411500, shot_number=None) -> dict:
    """A file of `shots` shots; the truth per shot (ground sample, canopy top sample) is returned."""
    rng = np.random.default_rng(seed)
    x = np.arange(samples, dtype=np.float64)
    ground = rng.uniform(0.6, 0.8, shots) * samples
    top = ground - rng.uniform(60, 200, shots)
    rx = np.empty((shots, samples))
    for i in range(shots):
        wave = 400 * np.exp(-0.5 * ((x - ground[i]) / 3.0) ** 2)
        wave += 80 * np.exp(-0.5 * ((x - (top[i] + 15)) / 8.0) ** 2)
        rx[i] = wave + 100 + rng.normal(0, 2.0, samples)
    tx = 500 * np.exp(-0.5 * ((np.arange(tx_samples) - 30) / 3.0) ** 2) + 100
    z0 = 300.0 + ground * STEP_M + rng.normal(0, 0.5, shots)
    lon = (-105.5 + np.arange(shots) * 1e-4) % 360 if east_of_180 else -105.5 + np.arange(shots) * 1e-4
    last = samples - 1
    with h5py.File(path, "w") as f:
        f["LFID"] = np.broadcast_to(np.asarray(lfid, np.uint32), (shots,))
        f["SHOTNUMBER"] = (np.arange(1000, 1000 + shots) if shot_number is None else shot_number).astype(np.uint32)
        f["TIME"] = 50000.0 + np.arange(shots) * 1e-3
        f["LON0"], f["LAT0"], f["Z0"] = lon, np.full(shots, 40.0), z0
        f[f"LON{last}"], f[f"LAT{last}"], f[f"Z{last}"] = lon, np.full(shots, 40.0), z0 - last * STEP_M
        f["INCIDENTANGLE"] = np.zeros(shots, np.float32)
        f["AZIMUTH"] = np.zeros(shots, np.float32)
        if with_sigmean:
            f["SIGMEAN"] = np.full(shots, 100.0, np.float32)
        f["TXWAVE"] = np.tile(tx, (shots, 1)).astype(np.uint16)
        rx = rx.astype(np.float32)
        if bad_shot is not None:
            rx[bad_shot, 10] = np.nan
        f["RXWAVE"] = rx
    return {"ground": ground, "top": top, "z0": z0, "lon": lon}


LEVEL2_RH = (*range(10, 100, 5), 96, 97, 98, 99, 100)  # the RH columns of an LVIS Level 2 (LGE) text file


def read_level2(path) -> dict:
    """An LVIS Level 2 text file (no header; LFID SHOTNUMBER TIME GLON GLAT ZG HLON HLAT ZH RH10 RH15 .. RH95 RH96
    .. RH100 AZIMUTH INCIDENTANGLE RANGE and the receiver channel of ZT, ZG and RH), -999 as NaN."""
    table = np.loadtxt(path, ndmin=2)
    rh_end = 9 + len(LEVEL2_RH)
    rh = np.where(table[:, 9:rh_end] == -999, np.nan, table[:, 9:rh_end])
    return {"lfid": table[:, 0].astype(np.int64), "shot_number": table[:, 1].astype(np.int64), "zg": table[:, 5],
            "zh": table[:, 8], "rh": {k: rh[:, i] for i, k in enumerate(LEVEL2_RH)},
            "channel": table[:, rh_end + 3:rh_end + 6].astype(np.int64)}
