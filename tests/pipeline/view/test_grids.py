"""fwl grid's maps as a layer of the map: the served cells are the GeoTIFF's, placed where the page draws the
echoes, and a request names only the viewed run's own grids."""

import json
import warnings
from urllib.parse import quote

import numpy as np
import pytest
import rasterio

from pipeline.view import grids
from tests.pipeline.view.conftest import GRID_CELL
from tests.pipeline.view.test_server import _status


def _layer(viewed, grid_id, name, band=1):
    return viewed.get(f"/api/grid?run={quote(viewed.run_id)}&grid={quote(grid_id)}&map={name}&band={band}")


def _own_grid(viewed):
    """The id of the run's own grid/ (2 m cells)."""
    listed = viewed.get(f"/api/grids?run={quote(viewed.run_id)}")["grids"]
    return next(g["id"] for g in listed if g["cell_m"] == GRID_CELL)


def _cells(layer):
    """The served values as an array, rows from the south as the page draws them (null: NaN)."""
    return np.array([[np.nan if v is None else v for v in row] for row in layer["z"]], dtype=float)


def test_a_runs_grids_are_listed_with_their_layers(viewed, gridded):
    listed = viewed.get(f"/api/grids?run={quote(viewed.run_id)}")["grids"]
    by_cell = {g["cell_m"]: g for g in listed}
    assert sorted(by_cell) == [GRID_CELL, 5.0]  # the run's own grid/ and the one elsewhere that names the run
    own = by_cell[GRID_CELL]
    assert own["name"] == "grid" and own["unavailable"] is None and own["id"].endswith("runs/leica_a/grid")
    maps = {(layer["map"], layer["band"]): layer for layer in own["layers"]}
    with rasterio.open(gridded / "profile.tif") as tif:
        bands = tif.count
    assert set(maps) == {("highest.tif", 1), ("lowest.tif", 1), ("count.tif", 1), ("amplitude.tif", 1)} | {
        ("profile.tif", b) for b in range(1, bands + 1)}
    assert maps[("highest.tif", 1)]["label"] == "highest kept echo z"
    assert maps[("profile.tif", 1)] == {"map": "profile.tif", "band": 1, "label": "energy 0-2 m above the lowest echo",
                                        "unit": "DN ps"}


def test_the_served_cells_are_the_geotiffs(viewed, gridded):
    grid_id = _own_grid(viewed)
    for name, band in (("highest.tif", 1), ("count.tif", 1), ("amplitude.tif", 1), ("profile.tif", 2)):
        layer = _layer(viewed, grid_id, name, band)
        with rasterio.open(gridded / name) as tif:
            expected = tif.read(band).astype(float)[::-1]  # the page's rows run from the south
            west, north, cell = tif.transform.c, tif.transform.f, tif.transform.a
        if name == "count.tif":
            expected[expected == 0] = np.nan  # an empty cell is drawn as the other maps' nodata
        served = _cells(layer)
        assert layer["block"] == 1 and served.shape == expected.shape
        np.testing.assert_array_equal(np.isnan(served), np.isnan(expected))  # nodata stays nodata
        assert np.isnan(served).sum() > 20 and np.isfinite(served).sum() > 20
        tolerance = 0.001 if name == "highest.tif" else 1e-5 * np.nanmax(np.abs(expected))
        assert np.nanmax(np.abs(served - expected)) < tolerance
        # the cells' centres: the GeoTIFF's own corner, cell size and rows
        assert layer["x0"] - layer["dx"] / 2 == west and layer["dx"] == cell == GRID_CELL
        assert layer["y0"] + (layer["height"] - 0.5) * layer["dy"] == north


def test_each_echo_as_the_page_draws_it_falls_in_a_cell_that_holds_it(viewed, gridded):
    grid_id = _own_grid(viewed)
    highest = _layer(viewed, grid_id, "highest.tif")
    cells = _cells(highest)
    drawn = viewed.get(f"/api/echoes?run={quote(viewed.run_id)}&colour=height&kept=1&limit=200000")
    x, y, z = (np.array(drawn[c]) for c in ("x", "y", "z"))
    col = np.floor((x - (highest["x0"] - highest["dx"] / 2)) / highest["dx"]).astype(int)
    row = np.floor((y - (highest["y0"] - highest["dy"] / 2)) / highest["dy"]).astype(int)
    assert len(x) > 100 and (col >= 0).all() and (row >= 0).all()
    top = cells[row, col]
    assert np.isfinite(top).all() and (z <= top + 0.001).all()  # under the map's cell, none above its highest
    # each cell's highest is one of its own echoes (within 1 mm)
    for r, c in {(int(a), int(b)) for a, b in zip(row, col)}:
        assert abs(z[(row == r) & (col == c)].max() - cells[r, c]) <= 0.001
    empty = np.isnan(cells)
    empty[row, col] = False
    assert empty.sum() == np.isnan(cells).sum()  # no echo drawn in an empty cell


def test_a_zoom_gets_the_cells_of_its_box(viewed, gridded):
    grid_id = _own_grid(viewed)
    with rasterio.open(gridded / "highest.tif") as tif:
        cells, west, north, cell = tif.read(1), tif.transform.c, tif.transform.f, tif.transform.a
    # a box from inside column 3 to inside column 9, row 2 to row 6 (from the north)
    box = (west + 3.5 * cell, west + 8.2 * cell, north - 6.9 * cell, north - 2.1 * cell)
    layer = viewed.get(f"/api/grid?run={quote(viewed.run_id)}&grid={quote(grid_id)}&map=highest.tif"
                       f"&box={','.join(map(str, box))}")
    expected = cells[2:7, 3:9][::-1]
    np.testing.assert_array_equal(np.isnan(_cells(layer)), np.isnan(expected))
    assert np.nanmax(np.abs(_cells(layer) - expected)) < 0.001
    assert layer["x0"] - layer["dx"] / 2 == west + 3 * cell and layer["y0"] - layer["dy"] / 2 == north - 7 * cell
    # at most max_cells cells: the 30 of the box, finer than the whole grid's blocks of 3 x 3
    whole = grids.read_layer(gridded / "highest.tif", 1, max_cells=30)
    zoomed = grids.read_layer(gridded / "highest.tif", 1, max_cells=30, box=box)
    assert whole["block"] == 3 and zoomed["block"] == 1 and _cells(zoomed).shape == expected.shape
    outside = grids.read_layer(gridded / "highest.tif", 1, box=(west - 100, west - 50, north - 10, north))
    assert outside["z"] == [] and outside["cells_with_values"] == 0
    got, data = _status(viewed, "GET", f"/api/grid?run={quote(viewed.run_id)}&grid={quote(grid_id)}"
                                       f"&map=highest.tif&box=1,0,0,1")
    assert got == 400 and "xmin <= xmax" in json.loads(data)["error"]


def test_a_large_grid_is_served_in_blocks(gridded):
    """Blocks of k x k cells: the highest of their cells, the sum of their counts; a ragged edge padded empty."""
    with rasterio.open(gridded / "highest.tif") as tif:
        highest = tif.read(1)
    with rasterio.open(gridded / "count.tif") as tif:
        count = tif.read(1).astype(float)
    k = 3
    h, w = highest.shape
    for name, cells, reduce in (("highest.tif", highest, np.nanmax), ("count.tif", count, np.nansum)):
        layer = grids.read_layer(gridded / name, 1, max_cells=highest.size // (k * k) + 1)
        padded = np.full((-(-h // k) * k, -(-w // k) * k), np.nan)
        padded[:h, :w] = np.where(cells == 0, np.nan, cells) if name == "count.tif" else cells
        blocks = padded.reshape(padded.shape[0] // k, k, padded.shape[1] // k, k).transpose(0, 2, 1, 3)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            expected = np.where(np.isnan(blocks).all(axis=(2, 3)), np.nan, reduce(blocks, axis=(2, 3)))[::-1]
        assert layer["block"] == k and layer["dx"] == k * GRID_CELL and layer["how"] in ("max", "sum")
        np.testing.assert_allclose(_cells(layer), expected, atol=0.001)
    assert np.nansum(_cells(layer)) == count.sum()  # every echo counted once


@pytest.mark.parametrize("query, status, said", [
    ("&grid=0/../..&map=highest.tif", 403, "leaves the viewer's folders"),
    ("&grid=0/runs/leica_a/echoes&map=highest.tif", 404, "is no grid of this run"),
    ("&grid=0/runs/leica_a/grid&map=../run.json", 400, "map must be one of the grid's maps"),
    ("&grid=0/runs/leica_a/grid&map=fwl-grid.json", 400, "map must be one of the grid's maps"),
    ("&grid=0/runs/leica_a/grid&map=profile.tif&band=999", 400, "band must be a whole number"),
    ("&grid=0/runs/leica_a/grid&map=highest.tif&band=-1", 400, "band must be a whole number"),
    ("&grid=0/runs/leica_a/grid", 400, "missing parameter 'map'"),
    ("&grid=/etc&map=highest.tif", 403, "names no folder"),
])
def test_a_layer_request_names_only_the_runs_own_grids(viewed, gridded, query, status, said):
    got, data = _status(viewed, "GET", f"/api/grid?run={quote(viewed.run_id)}{query}")
    assert got == status and said in json.loads(data)["error"]


def test_a_grid_of_another_run_is_not_this_runs(viewed, gridded, tmp_path):
    mark = json.loads((viewed.folder / "maps" / "fwl-grid.json").read_text())
    assert mark["run"] == str(viewed.run.resolve())
    other = viewed.folder / "other-maps"
    other.mkdir()
    for f in (viewed.folder / "maps").iterdir():
        (other / f.name).write_bytes(f.read_bytes())
    (other / "fwl-grid.json").write_text(json.dumps({**mark, "run": str(tmp_path)}))
    try:
        assert len(viewed.get(f"/api/grids?run={quote(viewed.run_id)}")["grids"]) == 2
        got, data = _status(viewed, "GET", f"/api/grid?run={quote(viewed.run_id)}&grid=0/other-maps&map=highest.tif")
        assert got == 404 and "is no grid of this run" in json.loads(data)["error"]
    finally:
        for f in other.iterdir():
            f.unlink()
        other.rmdir()
