"""The virtual point cloud over a run's COPC files: each file's count, box and path, as QGIS reads them."""

import json

import laspy
import numpy as np

from pipeline.vpc import write_vpc


def test_a_vpc_lists_each_file_with_its_count_box_and_relative_path(tmp_path):
    copc = tmp_path / "run" / "copc"
    copc.mkdir(parents=True)
    files = []
    for k, shift in enumerate((0.0, 100.0)):
        las = laspy.create(point_format=6, file_version="1.4")
        las.header.scales, las.header.offsets = [0.01] * 3, [0.0] * 3
        las.x, las.y, las.z = np.array([1.0, 5.0]) + shift, np.array([2.0, 8.0]), np.array([100.0, 130.0])
        path = copc / f"f{k}.copc.laz"
        las.write(path)
        files.append(path)
    (tmp_path / "run" / "grid").mkdir()
    vpc = write_vpc(files, tmp_path / "run" / "grid" / "survey.vpc")
    doc = json.loads(vpc.read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 2
    first = doc["features"][0]
    assert first["properties"]["pc:count"] == 2
    assert first["properties"]["proj:bbox"] == [1.0, 2.0, 100.0, 5.0, 8.0, 130.0]
    assert first["assets"]["data"]["href"] == "../copc/f0.copc.laz"
    assert doc["features"][1]["properties"]["proj:bbox"][0] == 101.0
