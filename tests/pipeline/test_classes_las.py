"""fwl classify's classes in the run's LAS and COPC files: every point finds its echo, and carries its class."""

import laspy
import numpy as np
import pyarrow.parquet as pq

from fwcore.engine.config import DecompositionConfig
from pipeline.classes_las import point_hash
from pipeline.cli import main
from pipeline.run import run
from tests.pipeline.conftest import IN_PROCESS


def test_the_point_clouds_carry_the_echo_table_s_classes(tmp_path):
    las = tmp_path / "forest.las"
    assert main(["simulate", "--scene", "forest", "--pulses", "3000", "--seed", "4", "--output", str(las)]) == 0
    out = tmp_path / "run"
    run([str(las)], out, DecompositionConfig(optimizer="lm", lm_iterations=5), ("parquet", "las", "copc"),
        points_per_range=1500, beam_args=IN_PROCESS, watch=False)
    assert main(["classify", str(out)]) == 0
    table = pq.read_table(out / "echoes", columns=["kept", "classification"])
    kept = table.filter(table.column("kept")).column("classification").to_numpy(zero_copy_only=False)
    expected = np.bincount(kept.astype(int), minlength=8)
    for path in (out / "las" / "forest.las", out / "copc" / "forest.copc.laz"):
        points = laspy.read(path)
        np.testing.assert_array_equal(np.bincount(np.asarray(points.classification), minlength=8), expected)
    assert expected[2] > 1000  # the ground


def test_the_point_hash_tells_points_apart():
    t = np.array([1.0, 1.0, 1.0, 2.0])
    x, y, z = np.array([5, 5, 6, 5]), np.array([7, 7, 7, 7]), np.array([9, 10, 9, 9])
    h = point_hash(t, x, y, z)
    assert len(set(h.tolist())) == 4 and point_hash(t[:1], x[:1], y[:1], z[:1])[0] == h[0]
