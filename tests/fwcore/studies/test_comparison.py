"""`fwl compare` on small real samples: tables for every optimizer, figures, point counts that add up."""

import csv

import pytest

from pipeline.cli import main

FAST = "none,lm,lbfgs,ga,pso,de,mde,mde-lm,ga-iterative"
MEANS = {"none": (183.504074, 1.71793518, 0.971386080), "lm": (161.686392, 1.26982296, 0.984868708),
         "lbfgs": (152.431834, 1.11048493, 0.988029285), "ga": (156.897951, 1.20919268, 0.986061809),
         "pso": (157.191048, 1.21202613, 0.986024431), "de": (157.302790, 1.21259968, 0.986009307),
         "mde": (156.953361, 1.21180812, 0.986013250), "mde-lm": (156.953361, 1.21180812, 0.986013250),
         "ga-iterative": (164.401854, 1.29373740, 0.984342539)}


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def leica_compare(tmp_path_factory, leica_dir):
    out = tmp_path_factory.mktemp("compare")
    # small budgets keep the test short; the README's tables use the defaults
    assert main(["compare", str(leica_dir / "leica_a.las"), "--optimizers", FAST, "--limit", "40",
                 "--generations", "5", "--ga-iterative-generations", "30", "--output", str(out)]) == 0
    return out


def test_every_optimizer_has_a_row_with_physical_numbers(leica_compare):
    rows = read_csv(leica_compare / "compare.csv")
    assert [r["optimizer"] for r in rows] == FAST.split(",")
    by = {r["optimizer"]: r for r in rows}
    for r in rows:
        assert int(r["waveforms"]) == 40
        # the 40 pulses' mean fit error, RMSE and R^2 of each method, as this code computes them (seeded
        # per pulse: any change to a kernel, the estimate or the metrics moves them)
        expected = MEANS[r["optimizer"]]
        assert (float(r["fit_error"]), float(r["rmse"]), float(r["r2"])) == pytest.approx(expected, rel=1e-6)
        assert float(r["echoes_kept"]) <= float(r["echoes"])
        assert float(r["seconds"]) > 0
    # the method's fixed budgets, every generation run: MDE 60 + 80 x 60 x (5 candidates + 1 trial), DE 100 x 101
    assert float(by["mde"]["evaluations"]) >= 28_860 and float(by["de"]["evaluations"]) >= 10_100
    # every optimizer starts from the initial estimate: the local ones can only improve it
    for name in ("lm", "lbfgs", "mde-lm"):
        assert float(by[name]["fit_error"]) < float(by["none"]["fit_error"])
    assert "| lm | generalized | 40 |" in (leica_compare / "compare.md").read_text()


def test_point_counts_add_up(leica_compare):
    for r in read_csv(leica_compare / "points.csv"):
        n = {k: int(r[k]) for k in ("system_points", "decomposed_points", "matched_system", "missed_system",
                                    "matched_decomposed", "new_points")}
        assert n["matched_system"] + n["missed_system"] == n["system_points"] > 0
        assert n["matched_decomposed"] + n["new_points"] == n["decomposed_points"]
        assert float(r["median_distance"]) <= 0.5
        assert 0 <= int(r["new_at_omitted_returns"]) + int(r["new_in_dead_zone"]) <= n["new_points"]
        assert float(r["dead_zone"]) >= 3.57  # the 40 pulses' closest returns are no closer than the file's


def test_figures_are_written(leica_compare):
    pulses = list(leica_compare.glob("fit_pulse_*.png"))
    assert len(pulses) == 3
    for png in pulses + [leica_compare / "methods.png"]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_chosen_pulses_and_a_csv_input(tmp_path, neon_dir):
    assert main(["compare", str(neon_dir / "return_waveforms.csv"), "--outgoing",
                 str(neon_dir / "outgoing_pulses.csv"), "--optimizers", "none,lm", "--model", "gaussian,generalized",
                 "--limit", "10", "--pulses", "3", "--output", str(tmp_path)]) == 0
    rows = read_csv(tmp_path / "compare.csv")
    assert [(r["optimizer"], r["model"]) for r in rows] == [("none", "gaussian"), ("lm", "gaussian"),
                                                              ("none", "generalized"), ("lm", "generalized")]
    assert (tmp_path / "fit_pulse_3.png").exists()
    assert not (tmp_path / "points.csv").exists()  # a CSV has no geometry


def test_an_unknown_pulse_is_an_error(tmp_path, neon_dir, capsys):
    assert main(["compare", str(neon_dir / "return_waveforms.csv"), "--optimizers", "none", "--limit", "5",
                 "--pulses", "999999", "--output", str(tmp_path)]) == 2
    assert "no pulse with id [999999]" in capsys.readouterr().err
