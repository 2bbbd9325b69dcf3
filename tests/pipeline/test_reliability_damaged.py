"""Damaged inputs (tests/damaged.py) in one folder and alone: the run finishes, nothing is lost or invented.

The folder is run as a user runs a survey's folder, `fwl run "in/*.las" "in/*.laz"`: the patterns also match
a folder named dir.las and a link to a file that is gone, which the run names. The decomposition method does
not matter here, so the runs use `--optimizer none` (initial estimates only); the folder run uses the
DirectRunner's 2 worker processes, the runs alone the in-memory runner. The same over three draws of every
random damage (64 matches): bench/damaged_inputs.py.
"""

import json
from pathlib import Path

import laspy
import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from pipeline.cli import main
from pipeline.outputs import read_run
from pipeline.summary import EXIT_NOTHING_DONE, EXIT_OK, EXIT_PARTIAL
from tests.damaged import NOT_INPUTS, SAMPLE_PULSES, write_variants

METHOD = ["--optimizer", "none", "--points-per-range", "400"]
FOLDER_RUNNER = ["--direct_num_workers=2", "--direct_running_mode=multi_processing"]
ALONE_RUNNER = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]
# rejected whole, each with a reason naming the file
FILE_REJECTED = {"cut_header", "cut_vlrs", "empty", "foreign_text", "foreign_binary", "missing_wdp", "empty_wdp",
                 "x_scale_zero", "cut_laz", "foreign_csv", "foreign_wdp", "empty_laz"}
# damage that may leave a readable file: random bytes of text fields or mantissas, samples, a count too low,
# packets of 1 or 3 samples (what the descriptor says: pulses without an echo)
MAY_BE_HARMLESS = {"good", "flip_header", "flip_descriptor", "flip_packets", "low_count", "flip_vlrs", "samples_1",
                   "samples_3"}
# the descriptor says what no packet can be: every pulse rejected
DESCRIPTOR_REJECTED = {"samples_0", "samples_257", "spacing_0", "spacing_negative", "inf_gain", "nan_gain", "bits_0",
                       "bits_12", "bits_136"}
ALONE = ["good", "cut_points", "flip_points", "x_t_not_finite", "empty_wdp"]


def snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def rows(folder, table, source_file=None):
    frame = ds.dataset(str(folder / table), format="parquet").to_table().to_pandas()
    if source_file is not None:
        frame = frame[frame.source_file == source_file]
    keys = [k for k in ("pulse_id", "echo_index", "stage", "reason") if k in frame.columns]
    return frame.drop(columns=[c for c in ("geometry",) if c in frame.columns]) \
        .sort_values(keys).reset_index(drop=True)


@pytest.fixture(scope="module")
def damaged(tmp_path_factory, leica_dir):
    """The variants (seed 12) in one folder, run together; a foreign file in the output folder's parent."""
    root = tmp_path_factory.mktemp("damaged")
    variants = write_variants(leica_dir, root / "in", seed=12)
    before = snapshot(root / "in")
    out = root / "out"
    code = main(["run", str(root / "in" / "*.las"), str(root / "in" / "*.laz"), "--output", str(out)]
                + METHOD + FOLDER_RUNNER)
    return root, variants, out, code, before


def test_the_run_finishes_with_the_partial_code_and_leaves_the_inputs_alone(damaged):
    root, variants, out, code, before = damaged
    assert code == EXIT_PARTIAL
    summary = read_run(out)
    assert summary["status"] == "partial"
    assert sorted(i["name"] for i in summary["inputs"]) == sorted(v.file_name for v in variants)
    assert snapshot(root / "in") == before
    # what the patterns match and is no file to read: named, with why
    assert {Path(n["path"]).name: n["reason"] for n in summary["not_inputs"]} == {
        "dir.las": "a folder that holds no .las, .laz, .pls or GEDI/LVIS L1B .h5 file",
        "missing.las": f"a link to {root / 'in' / 'gone.las'}, which does not exist"}
    assert set(NOT_INPUTS) == {Path(n["path"]).name for n in summary["not_inputs"]}


def test_the_intact_file_is_decomposed_whole_and_every_input_is_accounted_for(damaged):
    _, variants, out, _, _ = damaged
    summary = read_run(out)
    per_input = {i["name"]: i for i in summary["inputs"]}
    good = per_input["good.las"]["counts"]
    assert good["pulses_decomposed"] == good["pulses_read"] == SAMPLE_PULSES
    rejected = set(rows(out, "rejected").source_file)
    decomposed = set(rows(out, "pulses").source_file)
    for v in variants:  # in pulses/ or rejected/, and a file rejected whole with its reason in run.json
        assert v.file_name in rejected | decomposed, v
        if v.name in FILE_REJECTED:
            assert v.file_name in per_input[v.file_name]["rejected_because"], v
        if v.name in DESCRIPTOR_REJECTED:
            assert per_input[v.file_name]["counts"]["pulses_rejected"] == SAMPLE_PULSES, v


def test_every_pulse_is_decomposed_or_rejected_and_the_counts_match_the_metrics(damaged):
    _, variants, out, _, _ = damaged
    summary = read_run(out)
    per_input = {i["name"]: i["counts"] for i in summary["inputs"]}
    rejected = rows(out, "rejected")
    planned = {i["name"]: i.get("pulses_planned", 0) for i in summary["inputs"]}
    for v in variants:
        c = per_input[v.file_name]
        # counted apart: the pulses the plan found in the file (its packet keys) against those the ranges wrote
        if not c["problems"]:
            assert planned[v.file_name] == c["pulses_decomposed"] + c["pulses_rejected"], v
        else:  # a range lost whole is a problem row, its pulses not rows of their own
            assert planned[v.file_name] >= c["pulses_decomposed"] + c["pulses_rejected"], v
        if v.name in FILE_REJECTED:
            assert c["files_rejected"] == 1 and c["pulses_read"] == 0, v
        elif v.pulses_intact:  # every pulse the file promises is accounted for
            assert c["pulses_read"] == SAMPLE_PULSES, v
        if v.name not in MAY_BE_HARMLESS:
            assert (rejected.source_file == v.file_name).any(), f"{v}: damage that nothing reports"
    for key in ("pulses_read", "pulses_decomposed", "pulses_rejected", "files_rejected", "problems", "echoes_kept"):
        assert summary["metrics"].get(key, 0) == summary["counts"][key], key
    assert summary["counts"]["pulses_decomposed"] > 8 * SAMPLE_PULSES  # the readable files went through


def test_rejections_name_the_file_and_the_problem(damaged):
    _, variants, out, _, _ = damaged
    rejected = rows(out, "rejected")
    assert rejected.reason.str.len().min() > 10
    files = rejected[rejected.stage == "open"]
    assert {f"{n}.las" for n in FILE_REJECTED - {"cut_laz", "empty_laz"}} | {"cut_laz.laz", "empty_laz.laz"} \
        <= set(files.source_file)
    for _, row in files.iterrows():
        assert row.source_file in row.reason
    by_file = rejected.groupby("source_file").reason.apply(" | ".join)
    assert "truncated: 1000 of 1125 point records present" in by_file["cut_points.las"]
    assert "1125 of 1000000000 point records present" in by_file["huge_count.las"]
    assert "is empty" in by_file["empty_wdp.las"] and "x scale 0" in by_file["x_scale_zero.las"]
    assert "non-finite" in by_file["y_t_not_finite.las"] and "non-finite" in by_file["nan_gain.las"]
    assert "Traceback" not in " ".join(rejected.reason)


def test_no_non_finite_value_reaches_an_output(damaged):
    _, _, out, _, _ = damaged
    for table in ("echoes", "pulses"):
        data = ds.dataset(str(out / table), format="parquet").to_table()
        for field in data.schema:
            if pa.types.is_floating(field.type):  # null is "unavailable" (radiometry), never NaN or infinite
                values = data.column(field.name).drop_null().to_numpy()
                assert np.isfinite(values).all(), (table, field.name)
    for path in sorted((out / "las").iterdir()):
        las = laspy.read(path)
        for name in ("x", "y", "z", "gps_time", "amplitude", "echo_width"):
            assert np.isfinite(np.asarray(las[name], dtype=float)).all(), (path.name, name)
        # the generalized Gaussian's shape factor; echoes of a file's own pulse (--model auto chose it) have
        # none, and say so with the no-data value their header declares
        alpha = np.asarray(las["alpha"], dtype=float)
        assert np.isfinite(alpha).all() or np.isnan(alpha).all(), path.name
    from mcap.reader import make_reader

    from pipeline.sinks import decode_waveforms

    for path in sorted((out / "mcap").iterdir()):
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(topics=["/waveform"]):
                for name, values in decode_waveforms(message.data).items():
                    if name != "reject_reasons":
                        assert np.isfinite(np.asarray(values, dtype=float)).all(), (path.name, name)
    assert not list(out.rglob("*.tmp")) and not (out / "parts").exists()


@pytest.mark.parametrize("name", ALONE)
def test_a_file_alone_gives_the_rows_it_gives_in_the_folder(damaged, name, tmp_path):
    root, variants, out, _, _ = damaged
    variant = next(v for v in variants if v.name == name)
    alone = tmp_path / "alone"
    code = main(["run", str(root / "in" / variant.file_name), "--output", str(alone)] + METHOD + ALONE_RUNNER)
    summary = read_run(alone)
    together = {i["name"]: i["counts"] for i in read_run(out)["inputs"]}[variant.file_name]
    expected = EXIT_OK if name == "good" else EXIT_NOTHING_DONE if not together["pulses_decomposed"] else EXIT_PARTIAL
    assert code == expected == summary["exit_code"]
    assert summary["inputs"][0]["counts"] == together
    for table in ("echoes", "pulses", "rejected"):
        if together["pulses_decomposed"] or table == "rejected":
            assert rows(alone, table).equals(rows(out, table, variant.file_name)), table
    if together["pulses_decomposed"]:
        assert (alone / "las" / f"{name}.las").read_bytes() == (out / "las" / f"{name}.las").read_bytes()
        assert (alone / "mcap" / f"{name}.mcap").read_bytes() == (out / "mcap" / f"{name}.mcap").read_bytes()


def test_the_generator_is_seeded(tmp_path, leica_dir):
    a = write_variants(leica_dir, tmp_path / "a", seed=3)
    write_variants(leica_dir, tmp_path / "b", seed=3)
    write_variants(leica_dir, tmp_path / "c", seed=4)
    assert snapshot(tmp_path / "a") == snapshot(tmp_path / "b") != snapshot(tmp_path / "c")
    assert len(a) == len({v.name for v in a}) >= 20
    assert json.dumps([v.damage for v in a])  # every variant says what was done to it
