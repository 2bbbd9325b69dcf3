"""NASA GEDI L1B granules (HDF5): every beam's shots as pulses.

A granule holds one group per beam (BEAM0000 ... BEAM1011). A beam's received waveforms are one flat array
(`rxwaveform`): shot i's are `rx_sample_count[i]` samples from `rx_sample_start_index[i]`, which counts from 1;
its transmitted pulses likewise (`txwaveform`, 128 samples a shot). Samples are 1 ns apart; a sample's position
interpolates bin0 (the first sample) to lastbin (the last) over count - 1 steps. Positions are WGS84 longitude
and latitude (degrees) and ellipsoid heights (m): EPSG:4979.

Shots are numbered beam by beam in the beams' name order; a range never crosses a beam, so a granule of millions
of shots is planned from the shot counts alone and each range reads only its own slice of the arrays.
A shot with no samples, a stale return (the digitizer's previous waveform) or no geolocation is rejected with
its reason.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fwcore.io.errors import WaveformFileError
from fwcore.io.hdf5 import hdf5_file, holds, wgs84_3d_wkt
from fwcore.io.records import PointRange, PulseBatch

SAMPLE_SPACING_PS = 1000.0
EPSG_4979_SOURCE = "GEDI: WGS84 longitude, latitude and ellipsoid height (EPSG:4979)"
TX_SHAPE_FIELDS = ("tx_egsigma", "tx_egsigma_error", "tx_eggamma", "tx_eggamma_error")
NO_SAMPLES = "no samples (rx_sample_count 0)"
STALE = "stale return (stale_return_flag 1): the digitizer held the previous shot's waveform"
NO_GEOLOCATION = "no geolocation (elevation_bin0 or elevation_lastbin not finite)"


def is_gedi_l1b(path: str | Path) -> bool:
    """An HDF5 file with a BEAM group holding received waveforms (`rxwaveform`)."""
    return holds(path, lambda f: any(k.startswith("BEAM") and "rxwaveform" in f[k] for k in f))


@dataclasses.dataclass(frozen=True)
class GediGranule:
    """A granule's index: its beams in name order and their shot counts (what planning needs)."""

    path: str
    beams: tuple[str, ...]
    shots: tuple[int, ...]
    crs_wkt: str
    crs_source: str = EPSG_4979_SOURCE

    @property
    def point_count(self) -> int:
        return sum(self.shots)

    @property
    def first_shot(self) -> np.ndarray:
        """Each beam's first shot in the granule's numbering, and the total after them."""
        return np.r_[0, np.cumsum(self.shots)]

    def beam_of(self, start: int) -> tuple[str, int]:
        """The beam that holds shot `start` of the granule's numbering, and its first shot there."""
        i = int(np.searchsorted(self.first_shot, start, side="right") - 1)
        return self.beams[i], int(self.first_shot[i])


def open_gedi(path: str | Path) -> GediGranule:
    """The granule's beams and shot counts; a file that is not a GEDI L1B granule names what is wrong."""
    with hdf5_file(path, "GEDI granule") as f:
        beams = sorted(k for k in f if k.startswith("BEAM") and "rxwaveform" in f[k])
        missing = sorted({name for b in beams for name in REQUIRED if name not in f[b]})
        if missing:
            raise WaveformFileError(f"{path}: a GEDI L1B granule without {', '.join(missing)}")
        shots = tuple(int(f[b]["shot_number"].shape[0]) for b in beams)
    if not beams:
        raise WaveformFileError(f"{path}: an HDF5 file without GEDI L1B beams (no BEAM group holds rxwaveform); "
                                f"L2A and L2B granules hold no waveforms: give the L1B (GEDI01_B_*.h5)")
    return GediGranule(str(path), tuple(beams), shots, wgs84_3d_wkt())


def plan_gedi_ranges(path: str | Path, points_per_range: int = 10_000, opened: GediGranule | None = None
                     ) -> list[PointRange]:
    """Ranges of at most `points_per_range` shots, beam by beam: every shot in exactly one."""
    granule = opened or open_gedi(path)
    ranges = []
    for first, count in zip(granule.first_shot[:-1], granule.shots):
        for start in range(int(first), int(first) + count, max(1, points_per_range)):
            stop = min(start + points_per_range, int(first) + count)
            ranges.append(PointRange(str(path), start, stop, n_pulses=stop - start))
    return ranges


def _beam_number(group, name: str) -> int:
    """The beam's number as L1B's `beam` dataset says (BEAM0101 -> 5), else read from its name in binary."""
    if "beam" in group and group["beam"].shape[0]:
        return int(group["beam"][0])
    return int(name.removeprefix("BEAM"), 2)


def _slices(group, field: str, starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each shot's samples of a flat waveform array (start indices from 1), read in one slice, and the offsets."""
    counts = np.where(starts > 0, counts, 0)
    if not counts.any():
        return np.zeros(0), np.zeros(counts.size + 1, dtype=np.int64)
    lo = int((starts[counts > 0] - 1).min())
    hi = int((starts[counts > 0] - 1 + counts[counts > 0]).max())
    block = group[field][lo:hi].astype(np.float64)
    parts = [block[s - 1 - lo:s - 1 - lo + c] for s, c in zip(starts, counts)]
    return (np.concatenate(parts) if parts else np.zeros(0)), np.r_[0, np.cumsum(counts)].astype(np.int64)


REQUIRED = ("shot_number", "rx_sample_count", "rx_sample_start_index", "rxwaveform", "geolocation/elevation_bin0",
            "geolocation/elevation_lastbin", "geolocation/latitude_bin0", "geolocation/latitude_lastbin",
            "geolocation/longitude_bin0", "geolocation/longitude_lastbin")
# per shot, read where the granule has them, else these (the beam at nadir, no flags, no time)
OPTIONAL = {"stale_return_flag": 0, "geolocation/degrade": 0, "geolocation/local_beam_elevation": np.pi / 2,
            "geolocation/delta_time": 0.0, "noise_mean_corrected": None, "noise_stddev_corrected": None,
            "tx_sample_count": 0, "tx_sample_start_index": 0, **{k: None for k in TX_SHAPE_FIELDS}}
NOISE_SAMPLES = 50  # without L1B's noise: the first and last samples of the waveform, above and below any surface
# L1B's noise_stddev_corrected over the spread of the waveform's own end samples: the L1B waveform is already
# smoothed, so its samples spread about half as much as GEDI's noise sd says. Median over the shared granule's
# shots 1.86 (by beam 1.80 to 1.92; shot by shot 1.4 to 2.5, 10th to 90th percentile); other granules 1.5 to 2
NOISE_SD_PER_END_SPREAD = 1.86
NOISE_ESTIMATED = (f"estimated: the L1B has no noise_mean_corrected / noise_stddev_corrected; the noise mean is "
                   f"the median of each waveform's first and last {NOISE_SAMPLES} samples, its sd "
                   f"{NOISE_SD_PER_END_SPREAD} x their spread (the beam's median over the range's shots): the "
                   f"signal's extent, and so ground and RH, may differ from L2A's where the ratio differs (1.5-2 by "
                   f"granule)")
NOISE_FIELDS = ("noise_mean_corrected", "noise_stddev_corrected")


def _noise_at_ends(samples: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each waveform's noise mean from its first and last NOISE_SAMPLES samples (their median: a canopy reaching
    into the first samples barely moves it) and the noise sd L1B would give: NOISE_SD_PER_END_SPREAD x the
    median over the waveforms (one beam's) of their spread (1.4826 x the median absolute deviation)."""
    mean, spread = np.full(offsets.size - 1, np.nan), np.full(offsets.size - 1, np.nan)
    for i, (a, b) in enumerate(zip(offsets[:-1], offsets[1:])):
        ends = np.r_[samples[a:min(a + NOISE_SAMPLES, b)], samples[max(b - NOISE_SAMPLES, a):b]]
        if ends.size:
            mean[i] = np.median(ends)
            spread[i] = 1.4826 * np.median(np.abs(ends - mean[i]))
    finite = spread[np.isfinite(spread)]
    sd = NOISE_SD_PER_END_SPREAD * (np.median(finite) if finite.size else np.nan)
    return mean, np.where(np.isfinite(mean), sd, np.nan)


def noise_recorded(path: str | Path) -> bool:
    """Whether every beam of the granule records L1B's noise fields (subsets written by other tools drop them)."""
    return holds(path, lambda f: all(n in f[b] for b in f if b.startswith("BEAM") and "rxwaveform" in f[b]
                                     for n in NOISE_FIELDS))


def _shots(group, lo: int, hi: int):
    """A beam's shots lo..hi-1: numbers, sample counts, bin0 and lastbin positions, each shot's rejection reason
    ('' kept), and the optional columns (OPTIONAL) of the kept shots by their last name."""
    geo = group["geolocation"]
    shot = group["shot_number"][lo:hi].astype(np.int64)
    count = group["rx_sample_count"][lo:hi].astype(np.int64)
    values = {name.split("/")[-1]: (group[name][lo:hi].astype(np.float64) if name in group
                                    else None if default is None else np.full(hi - lo, float(default)))
              for name, default in OPTIONAL.items()}
    bin0 = np.stack([geo["longitude_bin0"][lo:hi], geo["latitude_bin0"][lo:hi], geo["elevation_bin0"][lo:hi]], 1)
    last = np.stack([geo["longitude_lastbin"][lo:hi], geo["latitude_lastbin"][lo:hi],
                     geo["elevation_lastbin"][lo:hi]], axis=1).astype(np.float64)
    bin0 = bin0.astype(np.float64)
    located = np.isfinite(bin0).all(axis=1) & np.isfinite(last).all(axis=1) & (np.abs(bin0[:, 2]) < 1e5)
    reasons = np.where(count <= 0, NO_SAMPLES, np.where(values["stale_return_flag"] == 1, STALE,
                                                         np.where(~located, NO_GEOLOCATION, "")))
    keep = reasons == ""
    kept = {name: v[keep] for name, v in values.items() if v is not None}
    kept["rx_sample_start_index"] = group["rx_sample_start_index"][lo:hi][keep]
    return shot, count, bin0, last, reasons, kept


def read_gedi(point_range: PointRange | str | Path, opened: GediGranule | None = None) -> PulseBatch:
    """The shots of a range (a whole granule given its path: its first beam's range is not enough, so every
    range is read) as pulses: received samples, the transmitted pulse as the outgoing waveform, each sample
    geolocated from bin0 to lastbin."""
    if not isinstance(point_range, PointRange):
        granule = opened or open_gedi(point_range)
        return concatenate([read_gedi(r, granule) for r in plan_gedi_ranges(point_range, 10**9, granule)])
    import h5py

    granule = opened or open_gedi(point_range.path)
    beam, first = granule.beam_of(point_range.start)
    stop = point_range.stop if point_range.max_pulses is None else min(point_range.stop,
                                                                        point_range.start + point_range.max_pulses)
    beam_end = first + granule.shots[granule.beams.index(beam)]
    if stop > beam_end:  # a range over several beams (a file's head, measuring its pulse): beam by beam
        return concatenate([read_gedi(PointRange(point_range.path, start, min(stop, end)), granule)
                            for start, end in zip(granule.first_shot[:-1], granule.first_shot[1:])
                            if start < stop and end > point_range.start
                            for start in [max(int(start), point_range.start)]])
    lo, hi = point_range.start - first, stop - first
    with h5py.File(point_range.path, "r") as f:
        shot, count, bin0, last, reasons, kept = _shots(f[beam], lo, hi)
        keep = reasons == ""
        rx, offsets = _slices(f[beam], "rxwaveform", kept["rx_sample_start_index"].astype(np.int64), count[keep])
        tx, tx_offsets = (_slices(f[beam], "txwaveform", kept["tx_sample_start_index"].astype(np.int64),
                                  kept["tx_sample_count"].astype(np.int64))
                          if "txwaveform" in f[beam] else (np.zeros(0), np.zeros(int(keep.sum()) + 1, np.int64)))
        channel = _beam_number(f[beam], beam)
    elevation, stale, degrade, time = (kept[k] for k in ("local_beam_elevation", "stale_return_flag", "degrade",
                                                         "delta_time"))
    shape = np.stack([kept[k] for k in TX_SHAPE_FIELDS], axis=1) if all(k in kept for k in TX_SHAPE_FIELDS) else None
    noise, noise_sd = kept.get("noise_mean_corrected"), kept.get("noise_stddev_corrected")
    if noise is None or noise_sd is None:  # a granule without them: measured on the waveforms' ends
        mean, sd = _noise_at_ends(rx, offsets)
        noise = mean if noise is None else noise
        noise_sd = sd if noise_sd is None else noise_sd
    l2a = l2a_beside(point_range.path)
    algorithm = selected_algorithms(l2a, beam, shot[keep])
    pft, region = land_cover_classes(l2a, beam, shot[keep])
    n, steps = int(keep.sum()), np.maximum(count[keep] - 1, 1).astype(np.float64)
    # position = anchor + (L0 - t) direction with the anchor at bin0 and L0 = 0: direction = (bin0 - lastbin) / span
    direction = (bin0[keep] - last[keep]) / (steps * SAMPLE_SPACING_PS)[:, None]
    empty_i = np.zeros(0, dtype=np.int64)
    return PulseBatch(
        source_file=str(point_range.path), pulse_id=shot[keep], packet_offset=np.flatnonzero(keep) + point_range.start,
        descriptor_index=np.zeros(n, np.int16), gps_time=time, anchor=bin0[keep], anchor_location_ps=np.zeros(n),
        direction=direction, scan_angle=np.degrees(np.arccos(np.clip(np.abs(np.sin(elevation)), 0, 1))),
        point_source_id=np.zeros(n, np.uint16), scan_direction_flag=np.zeros(n, np.uint8),
        edge_of_flight_line=np.zeros(n, np.uint8), user_data=np.zeros(n, np.uint8),
        sample_spacing_ps=np.full(n, SAMPLE_SPACING_PS), digitizer_gain=np.ones(n), digitizer_offset=np.zeros(n),
        bits_per_sample=np.full(n, 16, np.uint8), samples=rx, sample_offsets=offsets,
        return_xyz=np.zeros((0, 3)), return_number=empty_i, return_intensity=empty_i,
        return_location_ps=np.zeros(0), return_offsets=np.zeros(n + 1, dtype=np.int64),
        channel=np.full(n, channel, np.int16), outgoing=tx, outgoing_offsets=tx_offsets,
        outgoing_spacing_ps=np.full(n, SAMPLE_SPACING_PS),
        rejected=tuple((int(s), str(r)) for s, r in zip(shot[~keep], reasons[~keep])),
        noise_mean=noise, noise_sd=noise_sd, cos_zenith=np.abs(np.sin(elevation)), transmit_shape=shape,
        stale_return_flag=stale.astype(np.int8), degrade_flag=degrade.astype(np.int8), metric_algorithm=algorithm,
        pft_class=pft, region_class=region,
        shot_number=shot[keep].astype(np.int64))


def concatenate(batches: list[PulseBatch]) -> PulseBatch:
    """Several ranges' pulses of one file as one batch (flat arrays joined, offsets shifted)."""
    if len(batches) == 1:
        return batches[0]
    values = {}
    for field in dataclasses.fields(PulseBatch):
        parts = [getattr(b, field.name) for b in batches]
        if field.name in ("source_file", "metric_definition"):
            values[field.name] = parts[0]
        elif field.name == "rejected":
            values[field.name] = tuple(r for p in parts for r in p)
        elif any(p is None for p in parts):
            values[field.name] = None
        elif field.name.endswith("offsets"):
            shift = np.cumsum([0] + [p[-1] for p in parts[:-1]])
            values[field.name] = np.concatenate([parts[0][:1]] + [p[1:] + s for p, s in zip(parts, shift)])
        else:
            values[field.name] = np.concatenate(parts)
    return PulseBatch(**values)


def describe_gedi(path: str | Path) -> dict:
    """`fwl info`: the beams, their shots and samples, the footprint's bounds and the CRS, from the index only."""
    import h5py

    granule = open_gedi(path)
    beams = {}
    with h5py.File(path, "r") as f:
        for name, shots in zip(granule.beams, granule.shots):
            g = f[name]
            count = g["rx_sample_count"][:]
            geo = g["geolocation"]
            lon = np.r_[geo["longitude_bin0"][:], geo["longitude_lastbin"][:]]
            lat = np.r_[geo["latitude_bin0"][:], geo["latitude_lastbin"][:]]
            beams[name] = {"shots": shots, "samples": {"min": int(count.min()) if shots else 0, "max": int(count.max()) if shots else 0},
                           "stale": int(g["stale_return_flag"][:].sum()) if "stale_return_flag" in g else 0,
                           "bounds": [float(np.nanmin(lon)), float(np.nanmin(lat)), float(np.nanmax(lon)),
                                      float(np.nanmax(lat))] if shots else None}
    return {"file": str(path), "format": "GEDI L1B", "shots": granule.point_count, "beams": beams,
            "crs": "EPSG:4979", "problems": []}


def l2a_beside(path: str | Path) -> Path | None:
    """The L2A granule of the same orbit beside an L1B one (GEDI02_A_<time>_O<orbit>_... for GEDI01_B_<time>_
    O<orbit>_...), where there is one."""
    path = Path(path)
    parts = path.name.split("_")
    if len(parts) < 4 or not path.name.startswith("GEDI01_B_"):
        return None
    found = sorted(path.parent.glob(f"GEDI02_A_{parts[2]}_{parts[3]}_*.h5"))
    return found[0] if found else None


def selected_algorithms(l2a: Path | None, beam: str, shots: np.ndarray) -> np.ndarray | None:
    """Per shot, the algorithm the L2A granule selected for it (joined by shot number; 0 where L2A has not the
    shot); None without an L2A granule."""
    import h5py

    if l2a is None:
        return None
    try:
        with h5py.File(l2a, "r") as f:
            if beam not in f or "selected_algorithm" not in f[beam]:
                return np.zeros(shots.size, np.int8)
            numbers = f[beam]["shot_number"][:].astype(np.int64)
            selected = f[beam]["selected_algorithm"][:].astype(np.int8)
    except OSError:
        return None
    if not numbers.size:
        return np.zeros(shots.size, np.int8)
    order = np.argsort(numbers)
    at = np.clip(np.searchsorted(numbers[order], shots), 0, numbers.size - 1)
    return np.where(numbers[order][at] == shots, selected[order][at], 0).astype(np.int8)


def land_cover_classes(l2a: Path | None, beam: str, shots: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Per shot, its plant functional type and world region in the L2A granule (land_cover_data/pft_class and
    region_class, joined by shot number; 255 where L2A has not the shot); None without them (no L2A granule, or
    a version 001 one: its land_cover_data has no classes)."""
    import h5py

    if l2a is None:
        return None, None
    try:
        with h5py.File(l2a, "r") as f:
            cover = f[beam].get("land_cover_data") if beam in f else None
            if cover is None or "pft_class" not in cover or "region_class" not in cover:
                return None, None
            numbers = f[beam]["shot_number"][:].astype(np.int64)
            classes = np.stack([cover["pft_class"][:], cover["region_class"][:]], axis=1).astype(np.uint8)
    except OSError:
        return None, None
    found = np.full((shots.size, 2), 255, np.uint8)
    if numbers.size:
        order = np.argsort(numbers)
        at = np.clip(np.searchsorted(numbers[order], shots), 0, numbers.size - 1)
        hit = numbers[order][at] == shots
        found[hit] = classes[order][at][hit]
    return found[:, 0], found[:, 1]


def l2a_algorithm_settings(path: str | Path) -> tuple[int, dict[int, dict]]:
    """The algorithm the L2A granule selected most, and every algorithm's settings (l2a_settings): those of its
    rx_processing_aN groups (a v002 granule may hold more than six), else 1..l2a_alg_count."""
    import h5py

    with h5py.File(path, "r") as f:
        count = next((int(f[b]["ancillary/l2a_alg_count"][0]) for b in f if b.startswith("BEAM")
                      and "ancillary/l2a_alg_count" in f[b]), 6)
        groups = {int(k.removeprefix("rx_processing_a")) for b in f if b.startswith("BEAM") for k in f[b]
                  if k.startswith("rx_processing_a") and k.removeprefix("rx_processing_a").isdigit()}
    most, _ = l2a_settings(path)
    return most, {a: l2a_settings(path, a)[1] for a in sorted(groups or range(1, count + 1))}


# fwcore.metrics.waveform.MetricSettings's fields by the names of L2A's rx_processing_aN/ancillary
L2A_SETTINGS = {"smoothing_width": "rx_smoothing_width_locs", "smoothing_width_zcross": "rx_smoothing_width_zcross",
                "front_threshold_sd": "rx_front_threshold", "back_threshold_sd": "rx_back_threshold",
                "subbins": "rx_subbin_resolution", "select_mode": "enable_select_mode",
                "pulse_sep_thresh": "pulse_sep_thresh", "cumulative_energy_minimum": "cumulative_energy_minimum",
                "cumulative_energy_thresh": "cumulative_energy_thresh", "energy_thresh": "energy_thresh",
                "amp_thresh": "amp_thresh", "max_modes": "rx_max_mode_count"}


def l2a_settings(path: str | Path, algorithm: int | None = None) -> tuple[int, dict]:
    """The L2A granule's waveform settings of `algorithm` (default: the one it selected most often), as the
    fields of fwcore.metrics.waveform.MetricSettings (those its rx_processing_aN/ancillary holds), and that
    algorithm's number."""
    import h5py

    with h5py.File(path, "r") as f:
        beams = [k for k in f if k.startswith("BEAM") and "selected_algorithm" in f[k]]
        if not beams:
            raise WaveformFileError(f"{path}: not a GEDI L2A granule (no beam with selected_algorithm)")
        if algorithm is None:
            selected = np.concatenate([f[b]["selected_algorithm"][:] for b in beams])
            selected = selected[selected > 0]
            algorithm = int(np.bincount(selected).argmax()) if selected.size else 1
        # a granule without the group (some subsets drop it) gives none: the caller's table fills in
        ancillary = f[beams[0]].get(f"rx_processing_a{algorithm}/ancillary", {})
        settings = {field: float(ancillary[name][0]) for field, name in L2A_SETTINGS.items() if name in ancillary}
    for field in ("subbins", "max_modes"):
        if field in settings:
            settings[field] = int(settings[field])
    if "select_mode" in settings:
        settings["select_mode"] = bool(settings["select_mode"])
    return algorithm, settings
