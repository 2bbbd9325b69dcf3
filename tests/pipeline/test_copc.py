"""COPC: every kept echo of a run in copc/<stem>.copc.laz, readable by laspy's CopcReader, its octree's nodes
holding their points, box queries exact, the file independent of how the points were split into parts."""

import json
import shutil

import laspy
import numpy as np
import pyproj
import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.copc import Cube, assemble_copc, bucket_depth
from pipeline.run import run

FAST = DecompositionConfig(optimizer="lm", lm_iterations=5)
IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]
# small nodes, buckets and grids: a deep octree of the Leica sample's ~1500 echoes, buckets spilled to disk
DEEP = {"leaf_points": 40, "bucket_points": 300, "grid_bits": 2}


@pytest.fixture(scope="module")
def leica_run(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("copc") / "run"
    run([str(leica_dir / "leica_a.las")], out, FAST, ("parquet", "las", "copc"), points_per_range=400,
        beam_args=IN_PROCESS, watch=False)
    return out


def _sorted(records: np.ndarray) -> bytes:
    return np.sort(records, order=["gps_time", "X", "Y", "Z"]).tobytes()  # bytes: NaN (no radiometry) != NaN


def _levels(path) -> dict:
    """Each level of a COPC file's octree: its nodes' keys and point counts, and its points, as laspy reads them."""
    with laspy.CopcReader.open(path) as reader:
        entries = [e for e in reader.root_page.entries.values() if e.point_count > 0]
        return {d: ({(e.key.x, e.key.y, e.key.z): e.point_count for e in entries if e.key.level == d},
                    reader.level_query(d)) for d in sorted({e.key.level for e in entries})}


def test_the_copc_holds_every_kept_echo_as_the_las_does(leica_run):
    las = laspy.read(leica_run / "las" / "leica_a.las")
    summary = json.loads((leica_run / "run.json").read_text())
    with laspy.CopcReader.open(leica_run / "copc" / "leica_a.copc.laz") as reader:
        points = reader.query()
        header = reader.header
    assert header.point_count == len(points) == summary["counts"]["echoes_kept"] == len(las) > 1000
    assert header.version == "1.4" and header.point_format.id == 6
    assert _sorted(points.array) == _sorted(las.points.array)
    np.testing.assert_array_equal(header.mins, las.header.mins)
    np.testing.assert_array_equal(header.maxs, las.header.maxs)
    np.testing.assert_array_equal(header.number_of_points_by_return, las.header.number_of_points_by_return)
    assert header.number_of_points_by_return[0] == 924  # one first echo a pulse
    # the Extra Bytes: names, descriptions with units, no-data and the ranges over all points, as the LAS's
    copc_eb = header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
    las_eb = las.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
    assert [bytes(s) for s in copc_eb] == [bytes(s) for s in las_eb]
    assert copc_eb[0].name.rstrip(b"\0") == b"amplitude" and b"[DN]" in copc_eb[0].description
    assert copc_eb[0].min[0] == pytest.approx(float(np.min(las["amplitude"])))
    assert not list((leica_run / "parts").glob("*")) if (leica_run / "parts").exists() else True
    assert "copc/leica_a.copc.laz" in summary["files"]


def test_a_deep_octree_places_each_point_in_its_node_and_answers_box_queries(tmp_path, leica_run):
    part = tmp_path / "leica_a-000000000000.las"
    shutil.copy(leica_run / "las" / "leica_a.las", part)
    out = assemble_copc([part], tmp_path / "copc" / "leica_a.copc.laz", **DEEP)
    las = laspy.read(part)
    levels = _levels(out)
    assert max(levels) >= 3 and sum(len(nodes) for nodes, _ in levels.values()) > 20
    assert sum(len(points) for _, points in levels.values()) == len(las)
    assert sorted(tmp_path.iterdir()) == [tmp_path / "copc", part]  # the spilled buckets are gone
    with laspy.CopcReader.open(out) as reader:
        centre, half = np.asarray(reader.copc_info.center), reader.copc_info.halfsize
        for d, (nodes, points) in levels.items():  # each point inside a node of its level (the info's cube)
            xyz = np.stack([points.x, points.y, points.z], axis=1)
            # a point on the cube's face may sit a LAS scale unit outside it once quantised: the writer clips it in
            assert ((xyz >= centre - half - 0.01) & (xyz <= centre + half + 0.01)).all()
            voxel = np.clip(np.floor((xyz - (centre - half)) / (2 * half / 2 ** d)), 0, 2 ** d - 1).astype(int)
            assert {tuple(v) for v in voxel} <= set(nodes), d
            assert len(points) == sum(nodes.values())
        middle = (las.header.mins + las.header.maxs) / 2
        low, high = middle - 12, middle + 12
        box = reader.query(laspy.copc.Bounds(low[:2], high[:2]))
    inside = (las.x >= low[0]) & (las.x <= high[0]) & (las.y >= low[1]) & (las.y <= high[1])
    assert 200 < len(box) == inside.sum() < len(las)
    assert _sorted(box.array) == _sorted(las.points.array[inside])


def test_the_file_does_not_depend_on_how_the_points_were_split(tmp_path, leica_run):
    las = laspy.read(leica_run / "las" / "leica_a.las")
    whole = tmp_path / "whole" / "leica_a-000000000000.las"
    whole.parent.mkdir()
    las.write(whole)
    split = []
    for i, (lo, hi) in enumerate(((0, 500), (500, 501), (501, len(las)))):
        part = tmp_path / "split" / f"leica_a-{i:012d}.las"
        part.parent.mkdir(exist_ok=True)
        piece = laspy.LasData(las.header)
        piece.points = las.points[lo:hi].copy()
        piece.write(part)
        split.append(part)
    one = _levels(assemble_copc([whole], tmp_path / "one.copc.laz", **DEEP))
    three = _levels(assemble_copc(split, tmp_path / "three.copc.laz", **DEEP))
    assert one.keys() == three.keys() and len(one) >= 3
    for d in one:
        assert one[d][0] == three[d][0] and one[d][1].array.tobytes() == three[d][1].array.tobytes()


def test_the_crs_is_declared_as_wkt(tmp_path, leica_run):
    las = laspy.read(leica_run / "las" / "leica_a.las")
    wkt = pyproj.CRS.from_epsg(25832).to_wkt(pyproj.enums.WktVersion.WKT1_GDAL)
    # the run's own WKT record (the sample's unnamed local CRS) replaced by a named one
    las.header.vlrs = [v for v in las.header.vlrs if getattr(v, "record_id", None) != 2112]
    las.header.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt.encode() + b"\0"))
    las.header.global_encoding.wkt = True
    part = tmp_path / "leica_a-000000000000.las"
    las.write(part)
    with laspy.open(assemble_copc([part], tmp_path / "leica_a.copc.laz")) as reader:  # copclib: WKT as an EVLR
        assert reader.header.global_encoding.wkt
        assert reader.header.parse_crs().to_epsg() == 25832


def test_the_bucket_depth_keeps_each_bucket_under_its_budget():
    cube = Cube.around(np.zeros(3), np.full(3, 100.0), np.full(3, 0.01))
    assert np.allclose(cube.centre, 50.01) and cube.half == pytest.approx(50.01)
    xyz = np.concatenate([np.random.default_rng(1).uniform(0, 100, (1000, 3)), np.full((300, 3), 10.0)])
    codes, counts = np.unique((lambda c: (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2])(cube.cells(xyz, 8)),
                              return_counts=True)
    assert bucket_depth(codes, counts, 2000) == 0
    assert bucket_depth(codes, counts, 1000) == 1  # the 300 points at (10, 10, 10) and their octant's share
    assert bucket_depth(codes, counts, 100) == 8  # 300 points at one place: no depth splits them


def test_an_input_without_kept_echoes_gives_an_empty_copc(tmp_path, leica_run):
    las = laspy.read(leica_run / "las" / "leica_a.las")
    empty = laspy.LasData(las.header)
    empty.points = las.points[:0].copy()
    part = tmp_path / "leica_a-000000000000.las"
    empty.write(part)
    with laspy.CopcReader.open(assemble_copc([part], tmp_path / "leica_a.copc.laz")) as reader:
        assert reader.header.point_count == 0 and len(reader.query()) == 0
