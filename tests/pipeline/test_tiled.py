"""The maps' tiles on the runners: the spill puts each echo in every tile whose core or margin holds it, and a
tile's task reads the same echoes from the echo table's row groups; a resumed job redoes only the tiles without
their mark; and the forest's maps and classes are the same, byte for byte, on
the DirectRunner with one and two workers and on a Dask cluster."""

import functools
import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import rasterio

from fwcore.grid import Grid
from fwcore.terrain.tiles import tiles_over
from pipeline import tiled
from pipeline.cli import main
from pipeline.tiled import (FileTask, TileTask, balanced_order, mark_tile, read_spill, read_tile, result_path,
                            run_tiles, spill, start_spill, start_work, table_bounds, table_parts, tile_is_done,
                            tile_results, tile_tasks)

IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]


def _tasks(folder, rng):
    grid = Grid(0.0, 40.0, 1.0, 40, 40)
    x, y, z = rng.uniform(0, 40, 3000), rng.uniform(0, 40, 3000), rng.normal(100, 5, 3000)
    return [TileTask(str(folder), k, t) for k, t in enumerate(tiles_over(grid, 20.0, 5.0))], x, y, z


def _sum_core(task, fail=-1, calls=None):
    """A tile's work: the sum of its core's z into its result, as a worker would write it."""
    if task.index == fail:
        raise RuntimeError("a worker lost")
    e = read_spill(task)
    core = task.tile.in_core(e["x"], e["y"])
    result_path(task, ".json").write_text(json.dumps(float(e["z"][core].sum())))
    if calls is not None:
        with open(calls, "a") as f:
            f.write(f"{task.index}\n")
    mark_tile(task)


def test_the_spill_gives_each_tile_its_core_and_margin(tmp_path):
    tasks, x, y, z = _tasks(tmp_path, np.random.default_rng(3))
    assert not start_spill(tmp_path, {"a": 1}, resume=False)
    assert spill([{"x": x, "y": y, "z": z}], tasks, ("x", "y", "z")) == 3000
    for t in tasks:
        e = read_spill(t)
        xmin, ymin, xmax, ymax = t.tile.core
        inside = (x >= xmin - 5) & (x < xmax + 5) & (y >= ymin - 5) & (y < ymax + 5)
        np.testing.assert_array_equal(np.sort(e["z"]), np.sort(z[inside]))
    # the same settings resume the spill; others start it anew
    assert start_spill(tmp_path, {"a": 1}, resume=True)
    assert not start_spill(tmp_path, {"a": 2}, resume=True) and not read_spill(tasks[0])


def test_a_tile_reads_its_core_and_margin_from_the_row_groups_that_meet_them(tmp_path):
    rng = np.random.default_rng(5)
    grid = Grid(0.0, 40.0, 1.0, 40, 40)
    x, y, z = np.sort(rng.uniform(0, 40, 3000)), rng.uniform(0, 40, 3000), rng.normal(100, 5, 3000)
    kept = rng.random(3000) > 0.1
    x[7] = np.nan  # not placed: no tile's
    files = []
    for k, lo in enumerate(range(0, 3000, 1000)):  # three files of four row groups, sorted along x
        files.append(tmp_path / f"part-{k}.parquet")
        pq.write_table(pa.table({"x": x[lo:lo + 1000], "y": y[lo:lo + 1000], "z": z[lo:lo + 1000],
                                 "kept": kept[lo:lo + 1000]}), files[-1], row_group_size=250)
    parts = table_parts(files)
    assert [p.first for p in parts] == [0, 1000, 2000] and parts[0].boxes.shape == (4, 4)
    assert table_bounds(parts) == (np.nanmin(x), y.min(), np.nanmax(x), y.max())
    tasks = tile_tasks(tmp_path, tiles_over(grid, 20.0, 5.0), parts)
    groups = [sum(len(s.groups) for s in t.sources) for t in tasks]
    assert 0 < min(groups) and max(groups) < 12  # a tile reads the row groups near it, not all twelve
    for t in tasks:
        e = read_tile(t, ("x", "z"))
        xmin, ymin, xmax, ymax = t.tile.buffered
        inside = kept & (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
        np.testing.assert_array_equal(e["row"], np.flatnonzero(inside))  # in the table's order
        np.testing.assert_array_equal(e["z"], z[inside])
        np.testing.assert_array_equal(e["batch"], e["row"] // 1000 * 1000)  # a small file: one batch, its first row
        assert set(e) == {"x", "z", "row", "batch"}


def test_a_resumed_job_redoes_only_the_tiles_without_their_mark(tmp_path):
    tasks, x, y, z = _tasks(tmp_path, np.random.default_rng(4))
    start_spill(tmp_path, {}, resume=False)
    spill([{"x": x, "y": y, "z": z}], tasks, ("x", "y", "z"))
    mark_tile(tasks[0])  # tile 0 "finished" by an earlier attempt, with a result of its own
    result_path(tasks[0], ".json").write_text("-1.0")
    calls = tmp_path / "calls.txt"
    with pytest.raises(Exception, match="a worker lost"):
        run_tiles(functools.partial(_sum_core, fail=2, calls=calls), tasks, IN_PROCESS, small=True)
    assert not tile_is_done(tasks[2])
    before = set(calls.read_text().split()) if calls.exists() else set()
    redone = run_tiles(functools.partial(_sum_core, calls=calls), tasks, IN_PROCESS, small=True)
    assert redone == len(tasks) - 1 - len(before)
    sums = {t.index: json.loads(p.read_text()) for t, p in tile_results(tasks, ".json")}
    assert sums[0] == -1.0  # kept, not redone
    for t in tasks[1:]:
        xmin, ymin, xmax, ymax = t.tile.core
        core = (x >= xmin) & (x < xmax) & (y >= ymin) & (y < ymax)
        assert sums[t.index] == pytest.approx(z[core].sum())
    assert run_tiles(_sum_core, tasks, IN_PROCESS, small=True) == 0  # all done: no job


def _after_its_tiles(task, calls):
    """A file's work: the tiles it waits for have all ended (their marks) when it runs."""
    assert all(tile_is_done(TileTask(task.folder, k, None)) for k in task.tiles), task
    result_path(task, ".json").write_text(json.dumps(sorted(task.tiles)))
    with open(calls, "a") as f:
        f.write(f"{task.name}\n")
    mark_tile(task)


def test_a_resumed_command_keeps_the_marks_of_tiles_that_read_the_table(tmp_path):
    tasks, _, _, _ = _tasks(tmp_path, np.random.default_rng(7))
    assert not start_work(tmp_path, {"a": 1}, resume=False)
    mark_tile(tasks[3])
    assert start_work(tmp_path, {"a": 1}, resume=True) and tile_is_done(tasks[3])
    assert not start_work(tmp_path, {"a": 1}, resume=False) and not tile_is_done(tasks[3])  # no --resume: anew
    mark_tile(tasks[3])
    assert not start_work(tmp_path, {"a": 2}, resume=True) and not tile_is_done(tasks[3])  # other settings: anew


def test_the_files_tasks_run_in_the_same_job_once_their_tiles_have_ended(tmp_path):
    tasks, x, y, z = _tasks(tmp_path, np.random.default_rng(6))
    start_spill(tmp_path, {}, resume=False)
    spill([{"x": x, "y": y, "z": z}], tasks, ("x", "y", "z"))
    files = [FileTask(str(tmp_path), k, f"file-{k}", tiles=(k, (k + 1) % len(tasks))) for k in range(len(tasks))]
    calls = tmp_path / "calls.txt"
    job = functools.partial(_sum_core, calls=calls)
    assert run_tiles(job, tasks, IN_PROCESS, small=True, then=(functools.partial(_after_its_tiles, calls=calls),
                                                               files)) == 2 * len(tasks)
    assert [json.loads(p.read_text()) for _, p in tile_results(files, ".json")] == [
        sorted(f.tiles) for f in files]
    # resumed with the files left to do: they run, and no tile again
    for f in files[:2]:
        (tmp_path / f"{f.name}.done").unlink()
    calls.unlink()
    assert run_tiles(job, tasks, IN_PROCESS, small=True, then=(functools.partial(_after_its_tiles, calls=calls),
                                                               files)) == 2
    assert sorted(calls.read_text().split()) == ["file-00000", "file-00001"]


def test_the_tiles_are_dealt_heaviest_first_in_a_snake():
    tasks = [TileTask("", k, None, (), w) for k, w in enumerate([1.0, 9.0, 4.0, 8.0, 2.0, 7.0])]
    order = balanced_order(tasks, 2)
    assert [t.weight for t in order] == [9.0, 8.0, 4.0, 7.0, 2.0, 1.0]
    shares = [sum(t.weight for t in order[b::2]) for b in (0, 1)]
    assert shares == [15.0, 16.0]  # 9 + 4 + 2 against 8 + 7 + 1 (in turn without the snake: 9 + 7 + 2, 8 + 4 + 1)
    assert [t.weight for t in balanced_order(tasks, 1)] == [9.0, 8.0, 7.0, 4.0, 2.0, 1.0]


def test_a_dask_job_holds_at_most_dask_partitions_partitions():
    assert tiled.dask_share(1) == 1 and tiled.dask_share(tiled.DASK_PARTITIONS) == 1
    assert tiled.dask_share(tiled.DASK_PARTITIONS + 1) == 2
    assert tiled.dask_share(624) == 5 and -(-624 // 5) <= tiled.DASK_PARTITIONS  # 50 million echoes' tiles: 125


def _maps_and_classes(run, out, runner_args):
    assert main(["grid", str(run), "--cell", "5", "--output", str(out), "--classify", *runner_args]) == 0
    maps = {}
    for name in ("dtm", "chm", "cover", "pai", "pai_corrected", "pavd", "rh98"):
        with rasterio.open(out / f"{name}.tif") as src:
            maps[name] = src.read()
    table = pq.read_table(sorted((run / "echoes").glob("*.parquet"))[0], columns=["classification", "height"])
    return maps, table


@pytest.fixture(scope="module")
def dask_cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def test_the_maps_are_the_same_on_every_runner(forest_run, tmp_path, dask_cluster, monkeypatch):
    runners = {"direct-1": ["--direct_num_workers=1", "--direct_running_mode=multi_processing"],
               "direct-2": ["--direct_num_workers=2", "--direct_running_mode=multi_processing"],
               "dask": ["--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
                        f"--dask_client_address={dask_cluster}"]}
    results = {}
    for name, args in runners.items():
        run = tmp_path / name / "run"
        shutil.copytree(forest_run, run)
        for f in (run / "echoes").glob("*.parquet"):  # unclassified, as fwl run left it
            t = pq.read_table(f)
            pq.write_table(t.drop_columns([c for c in ("classification", "height") if c in t.column_names]), f)
        if name == "dask":  # several tiles a bag partition, as on a survey of more than DASK_PARTITIONS tiles
            monkeypatch.setattr(tiled, "DASK_PARTITIONS", 3)
        results[name] = _maps_and_classes(run, tmp_path / name / "grid", args)
    (maps, table) = results["direct-1"]
    assert np.isfinite(maps["dtm"]).sum() > 100 and (table.column("classification").to_numpy(False) == 2).sum() > 100
    for name in ("direct-2", "dask"):
        other, other_table = results[name]
        assert table.equals(other_table), name
        for k in maps:
            assert maps[k].tobytes() == other[k].tobytes(), (name, k)
