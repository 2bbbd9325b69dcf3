"""Biomass end to end: `fwl run --stratum` on the shared GEDI granule gives every measured shot L4A's agbd from its
own RH, close to what L2A's RH of the same shots give; `fwl grid` maps the mean per cell; `fwl footprints
--stratum` gives simulated GEDI footprints theirs, mapped too."""

import shutil
from pathlib import Path

import h5py
import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
import rasterio

from fwcore.grid import Grid
from fwcore.metrics.biomass import NO_STRATUM, NOT_LARGE, predict_agbd
from pipeline.cli import main
from pipeline.pulse_maps import _anchors
from tests.fwcore.io.lvis_files import write_lvis

GEDI = Path(__file__).resolve().parents[2] / "examples" / "data" / "gedi"
L1B = GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
L2A = GEDI / "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"
CELL = 0.002  # degrees
STRATUM = "GSW_SA"  # the granule's savanna: grass, shrubs and woodland, South America


@pytest.fixture(scope="module")
def biomass_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("gedi-biomass") / "run"
    assert main(["run", str(L1B), "--output", str(run), "--formats", "parquet", "--optimizer", "lm",
                 "--stratum", STRATUM.lower()]) == 0
    assert main(["grid", str(run), "--cell", str(CELL)]) == 0
    return run


def _pulses(run):
    return ds.dataset(str(run / "pulses"), format="parquet").to_table()


def _l2a_rh():
    rows = {}
    with h5py.File(L2A) as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            for s, rh, q in zip(f[beam]["shot_number"][:], f[beam]["rh"][:], f[beam]["quality_flag"][:]):
                if q == 1:
                    rows[int(s)] = rh.astype(np.float64)
    return rows


def test_every_measured_shot_has_its_agbd_from_its_own_rh(biomass_run):
    pulses = _pulses(biomass_run).to_pandas()
    measured = pulses[pulses.metrics_reason == ""]
    assert len(measured) >= 150
    assert set(measured.agbd_stratum) == {STRATUM} and set(measured.agbd_reason) == {""}
    assert set(measured.agbd_algorithm) == {1}  # grass: L4A's rule never leaves algorithm 1, nor L2A's here
    rh = np.stack(measured.rh.to_numpy()).astype(np.float64)
    again = predict_agbd(rh, np.full(len(rh), STRATUM, dtype=object))
    np.testing.assert_allclose(measured.agbd, again.agbd, rtol=1e-6)  # RH stored as float32
    np.testing.assert_allclose(measured.agbd_se, again.agbd_se, rtol=1e-6)  # RH stored as float32
    # savanna (RH98 3.5-6.7 m): a few to a few tens of Mg/ha, agbd_se near the model's floor
    assert 2.0 <= np.median(measured.agbd) <= 30.0 and measured.agbd.max() < 150.0 and measured.agbd.min() >= 0.0


def test_our_agbd_against_l2a_s_rh_of_the_same_shots(biomass_run):
    """The same model on L2A's RH: the difference is our RH's, within the issue's 3% median, 15% 90th percentile."""
    pulses = _pulses(biomass_run).to_pandas().set_index("pulse_id")
    theirs = _l2a_rh()
    shots = [s for s in theirs if s in pulses.index and pulses.at[s, "metrics_reason"] == ""]
    nasa = predict_agbd(np.stack([theirs[s] for s in shots]), np.full(len(shots), STRATUM, dtype=object)).agbd
    ours = pulses.loc[shots, "agbd"].to_numpy()
    relative = np.abs(ours - nasa) / nasa
    assert len(shots) >= 150 and np.median(relative) <= 0.03 and np.percentile(relative, 90) <= 0.15


def test_without_a_stratum_the_reason_says_so(tmp_path):
    run = tmp_path / "run"  # the L2A beside is version 001: no land cover
    assert main(["run", str(L1B), "--output", str(run), "--formats", "parquet", "--optimizer", "lm",
                 "--limit", "10"]) == 0
    pulses = _pulses(run).to_pandas()
    assert pulses.agbd.isna().all() and set(pulses.agbd_reason) == {NO_STRATUM}
    assert main(["run", str(L1B), "--output", str(tmp_path / "bad"), "--stratum", "ENT_NA"]) != 0
    assert not (tmp_path / "bad").exists()


def _raster(path):
    with rasterio.open(path) as src:
        t = src.transform
        return src.read(1), Grid(t.c, t.f, t.a, src.width, src.height)


def test_the_agbd_map_is_each_cell_s_mean(biomass_run):
    table = _pulses(biomass_run)
    x, y = _anchors(table.column("geometry").combine_chunks())
    agbd = table.column("agbd").to_numpy(zero_copy_only=False).astype(np.float64)
    values, grid = _raster(biomass_run / "grid" / "agbd.tif")
    cell = grid.index(x, y)
    ok = np.isfinite(agbd)
    for c in np.unique(cell[ok]):
        assert values.ravel()[c] == pytest.approx(agbd[ok & (cell == c)].mean(), rel=1e-6)
    assert np.isnan(values).sum() == values.size - np.unique(cell[ok]).size


def test_footprints_of_an_airborne_run_have_agbd_and_a_map(forest_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(forest_run, run)  # its own footprints.parquet: fwl grid maps it
    assert main(["footprints", str(run), "--spacing", "4", "--stratum", "ENT_NAm"]) == 0
    fp = pq.read_table(run / "footprints.parquet").to_pandas()
    measured = fp[fp.reason == ""]
    assert len(measured) >= 10 and set(measured.agbd_stratum) == {"ENT_NAm"} and set(measured.agbd_reason) == {""}
    rh = np.stack(measured.rh.to_numpy())
    np.testing.assert_allclose(measured.agbd, predict_agbd(rh, np.full(len(rh), "ENT_NAm", dtype=object)).agbd,
                               rtol=1e-6)  # RH stored as float32
    assert main(["grid", str(run), "--cell", "8", "--output", str(tmp_path / "grid")]) == 0
    values, grid = _raster(tmp_path / "grid" / "footprints_agbd.tif")
    cell = grid.index(measured.x.to_numpy(), measured.y.to_numpy())
    for c in np.unique(cell):
        assert values.ravel()[c] == pytest.approx(measured.agbd[cell == c].mean(), rel=1e-6)
    assert not (tmp_path / "grid" / "agbd.tif").exists()  # small-footprint pulses: no agbd of their own
    pulses = _pulses(run).to_pandas()
    assert pulses.agbd.isna().all() and set(pulses.agbd_reason) == {NOT_LARGE}


def test_lvis_shots_take_the_stratum_given(tmp_path):
    path = tmp_path / "LVIS1B_forest.h5"
    write_lvis(path, 12, seed=4)
    out = tmp_path / "run"
    assert main(["run", str(path), "--output", str(out), "--formats", "parquet", "--optimizer", "lm",
                 "--stratum", "DBT_NAm"]) == 0
    pulses = _pulses(out).to_pandas()
    assert (pulses.metrics_reason == "").all() and set(pulses.agbd_stratum) == {"DBT_NAm"}
    rh = np.stack(pulses.rh.to_numpy()).astype(np.float64)
    np.testing.assert_allclose(pulses.agbd, predict_agbd(rh, np.full(len(rh), "DBT_NAm", dtype=object)).agbd,
                               rtol=1e-6)
    assert (pulses.agbd > 0).all()


def test_footprints_at_a_granule_s_shots_take_its_land_cover(forest_run, tmp_path):
    """A version 002 L2A granule written here: two shots over the run, one deciduous broadleaf in North America
    (pft 4, region 7), one water (pft 0); --stratum does not override the land cover."""
    import pyproj

    to_wgs = pyproj.Transformer.from_crs(pyproj.CRS.from_epsg(32632), "EPSG:4326", always_xy=True)
    lon, lat = to_wgs.transform(np.array([12.0, 12.0]), np.array([-20.0, 20.0]))
    granule = tmp_path / "GEDI02_A_test.h5"
    with h5py.File(granule, "w") as f:
        g = f.create_group("BEAM0101")
        g["shot_number"] = np.array([21, 22], np.int64)
        g["lat_lowestmode"], g["lon_lowestmode"] = lat, lon
        g["land_cover_data/pft_class"] = np.array([4, 0], np.uint8)
        g["land_cover_data/region_class"] = np.array([7, 0], np.uint8)
    out = tmp_path / "shots.parquet"
    assert main(["footprints", str(forest_run), "--gedi", str(granule), "--crs", "EPSG:32632", "--stratum",
                 "ENT_NAm", "--output", str(out)]) == 0
    fp = pq.read_table(out).to_pandas()
    assert list(fp.shot_number) == [21, 22] and list(fp.agbd_stratum) == ["DBT_NAm", ""]
    assert fp.agbd[0] == pytest.approx(predict_agbd(np.stack(fp.rh.to_numpy())[:1], np.array(["DBT_NAm"],
                                                                                            dtype=object)).agbd[0])
    assert np.isnan(fp.agbd[1]) and "pft_class 0" in fp.agbd_reason[1]
