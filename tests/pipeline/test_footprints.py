"""fwl footprints on a simulated forest: footprints from the air against footprints drawn from the scene itself
(median |d ground| and |d RH98| <= 0.3 m), on a grid and at a granule's shots."""

import h5py
import numpy as np
import pyarrow.parquet as pq
import pyproj
import pytest

from fwcore.studies.forest import ForestConfig, draw_forest, flight_bounds, forest_flight_scene
from fwcore.studies.forest_truth import scene_footprint
from fwcore.metrics.footprint import FootprintSensor, footprint_metrics, footprint_waveform
from pipeline.cli import main
from tests.pipeline.conftest import FOREST_PULSES


def test_footprints_from_the_air_against_the_scene(forest_run, tmp_path):
    out = tmp_path / "fp.parquet"
    assert main(["footprints", str(forest_run), "--spacing", "4", "--output", str(out)]) == 0  # x 12 m: the middle
    table = pq.read_table(out)
    geo = pq.read_schema(out).metadata[b"geo"]
    assert b"Point Z" in geo
    fp = table.to_pydict()
    assert len(fp["x"]) >= 10 and all(r == "" for r in fp["reason"])
    drawn = draw_forest(flight_bounds(FOREST_PULSES, forest_flight_scene()), ForestConfig(), 21)
    s = FootprintSensor()
    d_ground, d_rh98 = [], []
    for x, y, ground, rh98 in zip(fp["x"], fp["y"], fp["ground_z"], fp["rh98"]):
        samples, top = footprint_waveform(*scene_footprint(drawn, x, y, s.radius_m), s)
        truth = footprint_metrics(samples, top, s)
        d_ground.append(ground - truth["ground_z"])
        d_rh98.append(rh98 - truth["rh"][98])
    assert np.median(np.abs(d_ground)) <= 0.3 and np.median(np.abs(d_rh98)) <= 0.3, (d_ground, d_rh98)


def test_footprints_at_a_granule_s_shots(forest_run, tmp_path):
    """A granule written here: three shots over the run (placed through a UTM zone the run is declared in) and
    one far away; the far one is left out, the others keep their shot numbers."""
    utm = pyproj.CRS.from_epsg(32632)
    to_wgs = pyproj.Transformer.from_crs(utm, "EPSG:4326", always_xy=True)
    x, y = np.array([12.0, 12.0, 12.0, 5000.0]), np.array([-40.0, 0.0, 40.0, 0.0])
    lon, lat = to_wgs.transform(x, y)
    granule = tmp_path / "GEDI02_A_test.h5"
    with h5py.File(granule, "w") as f:
        g = f.create_group("BEAM0101")
        g["shot_number"] = np.array([11, 12, 13, 14], np.int64)
        g["lat_lowestmode"], g["lon_lowestmode"] = lat, lon
    out = tmp_path / "shots.parquet"
    assert main(["footprints", str(forest_run), "--gedi", str(granule), "--crs", "EPSG:32632",
                 "--output", str(out)]) == 0
    fp = pq.read_table(out).to_pydict()
    assert fp["shot_number"] == [11, 12, 13] and fp["beam"] == ["BEAM0101"] * 3
    np.testing.assert_allclose(fp["y"], [-40.0, 0.0, 40.0], atol=1e-6)
    assert all(np.isfinite(fp["ground_z"]))
    with pytest.raises(SystemExit):
        main(["footprints", str(forest_run)])  # neither --gedi nor --spacing
