"""The pipeline on Beam's Dask runner against a real dask.distributed cluster gives the DirectRunner's rows.

The cluster is what deploy/README.md describes for several machines: a `dask scheduler` process and
`dask worker` processes that find it through its address, each worker started in its own folder,
sharing the input and output folders (and, to spare a compilation per worker, numba's cache, as a
worker image pre-filled at build time would).
"""

import json
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.dataset as ds
import pytest

from pipeline.cli import main

ARGS = ["--limit", "300", "--points-per-range", "100", "--formats", "parquet,las", "--generations", "20"]
DASK = str(Path(sys.executable).with_name("dask"))


def rows(directory, name, keys):
    return (ds.dataset(str(directory / name), format="parquet").to_table().to_pandas()
            .sort_values(keys).reset_index(drop=True))


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A scheduler and two single-threaded workers, separate processes standing in for machines."""
    work = tmp_path_factory.mktemp("cluster")
    scheduler_file = work / "scheduler.json"
    procs = [subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                               ":0", "--scheduler-file", str(scheduler_file)], cwd=work,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(300):
            if scheduler_file.exists() and scheduler_file.stat().st_size:
                break
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        for name in ("machine-a", "machine-b"):
            home = work / name
            home.mkdir()
            procs.append(subprocess.Popen([DASK, "worker", address, "--nworkers", "1", "--nthreads", "1",
                                           "--name", name, "--local-directory", str(home), "--no-dashboard"],
                                          cwd=home, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()


def test_dask_runner_gives_the_direct_runners_rows(tmp_path, leica_dir, cluster):
    source = str(leica_dir / "leica_a.las")
    assert main(["run", source, "--output", str(tmp_path / "direct"), *ARGS]) == 0
    assert main(["run", source, "--output", str(tmp_path / "dask"), *ARGS,
                 "--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                 f"--dask_client_address={cluster}"]) == 0
    for name, keys in (("echoes", ["pulse_id", "echo_index"]), ("pulses", ["pulse_id"])):
        direct, dask = rows(tmp_path / "direct", name, keys), rows(tmp_path / "dask", name, keys)
        assert len(direct) > 0
        assert direct.equals(dask), name
    # the point cloud assembled from parts written on both workers is the DirectRunner's, byte for byte
    las = (tmp_path / "dask" / "las" / "leica_a.las").read_bytes()
    assert las == (tmp_path / "direct" / "las" / "leica_a.las").read_bytes()
    # both workers decomposed ranges: each left its own log file
    assert len(list((tmp_path / "dask" / "logs").glob("worker-*.log"))) == 2


def test_planning_on_the_workers_gives_the_drivers_plans(tmp_path, leica_dir, cluster):
    """The plan job on the cluster and on the DirectRunner: the plans the driver makes by itself, file by file."""
    import apache_beam as beam

    from fwcore.engine.config import DecompositionConfig
    from pipeline.options import check_beam_args
    from pipeline.outputs import InputNames
    from pipeline.plan import inputs_to_plan, plan_input, read_plans
    from pipeline.run import Jobs
    from pipeline.transforms import PlanFiles

    bad = tmp_path / "broken.las"
    bad.write_bytes(b"LASF" + bytes(50))
    paths = [str(leica_dir / "leica_a.las"), str(leica_dir / "leica_a.laz"), str(bad)]
    inputs = inputs_to_plan(paths, InputNames.of(paths))
    config = DecompositionConfig()
    expected = {i.path: plan_input(i, config, 400, 500) for i in inputs}
    assert expected[str(bad)].rejection and len(expected[paths[0]].ranges) == 2
    for runner, args in (("direct", []), ("dask", ["--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                                                   f"--dask_client_address={cluster}"])):
        jobs, out = Jobs(check_beam_args(args)), tmp_path / runner
        jobs.run(len(inputs), lambda p: p | beam.Create(inputs) | PlanFiles(str(out), config, 400, 500,
                                                                            spread=not jobs.dask))
        assert read_plans(out, inputs) == expected, runner
        assert (out / "rejected" / "broken.parquet").is_file()


def test_a_gedi_granule_on_the_cluster_gives_the_direct_runners_shots(tmp_path, leica_dir, cluster):
    """GEDI's beams split into ranges of shots run on the workers as on the DirectRunner: the same shots, echoes
    and forest metrics."""
    import numpy as np

    granule = str(leica_dir.parent / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5")
    args = ["--points-per-range", "30", "--formats", "parquet", "--optimizer", "lm"]
    assert main(["run", granule, "--output", str(tmp_path / "direct"), *args]) == 0
    assert main(["run", granule, "--output", str(tmp_path / "dask"), *args,
                 "--runner=apache_beam.runners.dask.dask_runner.DaskRunner", f"--dask_client_address={cluster}"]) == 0
    direct, dask = (rows(tmp_path / r, "pulses", ["pulse_id"]) for r in ("direct", "dask"))
    assert len(direct) == 164 and direct.pulse_id.equals(dask.pulse_id)
    for column in ("ground_z", "cover", "pai", "n_echoes_kept"):
        assert direct[column].equals(dask[column]), column
    assert np.array_equal(np.stack(direct.rh.to_numpy()), np.stack(dask.rh.to_numpy()))
    echoes = [rows(tmp_path / r, "echoes", ["pulse_id", "echo_index"]) for r in ("direct", "dask")]
    assert echoes[0][["x", "y", "z", "amplitude"]].equals(echoes[1][["x", "y", "z", "amplitude"]])
