"""`fwl run` takes PulseWaves as it takes LAS: every pulse decomposed or rejected with a reason."""

import json

import laspy
import numpy as np
import pyarrow.dataset as ds
import pytest

from fwcore.io import read_pulses
from pipeline.cli import main

SAMPLES = ("las13fwf_example1", "geolas_example1", "lvis_example1", "optech_example1", "riegl_example3")
LIMIT = 120


@pytest.fixture(scope="module")
def pulsewaves_run(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("pwrun")
    inputs = [str(leica_dir.parent / "pulsewaves" / f"{name}.pls") for name in SAMPLES]
    assert main(["run", *inputs, "--output", str(out), "--formats", "parquet,las", "--limit", str(LIMIT),
                 "--optimizer", "lm", "--points-per-range", "60"]) == 3  # some pulses rejected (GeoLas)
    return out


def _table(run, name):
    return ds.dataset(str(run / name), format="parquet").to_table().to_pandas()


def test_every_pulse_is_decomposed_or_rejected_with_a_reason(pulsewaves_run, leica_dir):
    pulses, rejected = _table(pulsewaves_run, "pulses"), _table(pulsewaves_run, "rejected")
    for name in SAMPLES:
        mine = pulses[pulses.source_file == f"{name}.pls"]
        out = rejected[rejected.source_file == f"{name}.pls"]
        # rows are returning segments: one pulse may have two (RIEGL)
        assert mine.pulse_id.nunique() + out.pulse_id.nunique() == LIMIT, name
        assert (out.reason.str.len() > 0).all()
        batch = read_pulses(leica_dir.parent / "pulsewaves" / f"{name}.pls")
        assert set(mine.pulse_id) <= set(batch.pulse_id.tolist())
    geolas = rejected[rejected.source_file == "geolas_example1.pls"]
    assert len(geolas) > 0 and geolas.reason.str.contains("mis-encoded").all()
    assert json.loads((pulsewaves_run / "run.json").read_text())["counts"]["pulses_decomposed"] > 0


def test_echo_rows_carry_channel_and_segment_and_finite_positions(pulsewaves_run):
    echoes = _table(pulsewaves_run, "echoes")
    assert {"channel", "segment", "x", "y", "z"} <= set(echoes.columns)
    assert np.isfinite(echoes[["x", "y", "z"]].to_numpy()).all()


@pytest.mark.parametrize("name,epsg", [("riegl_example3", 4978), ("lvis_example1", 4326), ("optech_example1", 4978)])
def test_point_cloud_is_las14_with_the_inputs_crs(pulsewaves_run, name, epsg):
    las = laspy.read(pulsewaves_run / "las" / f"{name}.las")
    assert (las.header.version.minor, las.header.point_format.id) == (4, 6)
    assert las.header.global_encoding.wkt and las.header.parse_crs().to_epsg() == epsg
    assert {"echo_width", "alpha", "channel"} <= set(las.point_format.extra_dimension_names)


def test_geoparquet_carries_the_earth_centred_crs(pulsewaves_run):
    import pyarrow.parquet as pq

    part = sorted((pulsewaves_run / "echoes").glob("riegl_example3*.parquet"))[0]
    geo = json.loads(pq.read_schema(part).metadata[b"geo"])
    column = geo["columns"][geo["primary_column"]]
    assert column["crs"]["id"] == {"authority": "EPSG", "code": 4978}
