"""fwl compact: a finished run's echo parts as spatial tiles, every row once, atomically, resumable; the run stays a
run (fwl run --resume, fwl view, fwl evaluate, fwl watch's replacement of an input)."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

import pipeline.compact as compact
import pipeline.layout as layout
from fwcore.spatial import hilbert_key, square_bounds
from pipeline.cli import main
from pipeline.geoparquet import bytes_touched, centre_box, extent_of, row_groups
from pipeline.outputs import IncompleteRunError, OutputFolderError, remove_input_outputs

RUN = ["--preset", "fast", "--formats", "parquet", "--points-per-range", "400", "--direct_num_workers=1",
       "--direct_running_mode=in_memory"]
KEY = ["source_file", "pulse_id", "echo_index"]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 2,000-pulse simulated flight and its run: 10 echo parts in flight order."""
    folder = tmp_path_factory.mktemp("compact")
    assert main(["simulate", "--pulses", "2000", "--seed", "7", "--output", str(folder / "flight.las")]) == 0
    assert main(["run", str(folder / "flight.las"), "--output", str(folder / "run")] + RUN) == 0
    return folder


def _copy(flight, tmp_path) -> Path:
    shutil.copytree(flight / "run", tmp_path / "run")
    return tmp_path / "run"


def _rows(run: Path) -> pa.Table:
    """Every echo row, in a fixed order, without file metadata: the multiset of rows."""
    table = ds.dataset(str(run / "echoes"), format="parquet").to_table()
    return table.sort_by([(k, "ascending") for k in KEY]).replace_schema_metadata(None)


def _digests(run: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((run / "echoes").iterdir())}


def test_compact_rewrites_the_parts_as_tiles_holding_every_row_once(flight, tmp_path):
    run = _copy(flight, tmp_path)
    before = _rows(run)
    assert len(list((run / "echoes").glob("*.parquet"))) == 10
    assert main(["compact", str(run), "--tile-rows", "1500", "--row-group-rows", "256"]) == 0
    assert _rows(run).equals(before)
    tiles = sorted(p.name for p in (run / "echoes").iterdir())
    assert tiles == ["flight-tile-0000.parquet", "flight-tile-0001.parquet", "flight-tile-0002.parquet"]
    extent = square_bounds(extent_of(row_groups(sorted((run / "echoes").glob("*.parquet")))))
    keys = []
    for tile in tiles:
        table = pq.read_table(run / "echoes" / tile)
        assert table.num_rows <= 1500 and pq.ParquetFile(run / "echoes" / tile).metadata.row_group(0).num_rows == 256
        key = hilbert_key(table.column("x").to_numpy(), table.column("y").to_numpy(), extent)
        assert (np.diff(key.astype(np.int64)) >= 0).all()  # in Hilbert order, and tiles follow the curve
        keys.append((key.min(), key.max()))
        geo = json.loads(pq.read_schema(run / "echoes" / tile).metadata[b"geo"])["columns"]["geometry"]
        x, y, z = (table.column(c).to_numpy() for c in "xyz")
        assert geo["bbox"] == [x.min(), y.min(), z.min(), x.max(), y.max(), z.max()]
        assert geo["covering"]["bbox"]["xmin"] == ["bbox", "xmin"]
    assert all(a[1] <= b[0] for a, b in zip(keys, keys[1:]))
    summary = json.loads((run / "run.json").read_text())
    assert summary["compacted"] == {"tile_rows": 1500, "tiles": 3, "echoes": before.num_rows}
    assert [f for f in summary["files"] if f.startswith("echoes/")] == [f"echoes/{t}" for t in tiles]
    assert not (run / "parts").exists()
    tiled = _digests(run)
    assert main(["compact", str(run), "--tile-rows", "1500", "--row-group-rows", "256"]) == 0
    assert _digests(run) == tiled  # tiles compacted again are the same bytes


def test_the_compacted_run_is_still_a_run_for_resume_view_evaluate_and_watch(flight, tmp_path):
    from fwcore.studies.evaluate import evaluate_run
    from pipeline.view import queries

    run = _copy(flight, tmp_path)
    truth = flight / "flight.truth.parquet"
    evaluated = evaluate_run(run, truth)
    box = (0.3, 0.9, -50.0, 50.0)  # the viewer's: xmin, xmax, ymin, ymax
    shown = queries.echoes_in_box(run, "height", box, 100_000)
    pulse = queries.pulse_echoes(run, "flight.las", int(_rows(run).column("pulse_id")[0].as_py()))
    assert main(["compact", str(run), "--tile-rows", "1500"]) == 0
    tiles = _digests(run)
    again = evaluate_run(run, truth)  # the same statistics, up to the order of summation
    assert [r["split"] for r in again] == [r["split"] for r in evaluated]
    for a, b in zip(again, evaluated):
        np.testing.assert_allclose([a[k] for k in sorted(a) if k not in ("run", "split")],
                                   [b[k] for k in sorted(b) if k not in ("run", "split")], rtol=1e-12)
    again = queries.echoes_in_box(run, "height", box, 100_000)
    assert set(again) == set(shown) and 0 < shown["total"] == again["total"] < len(_rows(run))
    for k in shown:
        np.testing.assert_array_equal(again[k], shown[k])
    assert queries.pulse_echoes(run, "flight.las", pulse[0]["pulse_id"]) == pulse and "bbox" not in pulse[0]
    assert main(["run", str(flight / "flight.las"), "--output", str(run), "--resume"] + RUN) == 0
    assert _digests(run) == tiles  # a finished run resumed is left as it is
    removed = remove_input_outputs(run, "flight", ("echoes",))  # what fwl watch does to a replaced input
    assert sorted(p.name for p in removed) == sorted(tiles)


def test_compact_refuses_what_is_not_a_finished_run(flight, tmp_path):
    with pytest.raises(IncompleteRunError):
        compact.compact_run(tmp_path)
    run = _copy(flight, tmp_path)
    (run / "echoes" / "notes.parquet").write_bytes(b"someone's")
    with pytest.raises(OutputFolderError, match="notes.parquet"):
        compact.compact_run(run)
    (run / "echoes" / "notes.parquet").unlink()
    (run / "run.json").unlink()
    assert main(["compact", str(run)]) == 2  # interrupted: said, nothing touched
    assert len(list((run / "echoes").glob("*.parquet"))) == 10 and not (run / "parts").exists()


def _interrupt_at(monkeypatch, where: str) -> None:
    """An exception where a kill could land: while staging a tile, between the two renames, before the replaced
    parts are removed, while run.json is written."""
    def fail(*args, **kwargs):
        raise KeyboardInterrupt(where)
    if where == "staging":
        calls = iter(range(10))
        real = compact._tile
        monkeypatch.setattr(compact, "_tile", lambda *a, **k: real(*a, **k) if next(calls) < 1 else fail())
    elif where == "between renames":
        real_rename = Path.rename
        monkeypatch.setattr(Path, "rename", lambda self, to: fail() if self.name == "echoes" and
                            self.parent.name == "compact" else real_rename(self, to))
    elif where == "before removal":
        monkeypatch.setattr(compact.shutil, "rmtree", fail)
    else:
        monkeypatch.setattr(compact, "write_run_json", fail)


@pytest.mark.parametrize("where", ["staging", "between renames", "before removal", "run.json"])
def test_a_compact_interrupted_anywhere_and_rerun_gives_the_same_tiles(flight, tmp_path, monkeypatch, where):
    whole = _copy(flight, tmp_path / "whole")
    compact.compact_run(whole, tile_rows=1500)
    run = _copy(flight, tmp_path)
    before = _rows(run)
    with monkeypatch.context() as patch:
        _interrupt_at(patch, where)
        with pytest.raises(KeyboardInterrupt):
            compact.compact_run(run, tile_rows=1500)
    if (run / "echoes").is_dir():  # a reader sees the parts or the tiles, never a mix
        assert _rows(run).equals(before)
    compact.compact_run(run, tile_rows=1500)
    assert _digests(run) == _digests(whole) and _rows(run).equals(before)
    assert json.loads((run / "run.json").read_text())["compacted"]["tiles"] == 3
    assert not (run / "parts").exists()


def test_a_compact_killed_by_a_signal_and_rerun_gives_the_same_tiles(flight, tmp_path):
    whole = _copy(flight, tmp_path / "whole")
    compact.compact_run(whole, tile_rows=100)
    run = _copy(flight, tmp_path)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    process = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "compact", str(run), "--tile-rows", "100"],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    first = run / layout.STAGED / "flight-tile-0000.parquet"
    while process.poll() is None and not first.exists():
        time.sleep(0.001)
    process.send_signal(signal.SIGKILL)
    assert process.wait() == -signal.SIGKILL  # killed mid-way, not finished
    assert main(["compact", str(run), "--tile-rows", "100"]) == 0
    assert _digests(run) == _digests(whole)


@pytest.fixture(scope="module")
def square_flight(tmp_path_factory):
    """A flight over a square, small enough for a test: 100 scan lines of 40 pulses, 24 m by 24 m."""
    from fwcore.studies.simulate import SceneConfig, SensorConfig
    from fwcore.studies.truth import write_flight

    folder = tmp_path_factory.mktemp("square")
    scene = SceneConfig(speed_m_s=600.0, pulses_per_line=40, max_scan_angle_deg=1.4)
    write_flight(folder / "square.las", 4000, SensorConfig(), scene, 7, "las13-wdp")
    run = folder / "run"
    assert main(["run", str(folder / "square.las"), "--output", str(run), "--preset", "fast", "--formats", "parquet",
                 "--points-per-range", "1000", "--direct_num_workers=1", "--direct_running_mode=in_memory"]) == 0
    return run


def test_a_box_query_reads_few_row_groups_and_finds_every_echo_in_the_box(square_flight, tmp_path):
    """bench/bench_query.py's measure at a small scale: a box of 1% of the flight's area at its centre, row groups
    scaled to the flight (64 echoes, as 2,048 to a survey's)."""
    run = tmp_path / "run"
    shutil.copytree(square_flight, run)
    compact.compact_run(run, row_group_rows=64)
    files = sorted((run / "echoes").glob("*.parquet"))
    box = centre_box(extent_of(row_groups(files)))
    assert bytes_touched(files, box) <= 0.10
    xmin, ymin, xmax, ymax = box
    echoes = ds.dataset([str(f) for f in files], format="parquet")
    queried = echoes.to_table(filter=(ds.field("bbox", "xmin") <= xmax) & (ds.field("bbox", "xmax") >= xmin)
                              & (ds.field("bbox", "ymin") <= ymax) & (ds.field("bbox", "ymax") >= ymin))
    every = echoes.to_table()
    x, y = every.column("x").to_numpy(), every.column("y").to_numpy()
    scanned = every.filter(pa.array((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)))
    assert queried.num_rows > 0
    assert queried.sort_by([(k, "ascending") for k in KEY]).equals(scanned.sort_by([(k, "ascending") for k in KEY]))
