"""The coordinates a person reads on the viewer's map and 3D view, from the run's CRS.

A projected CRS is drawn as it is. Two kinds are not: an earth-centred CRS (EPSG:4978) is drawn in east, north
and up metres about the run's centre (the rotation of PROJ's `topocentric` conversion), and a geographic one
(EPSG:4979, 4326: GEDI, LVIS) in east and north metres about the run's centre by a local equirectangular
projection (a degree of longitude is N cos(lat0) pi/180 metres, one of latitude M pi/180, the ellipsoid's radii of
curvature at the centre's latitude), its heights as they are: degrees against metres would draw a 3D view as a
vertical line and a map's ticks as "41, 41, 41". Both are linear, so the map's queries apply them in SQL.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class Frame:
    """The map's x, y, z: the run's CRS as it is (rotation None), or a linear map of it, rows = (east, north, up)
    in the CRS's axes about `origin`."""

    labels: tuple[str, str, str]
    crs: str | None = None
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[tuple[float, ...], ...] | None = None  # rows: east, north, up in the CRS's axes
    centre: str | None = None  # where the local frame's origin is, in words

    def sql(self) -> tuple[str, str, str]:
        """The frame's x, y, z as DuckDB expressions over the echo table's x, y, z."""
        if self.rotation is None:
            return "x", "y", "z"
        x0, y0, z0 = self.origin
        return tuple("(" + (" + ".join(f"{c!r} * ({v} - ({o!r}))" for c, v, o in zip(r, "xyz", (x0, y0, z0)) if c)
                            or "0.0") + ")" for r in self.rotation)

    def apply(self, x, y, z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, y, z = (np.asarray(v, dtype=float) for v in (x, y, z))
        if self.rotation is None:
            return x, y, z
        d = np.stack([x - self.origin[0], y - self.origin[1], z - self.origin[2]])
        e, n, u = np.asarray(self.rotation) @ d
        return e, n, u

    @property
    def planar(self) -> bool:
        """Whether the map's x depends on the CRS's x alone and its y on y alone (a grid of the CRS's x and y
        then lies on the map, each cell scaled)."""
        r = self.rotation
        return r is None or (r[0][1] == r[0][2] == r[1][0] == r[1][2] == 0.0 and r[0][0] > 0 and r[1][1] > 0)

    def xy_scale(self) -> tuple[float, float, float, float]:
        """(x0, sx, y0, sy): the map's x = sx (x - x0), y = sy (y - y0) of a planar frame."""
        if self.rotation is None:
            return 0.0, 1.0, 0.0, 1.0
        if not self.planar:
            raise ValueError("this frame mixes the CRS's axes: no grid of its x and y lies on the map")
        return self.origin[0], self.rotation[0][0], self.origin[1], self.rotation[1][1]

    def describe(self) -> dict:
        return {"labels": list(self.labels), "crs": self.crs, "centre": self.centre,
                "local": self.rotation is not None}


def _where(lat: float, lon: float) -> str:
    return f"{abs(lat):.6f}°{'N' if lat >= 0 else 'S'} {abs(lon):.6f}°{'E' if lon >= 0 else 'W'}"


def topocentric(name: str, origin: tuple[float, float, float], semi_major: float,
                inverse_flattening: float) -> Frame:
    """East, north and up metres about `origin` (earth-centred x, y, z) on the CRS's ellipsoid."""
    import pyproj

    geodetic = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +inv +proj=cart +a={semi_major!r} +rf={inverse_flattening!r} "
        f"+step +proj=unitconvert +xy_in=rad +xy_out=deg")
    lon, lat, h = geodetic.transform(*origin)
    lam, phi = np.radians(lon), np.radians(lat)
    rotation = ((-np.sin(lam), np.cos(lam), 0.0),
                (-np.sin(phi) * np.cos(lam), -np.sin(phi) * np.sin(lam), np.cos(phi)),
                (np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)))
    rotation = tuple(tuple(float(v) for v in row) for row in rotation)
    return Frame(("east (m) from the run's centre", "north (m) from the run's centre", "up (m) from the run's centre"),
                 name, tuple(float(v) for v in origin), rotation, f"{_where(lat, lon)}, {h:.1f} m")


def equirectangular(name: str, lon0: float, lat0: float, semi_major: float, inverse_flattening: float) -> Frame:
    """East and north metres about (lon0, lat0) (degrees), heights as they are: the local equirectangular
    projection on the CRS's ellipsoid, exact at the centre (its scale off the centre's parallel drifts by
    tan(lat0) x the north distance over the earth's radius: 2.3e-4 at 1.5 km and 45 degrees)."""
    f = 1.0 / inverse_flattening if inverse_flattening else 0.0
    e2 = f * (2.0 - f)
    s = math.sin(math.radians(lat0))
    prime_vertical = semi_major / math.sqrt(1.0 - e2 * s * s)  # N, the east-west radius of curvature
    meridional = semi_major * (1.0 - e2) / (1.0 - e2 * s * s) ** 1.5  # M, the north-south one
    east = prime_vertical * math.cos(math.radians(lat0)) * math.pi / 180.0  # metres per degree of longitude
    north = meridional * math.pi / 180.0  # metres per degree of latitude
    rotation = ((east, 0.0, 0.0), (0.0, north, 0.0), (0.0, 0.0, 1.0))
    return Frame(("east (m) from the run's centre", "north (m) from the run's centre", "height (m)"),
                 name, (float(lon0), float(lat0), 0.0), rotation, _where(lat0, lon0))


def of_crs(crs, bounds: dict | None) -> Frame:
    """The frame a run of this pyproj CRS is drawn in (bounds: its echoes' {"x": [lo, hi], "y": ..., "z": ...}
    in the CRS, for the centre of a local frame; None when it has no echoes)."""
    if crs is None:
        return Frame(("x (m, CRS unknown)", "y (m, CRS unknown)", "z (m, CRS unknown)"))
    name = crs.name + (f" (EPSG:{crs.to_epsg()})" if crs.to_epsg() else "")
    local = crs.is_geocentric or crs.is_geographic
    if local and bounds is None:
        return Frame(("x", "y", "z (m)"), name)
    ellipsoid = crs.ellipsoid
    if crs.is_geocentric:
        origin = tuple((lo + hi) / 2 for lo, hi in (bounds["x"], bounds["y"], bounds["z"]))
        return topocentric(name, origin, ellipsoid.semi_major_metre, ellipsoid.inverse_flattening)
    if crs.is_geographic:
        return equirectangular(name, sum(bounds["x"]) / 2, sum(bounds["y"]) / 2, ellipsoid.semi_major_metre,
                               ellipsoid.inverse_flattening)
    units = [a.unit_name.replace("metre", "m") for a in crs.axis_info] or ["m", "m"]
    x_name, y_name = ("easting", "northing") if crs.is_projected else ("x", "y")
    return Frame((f"{x_name} ({units[0]}), {name}", f"{y_name} ({units[min(1, len(units) - 1)]}), {name}",
                  "height (m)"), name)
