"""Coordinate reference systems: GeoTIFF keys (LAS, PulseWaves) -> OGC WKT, with pyproj."""

from __future__ import annotations

import logging

import numpy as np

LOG = logging.getLogger("fwl")
MODEL_TYPE, PROJECTED_CS, GEOGRAPHIC_TYPE, VERTICAL_CS = 1024, 3072, 2048, 4096
MODEL_GEOCENTRIC = 3
USER_DEFINED = 32767
EARTH_RADIUS_M = 6_371_000.0
WGS84_GEOCENTRIC = 4978


def geokeys_from_bytes(data: bytes) -> dict[int, int]:
    """GeoKey id -> value of the short-valued keys of a GeoKeyDirectory record (34735)."""
    words = np.frombuffer(data[: len(data) // 2 * 2], dtype="<u2")
    if words.size < 4:
        return {}
    n = int(words[3])
    entries = words[4:4 + 4 * n].reshape(-1, 4)
    return {int(k): int(v) for k, location, _, v in entries if location == 0}


def epsg_from_geokeys(keys: dict[int, int]) -> int | None:
    """The EPSG code the keys name: projected, else geographic, else WGS 84 geocentric for a geocentric model."""
    for key in (PROJECTED_CS, GEOGRAPHIC_TYPE):
        code = keys.get(key)
        if code and code != USER_DEFINED:
            return code
    if keys.get(MODEL_TYPE) == MODEL_GEOCENTRIC:
        return WGS84_GEOCENTRIC  # the keys name no datum code; the files that say geocentric are WGS 84
    return None


def wkt_from_epsg(code: int | None) -> str | None:
    """OGC WKT (WKT1, as LAS 1.4 asks) of an EPSG code; None when unknown to PROJ."""
    if code is None:
        return None
    import pyproj

    try:
        return pyproj.CRS.from_epsg(code).to_wkt(pyproj.enums.WktVersion.WKT1_GDAL)
    except pyproj.exceptions.CRSError:
        LOG.warning("EPSG:%d is not a coordinate reference system PROJ knows", code)
        return None


def looks_earth_centred(xyz_min: np.ndarray, xyz_max: np.ndarray) -> bool:
    """Whether a bounding box lies on the Earth's surface in Earth-centred coordinates (|r| ~ 6371 km)."""
    centre = (np.asarray(xyz_min, float) + np.asarray(xyz_max, float)) / 2
    return bool(abs(np.linalg.norm(centre) - EARTH_RADIUS_M) < 30_000.0)


def las_crs_wkt(header) -> tuple[str | None, str]:
    """(WKT, where it came from) of a LAS header: its WKT record, or its GeoTIFF keys converted."""
    for vlr in list(header.vlrs) + list(getattr(header, "evlrs", None) or []):
        if vlr.user_id.rstrip("\0") != "LASF_Projection":
            continue
        if vlr.record_id == 2112:
            data = vlr.record_data_bytes() if hasattr(vlr, "record_data_bytes") else vlr.record_data
            return bytes(data).rstrip(b"\0").decode("utf-8", "replace"), "WKT record"
    for vlr in header.vlrs:
        if vlr.user_id.rstrip("\0") == "LASF_Projection" and vlr.record_id == 34735:
            keys = {k.id: k.value_offset for k in vlr.geo_keys if k.tiff_tag_location == 0} \
                if hasattr(vlr, "geo_keys") else geokeys_from_bytes(bytes(vlr.record_data))
            code = epsg_from_geokeys(keys)
            wkt = wkt_from_epsg(code)
            return wkt, f"GeoTIFF keys (EPSG:{code})" if wkt else "GeoTIFF keys without an EPSG code"
    return None, "none"
