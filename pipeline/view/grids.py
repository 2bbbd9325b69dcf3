"""A run's maps as a layer under the echoes: the Cloud Optimized GeoTIFFs `fwl grid` wrote, read for the page.

A run's grids are the folders under the viewer's folders that fwl grid marked as its own (fwl-grid.json): the
run's grid/ folder (fwl grid's default output) and any other whose mark names the run. A layer is one band of
one map, served as JSON: the cells' values, nodata (and the count map's empty cells) as null, which the page
draws transparent, with the cells' centres in the map's coordinates. fwl grid maps the echoes' own x and y, so
a grid lines up with the echoes wherever the map draws them as they are (a projected CRS, or none named); the
map of an earth-centred run draws east and north about its centre, where a grid of its x and y has no place.

A layer may be asked for within a box of the map (a zoom): only the cells it touches are read. More than
MAX_CELLS cells are served coarser: blocks of k x k cells, each the highest of its cells
(highest.tif), the lowest (lowest.tif), their sum (count and profile: the block's echoes and energy) or their
mean (the mean maps), read k rows at a time.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np

from pipeline.layout import GRID_MARK
from pipeline.view import params
from pipeline.view.catalog import Roots, files_under
from pipeline.view.queries import colour_range

MAX_CELLS = 250_000  # cells one layer sends the page (a few MB of JSON), whatever the grid's size
# each map fwl grid writes: how its cells combine when the layer is served coarser
MAPS = {"highest.tif": "max", "lowest.tif": "min", "count.tif": "sum", "profile.tif": "sum",
        "reflectance.tif": "mean", "amplitude.tif": "mean",
        # the forest's (pipeline.forest_maps): surfaces as their highest, the rest as means
        "dtm.tif": "mean", "dsm.tif": "max", "chm.tif": "max", "cover.tif": "mean", "pai.tif": "mean",
        "pavd.tif": "mean", "rh98.tif": "max", "rh50.tif": "mean"}
LOCAL_FRAME = ("the map draws this earth-centred run in east and north metres about its centre; a grid of its "
               "earth-centred x and y has no place on it")
PLACED = ("x0", "dx", "west", "east"), ("y0", "dy", "north", "south")  # a layer's x and y: where the map draws them
DESCRIPTION = re.compile(r"(?P<what>[^\[]*?)\s*\[(?P<unit>[^\]]*)\]\s*(?P<rest>.*)")


def _mark(folder: Path) -> dict | None:
    try:
        mark = json.loads((folder / GRID_MARK).read_text())
        return mark if isinstance(mark, dict) and isinstance(mark.get("files"), list) else None
    except (OSError, ValueError):
        return None


def belongs(folder: Path, run: Path) -> bool:
    """A grid folder of this run: inside it (the run's grid/), or elsewhere with a mark that names it."""
    mark = _mark(folder)
    if mark is None:
        return False
    if folder.parent == run:
        return True
    named = mark.get("run")
    return isinstance(named, str) and Path(named) == run


def run_grids(roots: Roots, run: Path) -> list[Path]:
    """The grid folders of a run under the viewer's folders (links that leave a folder are not followed)."""
    found = set()
    for root in roots.folders:
        for mark in files_under(root, GRID_MARK):
            folder = mark.parent.resolve()
            if folder.is_relative_to(root) and mark.is_file() and belongs(folder, run):
                found.add(folder)
    return sorted(found)


def label(description: str | None, fallback: str) -> tuple[str, str]:
    """A band's description as fwl grid wrote it ("highest kept echo z [m]") -> (what it is, its unit)."""
    match = DESCRIPTION.fullmatch(description or "")
    if match is None:
        return (description or fallback), ""
    return " ".join(p for p in (match["what"], match["rest"]) if p), match["unit"]


def describe(roots: Roots, run: Path, folder: Path, drawable: bool) -> dict:
    """A grid folder for the page's layer selector: its cell size and its maps' bands, each a layer."""
    import rasterio

    mark = _mark(folder) or {}
    ident = roots.id_of(folder)
    layers, missing = [], []
    for name in sorted(n for n in mark.get("files", []) if n in MAPS):
        try:
            with rasterio.open(folder / name) as tif:
                descriptions = tif.descriptions
        except rasterio.errors.RasterioIOError:
            missing.append(name)
            continue
        for band, text in enumerate(descriptions, start=1):
            what, unit = label(text, name.removesuffix(".tif"))
            layers.append({"map": name, "band": band, "label": what, "unit": unit})
    reason = None if drawable else LOCAL_FRAME
    if missing:
        reason = f"unreadable: {', '.join(missing)}" if not layers else reason
    return {"id": ident, "name": folder.name if folder.parent == run else ident.partition("/")[2] or folder.name,
            "cell_m": mark.get("cell_m"), "width": mark.get("width"), "height": mark.get("height"),
            "mean_of": mark.get("mean_of"), "layers": layers, "unavailable": reason}


def listing(roots: Roots, run: Path, drawable: bool) -> list[dict]:
    return [describe(roots, run, folder, drawable) for folder in run_grids(roots, run)]


def request(roots: Roots, run: Path, query: dict[str, list[str]], drawable: bool) -> tuple[Path, int]:
    """The map file and band a layer request names, each checked: the grid a folder under the viewer's folders
    that is this run's, the map one its mark lists, the band one the map has."""
    import rasterio

    if not drawable:
        raise params.BadRequest(LOCAL_FRAME)
    folder = roots.path_of(params.name(params.query_value(query, "grid"), "grid"))
    if not folder.is_dir() or not belongs(folder, run):
        raise FileNotFoundError(f"{params.query_value(query, 'grid')!r} is no grid of this run (fwl grid's folder "
                                f"with its {GRID_MARK})")
    name = params.query_value(query, "map")
    if name not in MAPS or name not in (_mark(folder) or {}).get("files", []):
        raise params.BadRequest(f"map must be one of the grid's maps ("
                                f"{', '.join(n for n in (_mark(folder) or {})['files'] if n in MAPS)}), not {name!r}")
    text = params.query_value(query, "band", "1")
    try:
        with rasterio.open(folder / name) as tif:
            count = tif.count
    except rasterio.errors.RasterioIOError as err:
        raise FileNotFoundError(f"{name} of grid {folder.name}: unreadable ({err})") from None
    if not re.fullmatch(r"[0-9]{1,6}", text) or not 1 <= int(text) <= count:
        raise params.BadRequest(f"band must be a whole number in [1, {count}] for {name}, not {text!r}")
    return folder / name, int(text)


def _reduce(block: np.ndarray, k: int, how: str) -> np.ndarray:
    """One row of k x k blocks from k rows (or fewer, at the south edge) of cells; NaN where all are NaN."""
    rows, width = block.shape
    pad = -width % k
    if pad:
        block = np.hstack([block, np.full((rows, pad), np.nan)])
    cells = block.reshape(rows, -1, k).transpose(1, 0, 2).reshape(-1, rows * k)
    empty = np.isnan(cells).all(axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN blocks: NaN, as wanted
        out = {"max": np.nanmax, "min": np.nanmin, "sum": np.nansum, "mean": np.nanmean}[how](cells, axis=1)
    return np.where(empty, np.nan, out)


def in_frame(layer: dict, frame) -> dict:
    """A layer of the CRS's x and y where a planar frame (pipeline.view.frame: a geographic run's metres about its
    centre) draws it: each cell's centre and size scaled, the cells as they are."""
    if frame.rotation is None:
        return layer
    x0, sx, y0, sy = frame.xy_scale()
    placed = dict(layer)
    for (origin, scale), names in zip(((x0, sx), (y0, sy)), PLACED):
        for name in names:
            placed[name] = layer[name] * scale if name.startswith("d") else (layer[name] - origin) * scale
    placed["shown_cell_m"] = layer["shown_cell_m"] * sx  # east-west, in metres
    return placed


def cell_words(cell: float | None, frame) -> str | None:
    """A grid's cell as the map's reader takes it: metres as they are; a geographic run's degrees with the
    metres they span on its map."""
    if cell is None:
        return None
    if frame.rotation is None:
        return f"{cell:g} m"
    _, sx, _, sy = frame.xy_scale()
    return f"{cell:g}° ({cell * sx:.3g} × {cell * sy:.3g} m)"


def crs_box(box, frame):
    """A box of the map (xmin, xmax, ymin, ymax in a planar frame) in the CRS's x and y."""
    if box is None or frame.rotation is None:
        return box
    x0, sx, y0, sy = frame.xy_scale()
    return (box[0] / sx + x0, box[1] / sx + x0, box[2] / sy + y0, box[3] / sy + y0)


def _window(box, west: float, north: float, cell: float, width: int, height: int) -> tuple[int, int, int, int]:
    """The columns and rows [col0, col1) x [row0, row1) of the cells a box (xmin, xmax, ymin, ymax) touches."""
    if box is None:
        return 0, width, 0, height
    xmin, xmax, ymin, ymax = box
    cols = np.clip([math.floor((xmin - west) / cell), math.ceil((xmax - west) / cell)], 0, width)
    rows = np.clip([math.floor((north - ymax) / cell), math.ceil((north - ymin) / cell)], 0, height)
    return int(cols[0]), int(cols[1]), int(rows[0]), int(rows[1])


def read_layer(path: Path, band: int, max_cells: int | None = None, box=None) -> dict:
    """One band of a map as the page draws it, the cells within `box` (all: None): rows from the south, cell
    centres x0 + i dx, y0 + j dy."""
    import rasterio
    from rasterio.windows import Window

    how = MAPS[path.name]
    with rasterio.open(path) as tif:
        t = tif.transform
        if t.b or t.d or not t.a > 0 or not t.e < 0:
            raise ValueError(f"{path.name}: not a north-up grid of square cells (transform {tuple(t)[:6]})")
        nodata = tif.nodata
        col0, col1, row0, row1 = _window(box, t.c, t.f, t.a, tif.width, tif.height)
        width, height = col1 - col0, row1 - row0
        k = max(1, math.ceil(math.sqrt(width * height / (max_cells or MAX_CELLS))))
        rows = []
        for top in range(row0, row1, k):
            block = tif.read(band, window=Window(col0, top, width, min(k, row1 - top))).astype(float)
            if nodata is not None and not math.isnan(nodata):
                block[block == nodata] = np.nan
            if path.name == "count.tif":
                block[block == 0] = np.nan  # no echo: drawn as the other maps' empty cells
            rows.append(_reduce(block, k, how) if k > 1 else block[0])
        description = tif.descriptions[band - 1]
        crs = tif.crs.to_string() if tif.crs else None
    values = np.vstack(rows)[::-1] if width * height else np.zeros((0, 0))  # from the south: y grows upwards
    what, unit = label(description, path.stem)
    size = k * t.a
    finite = values[np.isfinite(values)]
    if how in ("max", "min"):
        values = np.round(values, 3)  # heights in millimetres, as the echoes
    elif finite.size:  # six significant digits: what a colour shows, in fewer bytes
        values = np.round(values, int(np.clip(5 - math.floor(math.log10(max(np.abs(finite).max(), 1e-300))), 0, 15)))
    west, north = t.c + col0 * t.a, t.f - row0 * t.a  # the window's corner
    return {"map": path.name, "band": band, "label": what, "unit": unit, "crs": crs, "box": box,
            "cell_m": float(t.a), "block": k, "shown_cell_m": float(size), "how": how if k > 1 else None,
            "x0": float(west + size / 2), "dx": float(size), "y0": float(north - values.shape[0] * size + size / 2),
            "dy": float(size), "west": float(west), "north": float(north), "east": float(west + width * t.a),
            "south": float(north - height * t.a), "width": int(values.shape[1]), "height": int(values.shape[0]),
            "cells_with_values": int(finite.size), **colour_range(finite),
            "z": [[None if v != v else v for v in row] for row in values.tolist()]}
