"""NASA LVIS L1B waveform files (HDF5, the LVIS Facility and ABoVE layout): one shot per row.

Per shot (dimension N), as the product's data dictionary lists them: LFID (file id), SHOTNUMBER, TIME (UTC
seconds of the day), LON0/LAT0/Z0 (the first, highest sample) and LON<k>/LAT<k>/Z<k> (the last, k = samples - 1:
Z1023 for 1024), INCIDENTANGLE (degrees off nadir), SIGMEAN (the noise mean), TXWAVE (N, transmit samples) and
RXWAVE (N, receive samples). A sample's position interpolates the first to the last over k steps, as GEDI's does;
the sample spacing follows from the height between them and the incidence (about 1 ns). Longitudes east of 180
are taken back to -180..180. A shot whose receive samples or positions are not finite is rejected with its reason.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import re
from pathlib import Path

import numpy as np

from fwcore.io.errors import WaveformFileError
from fwcore.io.hdf5 import hdf5_file, holds, wgs84_3d_wkt
from fwcore.io.records import PointRange, PulseBatch

LIGHT_M_PER_PS = 299792458.0e-12
NOISE_SAMPLES = 50  # LVIS records from above the canopy: its first samples are noise
EPSG_4979_SOURCE = "LVIS: WGS84 longitude, latitude and ellipsoid height (EPSG:4979)"
NOT_FINITE = "non-finite receive samples"
NO_GEOLOCATION = "no geolocation (Z0 or the last sample's position not finite)"


def _last_index(names) -> int | None:
    found = [int(m.group(1)) for n in names for m in [re.fullmatch(r"Z(\d+)", n)] if m and m.group(1) != "0"]
    return max(found) if found else None


def is_lvis_l1b(path: str | Path) -> bool:
    """An HDF5 file with RXWAVE and Z0 at its root."""
    return holds(path, lambda f: "RXWAVE" in f and "Z0" in f)


@dataclasses.dataclass(frozen=True)
class LvisFile:
    path: str
    point_count: int
    last: int  # the last sample's index in the position names (1023)
    crs_wkt: str
    crs_source: str = EPSG_4979_SOURCE


def open_lvis(path: str | Path) -> LvisFile:
    """The file's shot count and layout; a file that is not an LVIS L1B names what is missing."""
    with hdf5_file(path, "LVIS file") as f:
        missing = [k for k in ("RXWAVE", "Z0", "LAT0", "LON0", "SHOTNUMBER") if k not in f]
        last = _last_index(f.keys())
        if missing or last is None:
            raise WaveformFileError(f"{path}: not an LVIS L1B file (missing {', '.join(missing) or 'Z<last>'})")
        if f["RXWAVE"].ndim != 2 or f["RXWAVE"].shape[1] != last + 1:
            raise WaveformFileError(f"{path}: RXWAVE has {f['RXWAVE'].shape[1:]} samples a shot where Z{last} "
                                    f"names {last + 1}")
        n = int(f["SHOTNUMBER"].shape[0])
    return LvisFile(str(path), n, last, wgs84_3d_wkt())


def file_lfids(path: str | Path) -> np.ndarray:
    """The distinct LFIDs of a whole file, sorted (int64): a shot's pulse id numbers its LFID by its rank here
    (lvis_pulse_ids). Read once a process per version of the file."""
    stat = os.stat(path)
    return _file_lfids(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=16)
def _file_lfids(path: str, _mtime_ns: int, _size: int) -> np.ndarray:
    import h5py

    with h5py.File(path, "r") as f:
        if "LFID" not in f:
            return np.zeros(1, np.int64)
        return np.unique(np.asarray(f["LFID"][:]).astype(np.int64))


def lvis_pulse_ids(lfid: np.ndarray, shot: np.ndarray, file_lfid: np.ndarray) -> np.ndarray:
    """Each shot's pulse id: the rank of its LFID among the file's (file_lfids) in the high 32 bits, its SHOTNUMBER
    in the low 32. LFID and SHOTNUMBER are each an unsigned 32-bit integer (LVIS's data dictionary): packed as they
    are they need 64 bits, and an LFID of 2^31 or more (the shared AfriSAR files hold 1,657,455,141) would overflow int64 into a
    negative id. A file holds far fewer than 2^31 LFIDs, so the rank never does; the id is unique in the file and
    the same in every range; the `lfid` and `shot_number` columns keep the mission's own numbers."""
    rank = np.searchsorted(file_lfid, lfid).astype(np.int64)
    return (rank << 32) | (np.asarray(shot, dtype=np.int64) & 0xFFFFFFFF)


def plan_lvis_ranges(path: str | Path, points_per_range: int = 10_000, opened: LvisFile | None = None
                     ) -> list[PointRange]:
    """Ranges of at most `points_per_range` shots, of equal size (to a shot): a long waveform's range is minutes
    of work, so 6,000 shots at 5,000 a range are two of 3,000, not 5,000 and 1,000 that leave a worker idle."""
    lvis = opened or open_lvis(path)
    count = -(-lvis.point_count // max(1, points_per_range))  # how many ranges
    step = max(1, -(-lvis.point_count // max(count, 1)))
    return [PointRange(str(path), s, min(s + step, lvis.point_count), n_pulses=min(s + step, lvis.point_count) - s)
            for s in range(0, lvis.point_count, step)]


def read_lvis(point_range: PointRange | str | Path, opened: LvisFile | None = None) -> PulseBatch:
    """The shots of a range (or the whole file) as pulses."""
    import h5py

    if not isinstance(point_range, PointRange):
        lvis = opened or open_lvis(point_range)
        point_range = PointRange(str(point_range), 0, lvis.point_count, n_pulses=lvis.point_count)
    lvis = opened or open_lvis(point_range.path)
    lo = point_range.start
    hi = point_range.stop if point_range.max_pulses is None else min(point_range.stop, lo + point_range.max_pulses)
    k = lvis.last
    with h5py.File(point_range.path, "r") as f:
        rx = f["RXWAVE"][lo:hi].astype(np.float64)
        tx = f["TXWAVE"][lo:hi].astype(np.float64) if "TXWAVE" in f else np.zeros((hi - lo, 0))
        first = np.stack([f["LON0"][lo:hi], f["LAT0"][lo:hi], f["Z0"][lo:hi]], axis=1).astype(np.float64)
        last = np.stack([f[f"LON{k}"][lo:hi], f[f"LAT{k}"][lo:hi], f[f"Z{k}"][lo:hi]], axis=1).astype(np.float64)
        shot = f["SHOTNUMBER"][lo:hi].astype(np.int64)
        file_id = f["LFID"][lo:hi].astype(np.int64) if "LFID" in f else np.zeros(hi - lo, np.int64)
        time = f["TIME"][lo:hi].astype(np.float64) if "TIME" in f else np.zeros(hi - lo)
        incidence = np.radians(f["INCIDENTANGLE"][lo:hi].astype(np.float64)) if "INCIDENTANGLE" in f \
            else np.zeros(hi - lo)
        noise_mean = f["SIGMEAN"][lo:hi].astype(np.float64) if "SIGMEAN" in f else None
    for position in (first, last):  # 0..360 east to -180..180
        position[:, 0] = np.where(position[:, 0] > 180.0, position[:, 0] - 360.0, position[:, 0])
    # SHOTNUMBER restarts in each LVIS file (LFID): the id packs the LFID's rank in the file with it
    pulse_id = lvis_pulse_ids(file_id, shot, file_lfids(point_range.path))
    located = np.isfinite(first).all(axis=1) & np.isfinite(last).all(axis=1)
    finite = np.isfinite(rx).all(axis=1)
    reasons = np.where(~finite, NOT_FINITE, np.where(~located, NO_GEOLOCATION, ""))
    keep = reasons == ""
    n = int(keep.sum())
    rx, tx, first, last, incidence = rx[keep], tx[keep], first[keep], last[keep], incidence[keep]
    step_m = (first[:, 2] - last[:, 2]) / k / np.maximum(np.cos(incidence), 1e-6)
    spacing = np.where(step_m > 0, 2.0 * step_m / LIGHT_M_PER_PS, 1000.0)
    noise_sd = rx[:, :NOISE_SAMPLES].std(axis=1)
    if noise_mean is None:
        noise_mean = np.median(rx[:, :NOISE_SAMPLES], axis=1)
    else:
        noise_mean = noise_mean[keep]
    samples_per_shot = rx.shape[1]
    empty_i = np.zeros(0, dtype=np.int64)
    return PulseBatch(
        source_file=str(point_range.path), pulse_id=pulse_id[keep], packet_offset=np.flatnonzero(keep) + lo,
        descriptor_index=np.zeros(n, np.int16), gps_time=time[keep], anchor=first, anchor_location_ps=np.zeros(n),
        direction=(first - last) / (k * spacing)[:, None], scan_angle=np.degrees(incidence),
        point_source_id=np.zeros(n, np.uint16), scan_direction_flag=np.zeros(n, np.uint8),
        edge_of_flight_line=np.zeros(n, np.uint8), user_data=np.zeros(n, np.uint8), sample_spacing_ps=spacing,
        digitizer_gain=np.ones(n), digitizer_offset=np.zeros(n), bits_per_sample=np.full(n, 16, np.uint8),
        samples=rx.ravel(), sample_offsets=np.arange(n + 1, dtype=np.int64) * samples_per_shot,
        return_xyz=np.zeros((0, 3)), return_number=empty_i, return_intensity=empty_i,
        return_location_ps=np.zeros(0), return_offsets=np.zeros(n + 1, dtype=np.int64),
        channel=np.zeros(n, np.int16), outgoing=tx.ravel(),
        outgoing_offsets=np.arange(n + 1, dtype=np.int64) * tx.shape[1], outgoing_spacing_ps=spacing,
        rejected=tuple((int(p), str(r)) for p, r in zip(pulse_id[~keep], reasons[~keep])),
        noise_mean=noise_mean, noise_sd=noise_sd, cos_zenith=np.cos(incidence), lfid=file_id[keep],
        shot_number=shot[keep], metric_definition="lvis")


def describe_lvis(path: str | Path) -> dict:
    import h5py

    lvis = open_lvis(path)
    with h5py.File(path, "r") as f:
        lon = np.asarray(f["LON0"][:], dtype=np.float64)
        lat = np.asarray(f["LAT0"][:], dtype=np.float64)
    lon = np.where(lon > 180, lon - 360, lon)
    return {"file": str(path), "format": "LVIS L1B", "shots": lvis.point_count, "samples": lvis.last + 1,
            "crs": "EPSG:4979", "bounds": [float(np.nanmin(lon)), float(np.nanmin(lat)), float(np.nanmax(lon)),
                                           float(np.nanmax(lat))] if lvis.point_count else None, "problems": []}
