"""Coordinate reference systems as OGC WKT, with pyproj: from GeoTIFF keys (LAS, PulseWaves) or a LAS header's WKT
record, from what the user gives (--crs), and back to a name or PROJJSON. Which CRS an input has is its format's
answer (fwcore.io.formats.input_crs)."""

from __future__ import annotations

import functools
import logging

import numpy as np

LOG = logging.getLogger("fwl")
MODEL_TYPE, PROJECTED_CS, GEOGRAPHIC_TYPE, VERTICAL_CS = 1024, 3072, 2048, 4096
PROJ_LINEAR_UNITS, GEOG_LINEAR_UNITS, VERTICAL_UNITS = 3076, 2052, 4099
MODEL_PROJECTED, MODEL_GEOCENTRIC = 1, 3
GIVEN = "--crs"  # the source of a CRS the user gave
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


def _linear_unit(code: int | None) -> tuple[str, float] | None:
    """(name, metres) of an EPSG linear unit code; None when absent, user-defined or unknown to PROJ."""
    if not code or code == USER_DEFINED:
        return None
    from pyproj.database import get_units_map

    unit = next((u for u in get_units_map(auth_name="EPSG", category="linear").values() if u.code == str(code)), None)
    return (unit.name, unit.conv_factor) if unit else None


def unnamed_wkt_from_geokeys(keys: dict[int, int]) -> str | None:
    """Keys that say "projected" and a linear unit but name no CRS: an unnamed local (engineering) CRS in that unit,
    OGC WKT1 LOCAL_CS, which laspy and pyproj parse; None when the keys say less (no model, no unit)."""
    if keys.get(MODEL_TYPE) != MODEL_PROJECTED:
        return None
    unit = next((u for k in (PROJ_LINEAR_UNITS, GEOG_LINEAR_UNITS, VERTICAL_UNITS)
                 if (u := _linear_unit(keys.get(k)))), None)
    if unit is None:
        return None
    name, metres = unit
    return (f'LOCAL_CS["unnamed projected CRS ({name})",'
            f'LOCAL_DATUM["unknown",32767],UNIT["{name}",{metres!r}],'
            'AXIS["Easting",EAST],AXIS["Northing",NORTH],AXIS["Up",UP]]')


def wkt_from_geokeys(keys: dict[int, int]) -> tuple[str | None, str]:
    """(WKT, where it came from) of GeoTIFF keys: their EPSG code's CRS, else an unnamed CRS in their unit."""
    code = epsg_from_geokeys(keys)
    wkt = wkt_from_epsg(code)
    if wkt:
        return wkt, f"GeoTIFF keys (EPSG:{code})"
    unnamed = unnamed_wkt_from_geokeys(keys)
    if unnamed:
        return unnamed, "GeoTIFF keys without an EPSG code: an unnamed CRS in their unit"
    return None, "GeoTIFF keys without an EPSG code or a unit"


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
            return wkt_from_geokeys(keys)
    return None, "none"


def parse_crs(text: str) -> str:
    """A CRS as the user gives it (an EPSG code, EPSG:n, WKT or PROJJSON, as pyproj reads them) -> OGC WKT1 as
    LAS 1.4 asks (WKT2 where WKT1 cannot say it); ValueError naming the problem."""
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(text.strip())
    except pyproj.exceptions.CRSError as err:
        shown = text if len(text) <= 60 else text[:57] + "..."
        raise ValueError(f"--crs {shown!r} is not a coordinate reference system pyproj reads (an EPSG code such as "
                         f"EPSG:25832, WKT or PROJJSON): {err}") from None
    return crs.to_wkt(pyproj.enums.WktVersion.WKT1_GDAL) or crs.to_wkt()


@functools.lru_cache(maxsize=64)
def crs_projjson(wkt: str | None) -> str | None:
    """PROJJSON of a WKT (GeoParquet's crs), None for None or a WKT pyproj cannot read."""
    if not wkt:
        return None
    import pyproj

    try:
        return pyproj.CRS.from_wkt(wkt).to_json()
    except pyproj.exceptions.CRSError:
        return None


def crs_name(wkt: str | None) -> str | None:
    """A CRS's name, with its EPSG code where it has one; None for none."""
    if not wkt:
        return None
    import pyproj

    try:
        crs = pyproj.CRS.from_wkt(wkt)
    except pyproj.exceptions.CRSError:
        return "(unparsed WKT)"
    code = crs.to_epsg(min_confidence=90)
    return f"EPSG:{code} ({crs.name})" if code else crs.name


@functools.lru_cache(maxsize=64)
def horizontal_metres(wkt: str | None) -> float:
    """Metres per unit of a CRS's first horizontal axis (a degree of latitude for a geographic CRS); 1 for no
    CRS or one pyproj cannot read: distances in metres turned into the coordinates' unit."""
    if not wkt:
        return 1.0
    import pyproj

    try:
        axis = pyproj.CRS.from_wkt(wkt).axis_info[0]
    except (pyproj.exceptions.CRSError, IndexError):
        return 1.0
    if axis.unit_name == "degree":
        return EARTH_RADIUS_M * np.pi / 180.0
    return float(axis.unit_conversion_factor or 1.0)
