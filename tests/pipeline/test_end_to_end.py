"""fwl run on real files, compared with the in-memory engine and the system's own returns."""

import json
import shutil

import laspy
import numpy as np
import pyarrow.dataset as ds
import pytest
from scipy.spatial import cKDTree

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import SystemPulse
from fwcore.io import read_pulses
from fwcore.pulses import pulse_waveforms
from pipeline.cli import main

ECHO_COLUMNS = ["source_file", "pulse_id", "gps_time", "echo_index", "echo_count", "time_ps", "amplitude", "sigma_chauve",
                "alpha", "fwhm_ps", "energy", "background", "x", "y", "z", "kept", "reject_reason", "fit_error",
                "rmse", "r2", "optimizer", "model"]
PULSE_COLUMNS = ["source_file", "pulse_id", "gps_time", "n_samples", "sample_spacing_ps", "noise_sigma", "background",
                 "fit_error", "rmse", "r2", "n_echoes_initial", "n_echoes", "n_echoes_kept", "n_system_returns",
                 "optimizer", "model"]


def table(directory, name):
    return ds.dataset(str(directory / name), format="parquet").to_table().to_pandas()


@pytest.fixture(scope="module")
def leica_run(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("run")
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--points-per-range", "300",
                 "--direct_num_workers=2", "--direct_running_mode=multi_processing"]) == 0
    return out


def test_counts_add_up_and_match_the_metrics(leica_run, leica_dir):
    summary = json.loads((leica_run / "run.json").read_text())
    c = summary["counts"]
    # the sample's distinct packets, read by laspy: a count apart from ours
    packets = np.unique(np.asarray(laspy.read(leica_dir / "leica_a.las").wavepacket_offset)).size
    assert packets == 924 == summary["inputs"][0]["pulses_planned"] == c["pulses_decomposed"] + c["pulses_rejected"]
    assert c["pulses_rejected"] == 0
    assert summary["metrics"]["pulses_read"] == 924 and summary["metrics"]["pulses_decomposed"] == 924
    assert summary["metrics"]["echoes_kept"] == c["echoes_kept"]
    assert summary["config"]["optimizer"] == "lm-mde" and summary["versions"]["apache-beam"]


def test_tables_have_their_schemas_and_the_config(leica_run):
    echoes = ds.dataset(str(leica_run / "echoes"), format="parquet")
    assert set(ECHO_COLUMNS) <= set(echoes.schema.names)
    assert json.loads(echoes.schema.metadata[b"fwlidar.config"])["population"] == 60
    assert set(PULSE_COLUMNS) <= set(ds.dataset(str(leica_run / "pulses"), format="parquet").schema.names)
    pulses = table(leica_run, "pulses")
    assert len(pulses) == 924 and pulses.pulse_id.is_unique
    assert (pulses.n_system_returns.sum()) == 1125


def test_duckdb_reads_the_dataset(leica_run):
    import duckdb
    kept, pulses = duckdb.sql(f"SELECT count(*) FILTER (WHERE kept), count(DISTINCT pulse_id) "
                              f"FROM read_parquet('{leica_run}/echoes/*.parquet')").fetchall()[0]
    assert pulses == 924 and kept == json.loads((leica_run / "run.json").read_text())["counts"]["echoes_kept"]


def test_echo_rows_match_the_in_memory_engine(leica_run, leica_dir):
    from fwcore.instrument.measure import file_system_pulse
    pulses = read_pulses(leica_dir / "leica_a.las")
    config = DecompositionConfig()
    system = file_system_pulse(leica_dir / "leica_a.las", 1125, config)  # as the run measures it
    assert system.echo_model(config.model) is Model.SYSTEM  # --model auto gives Leica its own pulse
    result = decompose_batch(pulse_waveforms(pulses, config.seed), config, system)
    echoes = table(leica_run, "echoes").sort_values(["pulse_id", "echo_index"])
    order = np.argsort(pulses.pulse_id, kind="stable")
    expected_amplitude = np.concatenate([result.waveform(i).amplitude for i in order])
    np.testing.assert_array_equal(echoes.amplitude.to_numpy(), expected_amplitude)
    expected_time = np.concatenate([result.waveform(i).position * 2000.0 for i in order])
    np.testing.assert_allclose(echoes.time_ps.to_numpy(), expected_time)


def test_point_cloud_opens_and_matches_the_system_returns(leica_run, leica_dir):
    las = laspy.read(leica_run / "las" / "leica_a.las")
    echoes = table(leica_run, "echoes")
    kept = echoes[echoes.kept]
    assert len(las.points) == len(kept)
    assert las.header.point_format.id == 6 and las.header.version.minor == 4
    ours = np.stack([las.x, las.y, las.z], axis=1)
    system = read_pulses(leica_dir / "leica_a.las").return_xyz
    d_system, _ = cKDTree(ours).query(system)
    d_ours, _ = cKDTree(system).query(ours)
    recall = (d_system <= 0.5).mean()
    extra = (d_ours > 0.5).sum() / len(system)
    # the strongest peer recovers 99% but keeps twice as many extra echoes as there are returns;
    # ours (echoes of Leica's own pulse, which --model auto chooses): 98.5% and 34%, the extra ones mostly
    # weak echoes inside the system's dead zone (README, "Engine benchmark"; the 25% is not reached)
    assert recall >= 0.98
    assert extra < 0.37
    # echoes placed with the file's range offset (README, "The range offset"): 0.156 m without it
    assert np.median(d_system[d_system <= 0.5]) < 0.05
    pulse = SystemPulse.from_dict(json.loads((leica_run / "run.json").read_text())["inputs"][0]["system_pulse"])
    assert pulse.model == "system" and pulse.model_choice.startswith("system: at held-out samples")
    # the system reports a return 1.21 ns before the centre of the response's lobe
    assert pulse.range_offset_ps == pytest.approx(-1213.3, abs=1.0)
    assert pulse.range_offset_source == "single returns (268)"


def test_mcap_holds_point_clouds_and_waveforms(leica_run):
    from mcap.reader import make_reader
    with open(leica_run / "mcap" / "leica_a.mcap", "rb") as f:
        reader = make_reader(f)
        topics = {}
        for schema, channel, message in reader.iter_messages():
            topics.setdefault(channel.topic, []).append((schema.name, message))
    assert {"/echoes", "/waveform"} <= set(topics)
    assert topics["/echoes"][0][0] == "foxglove.PointCloud"
    from pipeline.sinks import decode_waveforms
    assert topics["/waveform"][0][0] == "fwlidar.Waveforms"
    batches = [decode_waveforms(m.data) for _, m in topics["/waveform"]]
    assert sum(b["pulse_id"].size for b in batches) == 924
    first = batches[0]
    assert np.diff(first["sample_offsets"])[0] == 256 and first["raw"].size == first["model"].size
    # the model a pulse's echoes give at its samples: its background where no echo reaches, near its samples
    assert np.median(np.abs(first["model"] - first["raw"])) < 3.0
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    clouds = [PointCloud.FromString(m.data) for _, m in topics["/echoes"]]
    assert sum(len(c.data) // c.point_stride for c in clouds) == len(table(leica_run, "echoes").query("kept"))


def test_directory_with_a_truncated_and_a_plain_file(tmp_path, leica_dir):
    data = tmp_path / "flight"
    data.mkdir()
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", data / f"good{suffix}")
        shutil.copy(leica_dir / f"leica_a{suffix}", data / f"cut{suffix}")
    wdp = (data / "cut.wdp").read_bytes()
    (data / "cut.wdp").write_bytes(wdp[: len(wdp) // 3])  # packets of pulses ~300 on are lost
    laspy.convert(laspy.read(leica_dir / "leica_a.las"), point_format_id=1).write(data / "plain.las")
    out = tmp_path / "out"
    assert main(["run", str(data / "*.las"), "--output", str(out), "--limit", "400", "--generations", "5"]) == 3
    c = json.loads((out / "run.json").read_text())["counts"]
    assert c["files_rejected"] == 1
    assert c["pulses_read"] == 800 == c["pulses_decomposed"] + c["pulses_rejected"]
    rejected = table(out, "rejected")
    plain = rejected[rejected.source_file == "plain.las"]
    assert plain.stage.tolist() == ["open"] and "point format 1 has no waveform packets" in plain.reason.iloc[0]
    cut = rejected[rejected.source_file == "cut.las"]
    assert len(cut) == c["pulses_rejected"] > 0 and (cut.stage == "read").all()
    assert cut.reason.str.contains("beyond the end of cut.wdp").all()
    assert {p.name for p in (out / "las").iterdir()} == {"good.las", "cut.las"}


def test_an_input_that_matches_nothing_is_an_error(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nothing*.las"), "--output", str(tmp_path / "out")]) == 2
    assert "nothing*.las: no file matches this input" in capsys.readouterr().err
