"""One small run for every viewer test: the bundled Leica sample, decomposed by the viewer's own background job."""

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


@pytest.fixture(scope="session")
def viewed(tmp_path_factory, leica_dir):
    """A viewer over a folder holding a copy of the Leica sample; picking it decomposes it in the background."""
    folder = tmp_path_factory.mktemp("view")
    (folder / "inputs").mkdir()
    for name in ("leica_a.las", "leica_a.wdp"):
        shutil.copy(leica_dir / name, folder / "inputs" / name)
    runs = folder / "runs"
    server = make_server([folder], port=0, runs_dir=runs, jobs=Jobs(runs, RUN_ARGS, POINTS_PER_RANGE))
    serve_in_thread(server)
    v = Viewed(url_of(server), folder, runs / "leica_a", "", "", [])
    try:
        (listed,) = v.get("/api/catalog")["inputs"]
        v.input_id = listed["id"]
        listed = v.decompose(v.input_id)
        assert listed["job"]["status"] == "done", (runs / "leica_a.log").read_text()
        v.run_id = listed["run"]
        yield v
    finally:
        server.viewer.jobs.stop_all()
        server.shutdown()
        server.server_close()


GRID_CELL = 2.0


@pytest.fixture(scope="session")
def gridded(viewed):
    """`fwl grid` on the viewed run: its own grid/ folder (2 m cells, the default output) and a second grid (5 m)
    elsewhere in the viewed folder, whose mark names the run."""
    from pipeline.cli import main

    assert main(["grid", str(viewed.run), "--cell", str(GRID_CELL), "--bin-height", "2"]) == 0
    assert main(["grid", str(viewed.run), "--cell", "5", "--output", str(viewed.folder / "maps")]) == 0
    return viewed.run / "grid"
