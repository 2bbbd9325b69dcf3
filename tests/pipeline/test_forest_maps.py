"""fwl grid's forest maps on a classified simulated forest, against the scene's truth rasters; the tiles' share of
fwl grid's statistics, the same to the bit as a stream of the table."""

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import rasterio

from fwcore.studies.forest_evaluate import Raster, block_mean, canopy_accuracy, terrain_accuracy
from fwcore.studies.forest_truth import TRUTH_RASTERS, truth_raster_path
from fwcore.grid import CellStatistics, Grid, HeightProfile
from fwcore.terrain.tiles import tiles_over
from pipeline import echo_table
from pipeline.cli import main
from pipeline.forest_maps import STATISTICS, tile_statistics
from pipeline.tiled import read_tile, table_parts, tile_tasks

FOREST_MAPS = ["chm.tif", "cover.tif", "dsm.tif", "dtm.tif", "pai.tif", "pai_corrected.tif", "pavd.tif", "rh50.tif",
               "rh98.tif"]


def _read(path, band=1):
    with rasterio.open(path) as src:
        t = src.transform
        return Raster(src.read(band).astype(float), t.c, t.f, t.a)


def test_the_tiles_statistics_are_a_stream_of_the_tables_to_the_bit(tmp_path, monkeypatch):
    monkeypatch.setattr(echo_table, "BATCH_ROWS", 256)  # record batches across the row groups of 150 rows
    rng = np.random.default_rng(12)
    n = 1400
    e = {"x": np.sort(rng.uniform(0, 50, n)), "y": rng.uniform(0, 30, n), "z": rng.normal(300, 8, n),
         "energy": rng.uniform(1e4, 1e6, n), "amplitude": rng.uniform(0, 200, n),
         "reflectance": np.where(rng.random(n) < 0.3, np.nan, rng.uniform(0, 1, n)), "kept": rng.random(n) > 0.1}
    files = [tmp_path / "a.parquet", tmp_path / "b.parquet"]
    for f, part in zip(files, (slice(0, 700), slice(700, n))):
        pq.write_table(pa.table({k: v[part] for k, v in e.items()}), f, row_group_size=150)
    grid = Grid.covering(0, 0, 50, 30, 1.0)
    stream = CellStatistics(grid, STATISTICS)
    for b in echo_table.kept_batches(files, ["x", "y", "z", *STATISTICS]):
        stream.add(b["x"], b["y"], b["z"], **{k: b[k] for k in STATISTICS})
    highest, lowest = stream.heights()
    profile = HeightProfile(grid, lowest, 1.0, HeightProfile.bins_for(highest, lowest, 1.0))
    for b in echo_table.kept_batches(files, ["x", "y", "z", "energy"]):
        profile.add(b["x"], b["y"], b["z"], b["energy"])
    pasted = {k: np.zeros((grid.height, grid.width)) for k in ("count", "sum_amplitude", "sum_reflectance")}
    sums = np.zeros((grid.height, grid.width, profile.bins))
    for task in tile_tasks(tmp_path, tiles_over(grid, 10.0, 2.0), table_parts(files)):
        t = tile_statistics(task, read_tile(task, ("x", "y", "z", "energy", *STATISTICS)), 1.0)
        shape = (task.tile.row1 - task.tile.row0, task.tile.col1 - task.tile.col0)
        for k in pasted:
            pasted[k][task.tile.row0:task.tile.row1, task.tile.col0:task.tile.col1] = t[k].reshape(shape)
        tile_profile = t["profile"].reshape(*shape, -1)
        sums[task.tile.row0:task.tile.row1, task.tile.col0:task.tile.col1, :tile_profile.shape[-1]] = tile_profile
    np.testing.assert_array_equal(pasted["count"].ravel(), stream.count)
    for k in STATISTICS:
        assert pasted[f"sum_{k}"].ravel().tobytes() == stream.sums[k].tobytes()
    assert sums.reshape(-1, profile.bins).tobytes() == profile.sums.tobytes() and profile.bins > 3


@pytest.fixture(scope="module")
def maps(forest_run, tmp_path_factory):
    out = {}
    for cell in (1, 5):
        folder = tmp_path_factory.mktemp("forest-maps") / f"grid{cell}"
        assert main(["grid", str(forest_run), "--cell", str(cell), "--output", str(folder), "--classify"]) == 0
        out[cell] = folder
    return out


def test_the_forest_maps_beside_the_others(maps):
    files = json.loads((maps[1] / "fwl-grid.json").read_text())["files"]
    assert set(FOREST_MAPS) <= set(files) and "highest.tif" in files


def test_terrain_and_canopy_height_against_the_truth(maps, forest_flight):
    truth = {n: _read(truth_raster_path(forest_flight, n)) for n in TRUTH_RASTERS}
    a = terrain_accuracy(_read(maps[1] / "dtm.tif"), _read(maps[1] / "chm.tif"), truth["dtm"], truth["chm"],
                         truth["roof"], inner=4.0)  # a short flight: 24 m along track
    assert a["open_cells"] > 300 and a["canopy_cells"] > 300
    assert a["dtm_rmse_open_m"] <= 0.15 and a["dtm_rmse_canopy_m"] <= 0.40, a
    assert a["chm_rmse_smooth_canopy_m"] <= 1.0, a  # see docs: the crowns' flanks make the all-cells figure larger
    dsm, dtm = _read(maps[1] / "dsm.tif").values, _read(maps[1] / "dtm.tif").values
    chm = _read(maps[1] / "chm.tif").values
    seen = np.isfinite(dsm)
    assert (dsm[seen] >= dtm[seen] + chm[seen] - 0.5).mean() > 0.99  # the highest echo is at least the canopy's


def test_cover_and_pai_of_5_m_blocks_against_the_truth(maps, forest_flight):
    from scipy.ndimage import binary_erosion

    truth = {n: _read(truth_raster_path(forest_flight, n)) for n in TRUTH_RASTERS}
    seen = binary_erosion(_read(maps[5] / "count.tif").values > 0)  # whole blocks of the swath
    a = canopy_accuracy(_read(maps[5] / "cover.tif"), _read(maps[5] / "pai.tif"), truth["pgap"], truth["pai"],
                        truth["cover"], seen)
    assert a["blocks"] > 30
    assert a["cover_median_abs_error"] <= 0.05, a
    # PAI from the mean gap (L2B's, no clumping): near the PAI that gap means, below the mean PAI where crowns
    # and gaps share a block (docs/forest.md); each pulse's energies in the cell where its beam crosses the canopy
    assert a["pai_effective_median_relative_error"] <= 0.15 and a["pai_median_bias"] < 0, a
    # the clumping correction (log-averaging over 1 m sub-cells) takes it towards the mean PAI
    corrected = _read(maps[5] / "pai_corrected.tif")
    mean_pai = block_mean(truth["pai"], corrected)
    both = seen & (mean_pai >= 0.5) & np.isfinite(corrected.values) & np.isfinite(_read(maps[5] / "pai.tif").values)
    assert both.sum() > 30
    error = np.median(np.abs(corrected.values - mean_pai)[both] / mean_pai[both])
    assert error < a["pai_median_relative_error"] - 0.05, (error, a)


def test_pavd_bands_sum_to_the_pai_and_rh98_tops_rh50(maps):
    folder = maps[5]
    pai = _read(folder / "pai.tif").values
    with rasterio.open(folder / "pavd.tif") as src:
        pavd = src.read().astype(float)
        assert "above the terrain" in src.descriptions[0]
    total = np.nansum(pavd, axis=0) * 1.0  # 1 m bins
    ok = np.isfinite(pai) & (pai > 0)
    np.testing.assert_allclose(total[ok], pai[ok], rtol=1e-4, atol=1e-4)
    rh98, rh50 = _read(folder / "rh98.tif").values, _read(folder / "rh50.tif").values
    both = np.isfinite(rh98) & np.isfinite(rh50)
    assert (rh98[both] >= rh50[both]).all() and np.nanmax(rh98) > 10
