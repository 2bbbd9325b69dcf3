"""fwl grid: a run's kept echoes as Cloud Optimized GeoTIFFs in the run's CRS, each map checked against the
echo table, and the folders it refuses."""

import json

import numpy as np
import pyarrow.parquet as pq
import pyproj
import pytest
import rasterio
from rio_cogeo.cogeo import cog_validate

from fwcore.engine.config import DecompositionConfig
from pipeline.cli import main
from pipeline.run import run

FAST = DecompositionConfig(optimizer="lm", lm_iterations=5)
IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]
CELL = 2.0


@pytest.fixture(scope="module")
def leica_run(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("grid") / "run"
    run([str(leica_dir / "leica_a.las")], out, FAST, ("parquet",), points_per_range=400, beam_args=IN_PROCESS,
        watch=False)
    return out


@pytest.fixture(scope="module")
def maps(leica_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("maps") / "maps"
    assert main(["grid", str(leica_run), "--cell", str(CELL), "--output", str(out), "--crs", "EPSG:25832",
                 "--bin-height", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def kept(leica_run):
    table = pq.read_table(leica_run / "echoes", columns=["x", "y", "z", "energy", "amplitude", "kept"]).to_pandas()
    return table[table.kept]


def _cells(kept, west, north):
    return ((north - kept.y) // CELL).astype(int), ((kept.x - west) // CELL).astype(int)


def test_every_map_is_a_cog_in_the_given_crs(maps):
    summary = json.loads((maps / "fwl-grid.json").read_text())
    assert summary["files"] == ["amplitude.tif", "count.tif", "highest.tif", "lowest.tif", "profile.tif"]
    assert summary["mean_of"] == "amplitude"  # a LAS file alone: no radiometry
    for name in summary["files"]:
        with rasterio.open(maps / name) as tif:
            assert tif.crs.to_epsg() == 25832
            assert tif.transform.a == CELL and tif.transform.e == -CELL
            assert tif.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        valid, errors, _ = cog_validate(str(maps / name))
        assert valid, (name, errors)


def test_the_highest_map_is_the_highest_kept_echo_of_each_cell(maps, kept):
    with rasterio.open(maps / "highest.tif") as tif:
        highest, west, north = tif.read(1), tif.transform.c, tif.transform.f
    rows, cols = _cells(kept, west, north)
    expected = np.full(highest.shape, np.nan)
    for (r, c), z in kept.z.groupby([rows, cols]).max().items():
        expected[r, c] = z
    assert np.isfinite(expected).sum() > 300 and np.isnan(expected).sum() > 50  # cells with and without echoes
    np.testing.assert_array_equal(np.isnan(highest), np.isnan(expected))  # empty cells are nodata
    assert np.nanmax(np.abs(highest - expected)) < 0.001


def test_the_count_mean_and_profile_maps_add_up_to_the_echo_table(maps, kept):
    with rasterio.open(maps / "count.tif") as tif:
        count, west, north = tif.read(1), tif.transform.c, tif.transform.f
    rows, cols = _cells(kept, west, north)
    assert count.sum() == len(kept) and count[rows.iloc[0], cols.iloc[0]] == ((rows == rows.iloc[0])
                                                                              & (cols == cols.iloc[0])).sum()
    with rasterio.open(maps / "amplitude.tif") as tif:
        amplitude = tif.read(1)
    mean = kept.amplitude.groupby([rows, cols]).mean()
    np.testing.assert_allclose([amplitude[r, c] for r, c in mean.index], mean.to_numpy(), rtol=1e-6)
    with rasterio.open(maps / "profile.tif") as tif, rasterio.open(maps / "lowest.tif") as low:
        profile, lowest, descriptions = tif.read(), low.read(1), tif.descriptions
    assert descriptions[0] == "energy [DN ps] 0-2 m above the lowest echo"
    assert descriptions[-1].endswith("m and more above the lowest echo") and len(descriptions) == profile.shape[0]
    energy = kept.energy.groupby([rows, cols]).sum()
    np.testing.assert_allclose([profile[:, r, c].sum() for r, c in energy.index], energy.to_numpy(), rtol=1e-5)
    # each echo in the bin of its height above its cell's lowest echo: the first bin's energy, recomputed
    height = kept.z.to_numpy() - lowest[rows, cols]
    first = kept.energy[height < 2.0].groupby([rows[height < 2.0], cols[height < 2.0]]).sum()
    np.testing.assert_allclose([profile[0, r, c] for r, c in first.index], first.to_numpy(), rtol=1e-5)


def test_the_crs_comes_from_the_echo_table(leica_run, tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / "echoes").mkdir(parents=True)
    (run_dir / "run.json").write_text((leica_run / "run.json").read_text())
    for part in (leica_run / "echoes").glob("*.parquet"):
        table = pq.read_table(part)
        geo = json.loads(table.schema.metadata[b"geo"])
        geo["columns"]["geometry"]["crs"] = json.loads(pyproj.CRS.from_epsg(25832).to_json())
        pq.write_table(table.replace_schema_metadata({**table.schema.metadata, b"geo": json.dumps(geo).encode()}),
                       run_dir / "echoes" / part.name)
    assert main(["grid", str(run_dir), "--cell", "5", "--output", str(tmp_path / "maps")]) == 0
    with rasterio.open(tmp_path / "maps" / "highest.tif") as tif:
        assert tif.crs.to_epsg() == 25832 and tif.transform.a == 5.0


def test_it_refuses_what_is_not_a_run_and_folders_not_its_own(leica_run, maps, tmp_path, capsys):
    (tmp_path / "not-a-run").mkdir()
    assert main(["grid", str(tmp_path / "not-a-run"), "--cell", "2", "--output", str(tmp_path / "a")]) == 2
    assert "not an fwl run output folder" in capsys.readouterr().err and not (tmp_path / "a").exists()
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "notes.txt").write_text("mine")
    assert main(["grid", str(leica_run), "--cell", "2", "--output", str(tmp_path / "theirs")]) == 2
    assert "not an fwl grid output folder" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "theirs").iterdir()] == ["notes.txt"]
    assert main(["grid", str(leica_run), "--cell", "0", "--output", str(tmp_path / "b")]) == 2
    assert "cell size" in capsys.readouterr().err and not (tmp_path / "b").exists()
    # its own earlier output is replaced
    assert main(["grid", str(leica_run), "--cell", "4", "--output", str(maps.parent / "again")]) == 0
    assert main(["grid", str(leica_run), "--cell", "8", "--output", str(maps.parent / "again")]) == 0
    assert json.loads((maps.parent / "again" / "fwl-grid.json").read_text())["cell_m"] == 8.0


def test_by_default_the_maps_go_into_the_run_and_leave_with_it(leica_run, leica_dir, tmp_path):
    """fwl grid RUN_DIR writes RUN_DIR/grid/ (where fwl view finds it); the run folder stays a run's folder that
    resume, compact and watch take, and a new run into it removes the maps of the run it replaces."""
    import shutil

    from pipeline.outputs import InputNames, OutputFolderError, earlier_run_files, take_output_folder

    run_dir = tmp_path / "run"
    shutil.copytree(leica_run, run_dir)
    assert main(["grid", str(run_dir), "--cell", "4"]) == 0
    assert json.loads((run_dir / "grid" / "fwl-grid.json").read_text())["cell_m"] == 4.0
    assert {"grid/highest.tif", "grid/fwl-grid.json"} <= {str(f) for f in earlier_run_files(run_dir)}
    (run_dir / "grid" / "notes.txt").write_text("mine")  # what fwl grid did not write is no run's
    with pytest.raises(OutputFolderError, match="grid/notes.txt"):
        earlier_run_files(run_dir)
    (run_dir / "grid" / "notes.txt").unlink()
    leica = str(leica_dir / "leica_a.las")
    take_output_folder(run_dir, InputNames.of([leica]), [leica])
    assert not (run_dir / "grid").exists() and not (run_dir / "echoes").exists()
