import csv as csv_module
import json
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from fwcore.io.neon import read_neon_csv
from pipeline.cli import main


def test_version():
    out = subprocess.run([sys.executable, "-m", "pipeline.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("fwl 0.")


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory, neon_dir):
    lines = (neon_dir / "return_waveforms.csv").read_text().splitlines()
    # the first 12 waveforms plus id 145, which has a zero gap between two recorded segments
    rows = lines[:13] + [line for line in lines if line.startswith("145,")]
    path = tmp_path_factory.mktemp("csv") / "small.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def test_decompose_csv_writes_echoes_that_reproduce_the_fitted_model(tmp_path, small_csv, neon_dir):
    out = tmp_path / "echoes.parquet"
    code = main(["decompose-csv", str(small_csv), "--output", str(out),
                 "--outgoing", str(neon_dir / "outgoing_pulses.csv"), "--generations", "30", "--seed", "3"])
    assert code == 0
    echoes = pq.read_table(out)
    waveforms = pq.read_table(tmp_path / "echoes.waveforms.parquet").to_pandas()
    for column in ("waveform_id", "echo_index", "amplitude", "time", "sigma", "alpha", "fwhm", "energy",
                   "background", "kept", "reject_reason", "fit_error", "rmse", "r2"):
        assert column in echoes.column_names
    config = json.loads(echoes.schema.metadata[b"fwlidar.config"])
    assert config["generations"] == 30 and config["seed"] == 3
    assert len(waveforms) == 13 and (waveforms.status == "").all()
    echoes = echoes.to_pandas()
    csv = read_neon_csv(small_csv)
    for wid, samples, valid in zip(csv.waveform_id, csv.samples, csv.valid):
        rows = echoes[echoes.waveform_id == wid]
        t = np.arange(samples.size)[valid]
        model = rows.background.iloc[0] + sum(
            r.amplitude * np.exp(-np.abs(t - r.time) ** (r.alpha ** 2) / (2 * r.sigma ** 2)) for r in rows.itertuples())
        # the rows reproduce the model whose raw-sample error the table reports
        assert np.abs(model - samples[valid]).sum() == pytest.approx(rows.fit_error_raw.iloc[0], rel=1e-9)
        assert (rows.echo_index.to_numpy() == np.arange(len(rows))).all()
        assert ((rows.reject_reason == "") == rows.kept).all()


def test_decompose_csv_reports_a_missing_file(tmp_path, capsys):
    assert main(["decompose-csv", str(tmp_path / "nope.csv"), "--output", str(tmp_path / "o.parquet")]) == 2
    assert "nope.csv: no such waveform CSV" in capsys.readouterr().err


def test_decompose_csv_rejects_a_bad_option_value(tmp_path, small_csv, capsys):
    assert main(["decompose-csv", str(small_csv), "--output", str(tmp_path / "o.parquet"), "--population", "3"]) == 2
    assert "population (NP) must be at least 5" in capsys.readouterr().err


def test_config_loads_from_toml(tmp_path):
    from fwcore.engine.config import DecompositionConfig, Optimizer
    path = tmp_path / "c.toml"
    path.write_text('[decomposition]\noptimizer = "de"\npopulation = 100\n')
    config = DecompositionConfig.from_toml(path)
    assert config.optimizer is Optimizer.DE and config.population == 100
    path.write_text('[decomposition]\nspeed = 3\n')
    with pytest.raises(ValueError, match="unknown decomposition settings"):
        DecompositionConfig.from_toml(path)


def test_presets_then_toml_then_flags(tmp_path):
    from fwcore.engine.config import Optimizer
    from pipeline.cli import _config_from_args, build_parser
    path = tmp_path / "c.toml"
    path.write_text('[decomposition]\nlm_iterations = 7\n')
    args = build_parser().parse_args(["run", "--preset", "fast", "--config", str(path), "--seed", "3"])
    config = _config_from_args(args)
    assert config.optimizer is Optimizer.LM and config.lm_iterations == 7 and config.seed == 3
    paper = _config_from_args(build_parser().parse_args(["run", "--preset", "paper", "--no-select-echoes"]))
    assert not paper.select_echoes and paper.optimizer is Optimizer.MDE and paper.tol == 0.0
    assert paper.noise_estimator.value == "residual" and paper.generations == 80


def test_simulate_writes_a_flight_of_several_chunks_and_says_what_it_wrote(tmp_path, monkeypatch, capsys):
    import laspy

    from fwcore.studies import simulate

    monkeypatch.setattr(simulate, "CHUNK_PULSES", 100)
    las = tmp_path / "sim.las"
    assert main(["simulate", "--pulses", "250", "--seed", "2", "--format", "las14-internal", "--bits", "16",
                 "--background", "300", "--output", str(las)]) == 0
    points = laspy.read(las)
    truth = pq.read_table(tmp_path / "sim.truth.parquet")
    out = capsys.readouterr().out
    assert f"250 pulses, {len(points.points)} system returns" in out and f"{truth.num_rows} true echoes" in out
    assert points.header.global_encoding.waveform_data_packets_internal and points.header.number_of_evlrs == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sim.las", "sim.trajectory.csv", "sim.truth.parquet"]  # no scratch


def test_simulate_s_sensor_response_and_its_former_spelling_draw_the_same_flight(tmp_path, capsys):
    """fwl simulate's --sensor-response is the simulated sensor's (fwl run's --system-response overrides a file's
    pulse); --system-response, its former spelling there, still draws the same flight, with a warning."""
    flights = {}
    for option in ("--sensor-response", "--system-response"):
        las = tmp_path / option.strip("-") / "sim.las"
        assert main(["simulate", "--pulses", "30", "--seed", "2", option, "leica", "--output", str(las)]) == 0
        flights[option] = (pq.read_table(las.with_name("sim.truth.parquet")), capsys.readouterr().err)
    (new, said_new), (old, said_old) = flights.values()
    assert new.num_rows > 30 and new.to_pandas().equals(old.to_pandas())  # NaN where the other has NaN
    assert np.isnan(new.column("alpha").to_numpy()).all()  # echoes of the response: no generalized shape
    assert said_new == "" and "--system-response is deprecated here, give --sensor-response" in said_old


@pytest.mark.parametrize("command, given, said", [
    (["decompose-csv", "{leica}", "--output", "{out}"], "leica_a.las",
     "is a LAS/LAZ file, not a NEON-layout waveform CSV (waveform_id, n_samples, s0, ...) (fwl run reads it)"),
    (["run", "{neon}", "--output", "{out}", "--direct_num_workers=1", "--direct_running_mode=in_memory"],
     "return_waveforms.csv", "is a NEON-layout waveform CSV, not a flight line of full waveforms: give it to "
                             "fwl decompose-csv"),
    (["info", "{wvs}"], "riegl_example3.wvs", "is a PulseWaves waves file (.wvs: the samples of the .pls beside it)"),
    (["info", "{wdp}"], "leica_a.wdp", "is a LAS waveform packet file (.wdp: the samples of the .las beside it)"),
    (["run", "{noise}", "--output", "{out}", "--direct_num_workers=1", "--direct_running_mode=in_memory"],
     "noise.las", ": not a readable LAS/LAZ file: a binary file of no format fwl reads"),
    (["info", "{noise}"], "noise.las", ": not a readable LAS/LAZ file: a binary file of no format fwl reads"),
])
def test_a_file_of_the_wrong_kind_is_named_with_what_it_is(command, given, said, leica_dir, neon_dir, pulsewaves_dir,
                                                          tmp_path, capfd):
    files = {"leica": leica_dir / "leica_a.las", "neon": neon_dir / "return_waveforms.csv",
             "wdp": leica_dir / "leica_a.wdp", "wvs": pulsewaves_dir / "riegl_example3.wvs",
             "out": tmp_path / "out", "noise": tmp_path / "noise.las"}
    # random bytes without a zero byte: named "a text file (CSV)" before
    files["noise"].write_bytes(np.random.default_rng(5).integers(1, 256, 5000, dtype=np.uint8).tobytes())
    code = main([part.format(**files) for part in command])
    if command[0] == "run":  # the file is rejected with its reason, the run says so, on the terminal too
        assert code == 4
        rejected = pq.read_table(tmp_path / "out" / "rejected").to_pylist()
        assert len(rejected) == 1 and said in rejected[0]["reason"] and given in rejected[0]["reason"]
        out = capfd.readouterr().out
        assert f"rejected: {rejected[0]['reason']}" in out and "see " not in out
        assert json.loads((tmp_path / "out" / "run.json").read_text())["inputs"][0]["rejected_because"] == \
            rejected[0]["reason"]
        return
    assert code == 2
    err = capfd.readouterr().err
    assert given in err and said in err and "codec" not in err


def test_info_describes_a_neon_csv(neon_dir, capsys):
    assert main(["info", str(neon_dir / "return_waveforms.csv")]) == 0
    assert "NEON waveform CSV\n  waveforms: 250, 72-184 samples each" in capsys.readouterr().out


def test_a_folder_a_pattern_matches_that_holds_no_input_is_named_not_skipped(leica_copy, tmp_path, capfd):
    (tmp_path / "dir.las").mkdir()  # a folder named like a flight line, empty
    out = tmp_path / "out"
    code = main(["run", str(tmp_path / "*.las"), "--output", str(out), "--limit", "20", "--preset", "fast",
                 "--formats", "parquet", "--direct_num_workers=1", "--direct_running_mode=in_memory"])
    summary = json.loads((out / "run.json").read_text())
    assert code == 3 and summary["status"] == "partial"
    assert summary["not_inputs"] == [{"path": str(tmp_path / "dir.las"),
                                      "reason": "a folder that holds no .las, .laz, .pls or GEDI/LVIS L1B .h5 file"}]
    assert summary["counts"]["files_rejected"] == 0 and summary["counts"]["pulses_decomposed"] == 20
    said = capfd.readouterr()
    assert "dir.las: a folder that holds no .las, .laz, .pls or GEDI/LVIS L1B .h5 file" in said.err + said.out
    assert "rejected/" not in said.out  # nothing there to see: the summary says what happened


def test_decompose_csv_with_the_system_impulse_writes_echoes_of_its_shape(tmp_path, small_csv, neon_dir, capsys):
    from fwcore.engine.config import DecompositionConfig
    from fwcore.engine.decompose import echo_shapes
    from fwcore.instrument.pulse import SystemPulse
    from fwcore.engine.model import tabulated_model

    out = tmp_path / "echoes.parquet"
    assert main(["decompose-csv", str(small_csv), "--output", str(out), "--model", "system",
                 "--system-response", str(neon_dir / "system_impulse.csv")]) == 0
    assert "system response system_impulse.csv" in capsys.readouterr().out
    table = pq.read_table(out)
    config = json.loads(table.schema.metadata[b"fwlidar.config"])
    pulse = json.loads(table.schema.metadata[b"fwlidar.pulse"])
    assert config["model"] == "system" and pulse["response"]["source"] == "system_impulse.csv"
    # the table the engine used, rebuilt from the settings and the pulse in the table's metadata
    shape = echo_shapes(DecompositionConfig.from_dict(config), SystemPulse.from_dict(pulse), np.array([1000.0]))[1000.0]
    echoes = table.to_pandas()
    assert table.column("alpha").null_count == table.num_rows  # the generalized Gaussian's shape: none here
    csv = read_neon_csv(small_csv)
    for wid, samples, valid in zip(csv.waveform_id, csv.samples, csv.valid):
        rows = echoes[echoes.waveform_id == wid]
        t = np.arange(samples.size)[valid]
        # the config in the table's metadata and its rows reproduce the fitted model
        model = tabulated_model(t, rows.background.iloc[0], rows.amplitude, rows.time, rows.sigma, shape)
        # (the response in the metadata is rounded to 1e-6 of its peak)
        assert np.abs(model - samples[valid]).sum() == pytest.approx(rows.fit_error_raw.iloc[0], rel=1e-5)


def test_compare_lists_the_deconvolution_methods_beside_the_optimizers(tmp_path, small_csv, neon_dir):
    out = tmp_path / "compare"
    assert main(["compare", str(small_csv), "--output", str(out), "--optimizers", "lm,gold,richardson-lucy",
                 "--model", "system", "--system-response", str(neon_dir / "system_impulse.csv")]) == 0
    rows = list(csv_module.DictReader((out / "compare.csv").open()))
    assert [r["optimizer"] for r in rows] == ["lm", "gold", "richardson-lucy"]
    errors = {r["optimizer"]: float(r["fit_error"]) for r in rows}
    assert all(np.isfinite(v) and v > 0 for v in errors.values())
    assert errors["lm"] < min(errors["gold"], errors["richardson-lucy"])  # a fit beats a deconvolution's lobes


def test_info_measures_the_system_response_and_its_json_is_a_response_file(tmp_path, pulsewaves_dir, capsys):
    from fwcore.instrument.response import load_response

    assert main(["info", str(pulsewaves_dir / "riegl_example3.pls"), "--system-response"]) == 0
    assert "system response: FWHM 4.06 ns, afterpulse 10.4 ns behind the peak at 3.4%" in capsys.readouterr().out
    assert main(["info", str(pulsewaves_dir / "riegl_example3.pls"), "--system-response", "--json"]) == 0
    saved = tmp_path / "riegl.json"
    saved.write_text(capsys.readouterr().out)
    response = load_response(saved)
    assert response.fwhm_ps == pytest.approx(4062, abs=5) and response.source.startswith("isolated echoes")


def test_run_takes_a_given_response_instead_of_measuring_one(tmp_path, pulsewaves_dir):
    from fwcore.instrument.pulse import SystemPulse
    from fwcore.instrument.response import named_response

    out = tmp_path / "run"
    assert main(["run", str(pulsewaves_dir / "riegl_example3.pls"), "--output", str(out), "--limit", "40",
                 "--preset", "fast", "--formats", "parquet", "--model", "system", "--system-response", "riegl",
                 "--direct_num_workers=1", "--direct_running_mode=in_memory"]) == 0
    summary = json.loads((out / "run.json").read_text())
    (entry,) = summary["inputs"]
    shipped = named_response("riegl")
    pulse = SystemPulse.from_dict(entry["system_pulse"])  # the file's pulse, one record
    assert pulse.response.source == shipped.source == summary["overrides"]["system_response"]["source"]
    assert pulse.fwhm_ps == pytest.approx(shipped.fwhm_ps) and pulse.response == shipped
    echoes = ds.dataset(str(out / "echoes"), format="parquet").to_table()
    # a tabulated echo has no generalized Gaussian's shape: null, and no NaN in any column
    assert echoes.num_rows > 40 and echoes.column("alpha").null_count == echoes.num_rows
    assert echoes.column("sigma_chauve").null_count == echoes.num_rows
    for name in echoes.column_names:
        if pa.types.is_floating(echoes.schema.field(name).type):
            assert not pc.any(pc.is_nan(echoes.column(name))).as_py(), name
    assert main(["run", str(pulsewaves_dir / "riegl_example3.pls"), "--output", str(tmp_path / "bad"),
                 "--model", "system", "--system-response", str(tmp_path / "none.json")]) == 2
