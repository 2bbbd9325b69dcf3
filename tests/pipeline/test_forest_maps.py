"""fwl grid's forest maps on a classified simulated forest, against the scene's truth rasters."""

import json

import numpy as np
import pytest
import rasterio

from fwcore.studies.forest_evaluate import Raster, block_mean, canopy_accuracy, terrain_accuracy
from fwcore.studies.forest_truth import TRUTH_RASTERS, truth_raster_path
from pipeline.cli import main

FOREST_MAPS = ["chm.tif", "cover.tif", "dsm.tif", "dtm.tif", "pai.tif", "pai_corrected.tif", "pavd.tif", "rh50.tif",
               "rh98.tif"]


def _read(path, band=1):
    with rasterio.open(path) as src:
        t = src.transform
        return Raster(src.read(band).astype(float), t.c, t.f, t.a)


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
