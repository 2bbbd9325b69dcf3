"""A QGIS virtual point cloud (.vpc) over a run's COPC files: one layer for the whole survey.

The format is PDAL wrench's (github.com/PDAL/wrench, vpc-spec.md): a STAC ItemCollection (a GeoJSON
FeatureCollection), one STAC Item per file with the pointcloud and projection extensions: its point count, its
3D bounding box in its own CRS (proj:bbox, which QGIS uses) and in WGS 84 (GeoJSON's), its CRS as WKT2, and
the file as the item's data asset, by a path relative to the .vpc. Only the files' headers are read.
"""

from __future__ import annotations

import datetime
import json
import os
from pathlib import Path

from fwcore.io.crs import las_crs_wkt

STAC_EXTENSIONS = ["https://stac-extensions.github.io/pointcloud/v1.0.0/schema.json",
                   "https://stac-extensions.github.io/projection/v1.1.0/schema.json"]


def _wgs84_box(box: list[float], wkt: str | None) -> list[float]:
    """The 2D box's corners in WGS 84 (lon, lat), or the box itself where the CRS is unknown (GeoJSON asks for
    WGS 84; proj:bbox is the box QGIS reads)."""
    if not wkt:
        return box
    import pyproj

    to_wgs = pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(wkt), "EPSG:4326", always_xy=True)
    xs, ys = to_wgs.transform([box[0], box[2], box[0], box[2]], [box[1], box[1], box[3], box[3]])
    return [min(xs), min(ys), max(xs), max(ys)]


def vpc_item(path: Path, relative_to: Path) -> dict:
    """One COPC (or LAS) file as a STAC Item."""
    import laspy

    with laspy.open(path) as f:
        h = f.header
        wkt = las_crs_wkt(h)[0]
        mins, maxs = [float(v) for v in h.mins], [float(v) for v in h.maxs]
        count = int(h.point_count)
    lon0, lat0, lon1, lat1 = _wgs84_box([mins[0], mins[1], maxs[0], maxs[1]], wkt)
    ring = [[lon0, lat0], [lon1, lat0], [lon1, lat1], [lon0, lat1], [lon0, lat0]]
    return {
        "type": "Feature", "stac_version": "1.0.0", "stac_extensions": STAC_EXTENSIONS,
        "id": path.name.split(".")[0],
        "geometry": {"type": "Polygon", "coordinates": [ring]},
        "bbox": [lon0, lat0, mins[2], lon1, lat1, maxs[2]],
        "properties": {"datetime": datetime.datetime.fromtimestamp(path.stat().st_mtime,
                                                                   datetime.timezone.utc).isoformat(),
                       "pc:count": count, "pc:encoding": "?", "pc:type": "lidar",
                       "proj:bbox": [*mins, *maxs], "proj:wkt2": wkt or None},
        "links": [],
        "assets": {"data": {"href": _href(path, relative_to), "roles": ["data"]}},
    }


def _href(path: Path, folder: Path) -> str:
    """The file's path from the .vpc's folder, as the spec's examples write it ("./x.copc.laz", "../copc/x")."""
    rel = Path(os.path.relpath(path, folder)).as_posix()
    return rel if rel.startswith("../") else "./" + rel


def write_vpc(files: list[Path], output: Path) -> Path:
    """The .vpc of `files` at `output` (atomically)."""
    output = Path(output)
    collection = {"type": "FeatureCollection",
                  "features": [vpc_item(Path(f), output.parent) for f in sorted(files)]}
    tmp = output.with_name(output.name + ".tmp")
    tmp.write_text(json.dumps(collection, indent=1) + "\n")
    tmp.replace(output)
    return output
