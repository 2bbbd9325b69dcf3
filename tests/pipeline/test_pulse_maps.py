"""fwl grid on a GEDI run: each cell's RH98, RH50, cover, PAI and ground are the mean of its shots' own, the maps in
the granule's EPSG:4979."""

from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pytest
import rasterio

from fwcore.grid import Grid
from pipeline.cli import main
from pipeline.pulse_maps import _anchors, large_footprint_run

GEDI = Path(__file__).resolve().parents[2] / "examples" / "data" / "gedi"
L1B = GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
CELL = 0.002  # degrees


@pytest.fixture(scope="module")
def gridded(tmp_path_factory):
    run = tmp_path_factory.mktemp("gedi-grid") / "run"
    assert main(["run", str(L1B), "--output", str(run), "--formats", "parquet", "--optimizer", "lm"]) == 0
    assert main(["grid", str(run), "--cell", str(CELL)]) == 0
    return run


def test_each_cell_is_the_mean_of_its_shots(gridded):
    assert large_footprint_run(gridded)
    table = ds.dataset(str(gridded / "pulses"), format="parquet").to_table()
    x, y = _anchors(table.column("geometry").combine_chunks())
    pulses = table.to_pandas()
    with rasterio.open(gridded / "grid" / "rh98.tif") as src:
        rh98 = src.read(1)
        assert src.crs.to_epsg() == 4979 or src.crs.to_epsg() == 4326
        t = src.transform
        grid = Grid(t.c, t.f, t.a, src.width, src.height)
    cell = grid.index(x, y)
    expected = pulses.assign(cell=cell, rh98=[r[98] for r in pulses.rh]).groupby("cell").rh98.mean()
    for c, value in expected.items():
        assert rh98.ravel()[c] == pytest.approx(value, abs=1e-4)
    assert np.isnan(rh98).sum() == rh98.size - len(expected)
    for name in ("rh50.tif", "cover.tif", "pai.tif", "ground.tif"):
        assert (gridded / "grid" / name).is_file()


def test_an_airborne_run_is_not_mapped_from_its_pulses(tmp_path, leica_dir):
    run = tmp_path / "run"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(run), "--formats", "parquet",
                 "--preset", "fast", "--limit", "60"]) == 0
    assert not large_footprint_run(run)
