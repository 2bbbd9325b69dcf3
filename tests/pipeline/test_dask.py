"""The same pipeline on Beam's Dask runner against a real dask.distributed cluster gives the same rows."""

import pyarrow.dataset as ds
import pytest

from pipeline.cli import main

ARGS = ["--limit", "300", "--points-per-range", "200", "--formats", "parquet,las", "--generations", "20"]


def rows(directory, name, keys):
    return (ds.dataset(str(directory / name), format="parquet").to_table().to_pandas()
            .sort_values(keys).reset_index(drop=True))


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c, \
            Client(c):
        yield c


def test_dask_runner_gives_the_direct_runners_rows(tmp_path, leica_dir, cluster):
    source = str(leica_dir / "leica_a.las")
    assert main(["run", source, "--output", str(tmp_path / "direct"), *ARGS]) == 0
    assert main(["run", source, "--output", str(tmp_path / "dask"), *ARGS,
                 "--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                 f"--dask_client_address={cluster.scheduler_address}"]) == 0
    for name, keys in (("echoes", ["pulse_id", "echo_index"]), ("pulses", ["pulse_id"])):
        direct, dask = rows(tmp_path / "direct", name, keys), rows(tmp_path / "dask", name, keys)
        assert len(direct) > 0
        assert direct.equals(dask), name
    assert (tmp_path / "dask" / "las" / "leica_a.las").exists()
