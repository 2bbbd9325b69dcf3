"""One small run for every viewer test: the bundled Leica sample, decomposed by the viewer's own background job."""

import contextlib
import dataclasses
import json
import shutil
import time
import urllib.request
from pathlib import Path

import pyarrow.dataset as ds
import pytest

from pipeline.view.jobs import Jobs
from pipeline.view.server import make_server, serve_in_thread, url_of
from tests.parallel import wait_for_kernels

# a few ranges of a few pulses, the fast preset, Beam in-process: the run stays within seconds
POINTS_PER_RANGE = 40
def run_args(limit: int) -> list[str]:
    return ["--limit", str(limit), "--preset", "fast", "--formats", "parquet",
            "--direct_num_workers=1", "--direct_running_mode=in_memory"]


RUN_ARGS = run_args(90)


@dataclasses.dataclass
class Viewed:
    url: str
    folder: Path
    run: Path
    run_id: str
    input_id: str
    job_states: list

    def get(self, path: str) -> dict:
        with urllib.request.urlopen(self.url.rstrip("/") + path, timeout=120) as r:
            return json.loads(r.read())

    def post(self, path: str, body: dict) -> dict:
        request = urllib.request.Request(self.url.rstrip("/") + path, data=json.dumps(body).encode(),
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=120) as r:
            return json.loads(r.read())

    def decompose(self, input_id: str, seconds: float = 600.0) -> dict:
        """Pick an input and poll the catalog until its background job ends; its final catalog entry
        (every job state seen is kept in job_states)."""
        self.job_states.append(self.post("/api/decompose", {"input": input_id}))
        deadline = time.time() + seconds
        while True:
            (listed,) = self.get("/api/catalog")["inputs"]
            self.job_states.append(listed["job"])
            if listed["job"]["status"] != "running" or time.time() >= deadline:
                return listed
            time.sleep(0.5)

    def echoes(self):
        return ds.dataset(str(self.run / "echoes"), format="parquet").to_table().to_pandas()

    def pulses(self):
        return ds.dataset(str(self.run / "pulses"), format="parquet").to_table().to_pandas()


@contextlib.contextmanager
def decomposed_in_viewer(folder: Path, run_name: str, args: list[str], points_per_range: int):
    """A viewer over `folder` (one input), the input picked and its background job run to the end: the Viewed
    of its run `run_name`; the server stopped after."""
    runs = folder / "runs"
    wait_for_kernels()  # the job's process would wait for the engine's compile inside the request's 120 s
    server = make_server([folder], port=0, runs_dir=runs, jobs=Jobs(runs, args, points_per_range))
    serve_in_thread(server)
    v = Viewed(url_of(server), folder, runs / run_name, "", "", [])
    try:
        (listed,) = v.get("/api/catalog")["inputs"]
        v.input_id = listed["id"]
        listed = v.decompose(v.input_id)
        assert listed["job"]["status"] == "done", (runs / f"{run_name}.log").read_text()
        v.run_id = listed["run"]
        yield v
    finally:
        server.viewer.jobs.stop_all()
        server.shutdown()
        server.server_close()


@pytest.fixture(scope="session")
def viewed(tmp_path_factory, leica_dir):
    """A viewer over a folder holding a copy of the Leica sample; picking it decomposes it in the background."""
    folder = tmp_path_factory.mktemp("view")
    (folder / "inputs").mkdir()
    for name in ("leica_a.las", "leica_a.wdp"):
        shutil.copy(leica_dir / name, folder / "inputs" / name)
    with decomposed_in_viewer(folder, "leica_a", RUN_ARGS, POINTS_PER_RANGE) as v:
        yield v


GRID_CELL = 2.0


@pytest.fixture(scope="session")
def gridded(viewed):
    """`fwl grid` on the viewed run: its own grid/ folder (2 m cells, the default output) and a second grid (5 m)
    elsewhere in the viewed folder, whose mark names the run."""
    from pipeline.cli import main

    assert main(["grid", str(viewed.run), "--cell", str(GRID_CELL), "--bin-height", "2"]) == 0
    assert main(["grid", str(viewed.run), "--cell", "5", "--output", str(viewed.folder / "maps")]) == 0
    return viewed.run / "grid"


GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
GEDI_L1B = "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"


@pytest.fixture(scope="session")
def gedi_viewed(tmp_path_factory):
    """A viewer over a folder holding the shared GEDI L1B granule (EPSG:4979; shot numbers beyond 2^53), its first
    24 shots decomposed by the viewer's background job."""
    folder = tmp_path_factory.mktemp("gedi-view")
    shutil.copy(GEDI / GEDI_L1B, folder / GEDI_L1B)
    args = ["--limit", "24", "--optimizer", "lm", "--formats", "parquet", "--direct_num_workers=1",
            "--direct_running_mode=in_memory"]
    with decomposed_in_viewer(folder, Path(GEDI_L1B).stem, args, 12) as v:
        yield v


# the drops of the modes written below the ground: the shot's passed-over modes
PASSED_OVER_DROPS_M = (2.5, 4.0)


def add_products(run: Path) -> None:
    """Write into a run's pulses/ the columns GEDI's products add (pipeline.tables: selected_algorithm, mode_z,
    agbd, agbd_se, agbd_stratum, agbd_reason, lfid, shot_number), with values made from each row so a test knows
    them: algorithm 2 for even shot numbers, else 1; modes at RH98, the ground and 2.5 and 4 m below it; agbd
    ten times RH98 (RH98 at or below 0 m: null, with a reason)."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    for part in sorted((run / "pulses").glob("*.parquet")):
        table = pq.read_table(part)
        shots = table.column("pulse_id").to_numpy()
        ground = table.column("ground_z").to_numpy(zero_copy_only=False)
        rh98 = np.array([np.nan if r is None else r[98] for r in table.column("rh").to_pylist()])
        modes = [None if not np.isfinite(g) else [g + h, g] + [g - d for d in PASSED_OVER_DROPS_M]
                 for g, h in zip(ground, rh98)]
        biomass = np.where(rh98 > 0, 10.0 * rh98, np.nan)
        columns = {
            "selected_algorithm": pa.array(np.where(shots % 2 == 0, 2, 1).astype(np.int8)),
            "mode_z": pa.array(modes, pa.list_(pa.float32())),
            "agbd": pa.array(biomass, mask=~np.isfinite(biomass)),
            "agbd_se": pa.array(biomass / 4, mask=~np.isfinite(biomass)),
            "agbd_stratum": pa.array(["GSW_SAm"] * len(shots)),
            "agbd_reason": pa.array(["" if np.isfinite(b) else "RH98 at or below the ground" for b in biomass]),
            "lfid": pa.nulls(len(shots), pa.int64()),
            "shot_number": pa.array(shots, pa.int64())}
        for name, values in columns.items():
            if name in table.column_names:
                table = table.drop_columns([name])
            table = table.append_column(name, values)
        pq.write_table(table, part)


@pytest.fixture(scope="session")
def gedi_products(gedi_viewed, tmp_path_factory):
    """A copy of the GEDI run whose pulses/ holds the products' columns (add_products), in a viewer of its own."""
    folder = tmp_path_factory.mktemp("gedi-products")
    run = folder / gedi_viewed.run.name
    shutil.copytree(gedi_viewed.run, run)
    add_products(run)
    server = make_server([run], port=0, runs_dir=folder / "runs")
    serve_in_thread(server)
    v = Viewed(url_of(server), folder, run, "", gedi_viewed.input_id, [])
    try:
        (listed,) = v.get("/api/catalog")["runs"]
        v.run_id = listed["id"]
        yield v
    finally:
        server.shutdown()
        server.server_close()
