"""`fwl simulate` -> `fwl run` -> `fwl evaluate`: accuracy against the truth of a simulated flight."""

import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from pipeline.cli import main
from fwcore.studies.evaluate import evaluate_run, match_echoes, range_crlb_cm
from fwcore.studies.simulate import SensorConfig

HIGH_SNR = ["--noise", "0.5", "--shot-noise", "0", "--weak-fraction", "0"]


@pytest.fixture(scope="module")
def high_snr_run(tmp_path_factory):
    work = tmp_path_factory.mktemp("sim")
    las = work / "sim.las"
    assert main(["simulate", "--pulses", "400", "--seed", "4", "--output", str(las), *HIGH_SNR]) == 0
    # in process: the study reads the run's rows, which do not depend on the runner (a worker pool costs 4 s)
    assert main(["run", str(las), "--output", str(work / "run"), "--formats", "parquet",
                 "--direct_num_workers=1", "--direct_running_mode=in_memory"]) == 0
    return work


def test_pulse_ids_and_times_are_the_pipelines(high_snr_run):
    truth = pq.read_table(high_snr_run / "sim.truth.parquet").to_pandas()
    echoes = ds.dataset(str(high_snr_run / "run" / "echoes")).to_table().to_pandas()
    assert set(truth.pulse_id) == set(echoes.pulse_id)
    # a single-echo pulse: the decomposed time is the true one
    single = truth.groupby("pulse_id").filter(lambda g: len(g) == 1).iloc[0]
    found = echoes[(echoes.pulse_id == single.pulse_id) & echoes.kept]
    assert len(found) == 1 and found.time_ps.iloc[0] == pytest.approx(single.time_ps, abs=60)


def test_high_snr_echoes_separated_by_two_sigma_are_found_within_two_centimetres(high_snr_run):
    truth = pq.read_table(high_snr_run / "sim.truth.parquet").to_pandas().sort_values(["pulse_id", "time_ps"])
    truth = truth.reset_index(drop=True)
    echoes = ds.dataset(str(high_snr_run / "run" / "echoes")).to_table().to_pandas()
    kept = echoes[echoes.kept]
    ti, fi = match_echoes(truth.pulse_id.values, truth.time_ps.values, kept.pulse_id.values, kept.time_ps.values,
                          1000.0)
    sigma = truth.fwhm_ps / (2 * np.sqrt(2 * np.log(2)))
    same_prev = truth.pulse_id.eq(truth.pulse_id.shift())
    same_next = truth.pulse_id.eq(truth.pulse_id.shift(-1))
    gap = np.minimum(truth.time_ps.diff().where(same_prev, np.inf),
                     (-truth.time_ps.diff(-1)).where(same_next, np.inf))
    separated = (gap > 2 * sigma).to_numpy()
    matched = np.zeros(len(truth), bool)
    matched[ti] = True
    assert separated.sum() > 600
    assert matched[separated].mean() >= 0.98
    dt_cm = (kept.time_ps.to_numpy()[fi] - truth.time_ps.to_numpy()[ti]) * 0.0299792458 / 2
    assert np.sqrt(np.mean(dt_cm[separated[ti]] ** 2)) < 2.0


def test_evaluate_reports_consistent_rows(high_snr_run, capsys):
    rows = evaluate_run(high_snr_run / "run", high_snr_run / "sim.truth.parquet")
    everything = rows[0]
    assert everything["split"] == "all" and 0.9 < everything["recall"] <= 1 and 0.9 < everything["precision"] <= 1
    bands = [r for r in rows if r["split"].startswith("SNR")]
    kinds = [r for r in rows if r["split"] in ("single", "resolved", "overlapping")]
    assert sum(r["true_echoes"] for r in bands) == everything["true_echoes"] == sum(r["true_echoes"] for r in kinds)
    assert sum(r["matched"] for r in bands) == everything["matched"]
    assert everything["rmse_over_crlb"] >= 1.0  # no estimator beats the bound
    out = high_snr_run / "evaluation.md"
    assert main(["evaluate", str(high_snr_run / "run"), "--truth", str(high_snr_run / "sim.truth.parquet"),
                 "--output", str(out)]) == 0
    # the default model asks the file: the method's own flight gets its generalized Gaussians
    assert "| run (lm-mde, auto: generalized) | all |" in out.read_text()


def test_crlb_by_hand_for_a_gaussian_echo():
    # sigma_t = 2 ns, 1 ns samples, white noise 1 DN, A = 100: var(t) ~ 2 sigma dt sigma_n^2 / (sqrt(pi) A^2)
    sensor = SensorConfig(noise_sigma=1.0, shot_noise=0.0)
    sigma_ps = 2000.0
    chauve = sigma_ps  # alpha = sqrt(2): Chauve's sigma is the Gaussian's
    bound = range_crlb_cm([100.0], [chauve], [np.sqrt(2)], sensor)[0]
    var_noise = 1.0 + 1.0 / 12.0  # quantisation adds 1/12 DN^2
    expected_ps = np.sqrt(2 * sigma_ps * 1000.0 * var_noise / (np.sqrt(np.pi) * 100.0 ** 2))
    assert bound == pytest.approx(expected_ps * 0.0299792458 / 2, rel=0.01)


def test_matching_is_one_to_one_and_within_the_window():
    ti, fi = match_echoes([1, 1, 2], [1000.0, 5000.0, 1000.0], [1, 1, 2, 3], [1400.0, 1500.0, 2500.0, 1000.0], 1000.0)
    assert sorted(zip(ti.tolist(), fi.tolist())) == [(0, 0)]


def test_a_directory_that_is_no_run_is_an_error(tmp_path, capsys):
    assert main(["evaluate", str(tmp_path), "--truth", str(tmp_path / "x.parquet")]) == 2
    assert "not an fwl run output folder" in capsys.readouterr().err


def hand_built_truth():
    """Pulses of known separations, W = 4 ns (the median FWHM), noise sigma 1 DN:
    pulse 1: a single echo (resolvable); pulse 2: two echoes 10 ns apart (2.5 W, both resolvable);
    pulse 3: two echoes 3 ns apart (0.75 W: a group, centre 3,500 ps) and one 20 ns on (resolvable);
    pulse 4: two echoes 2.5 ns apart (0.625 W: a group, centre 6,250 ps); pulse 5: one echo of SNR 3."""
    return {"pulse_id": np.array([1, 2, 2, 3, 3, 3, 4, 4, 5]),
            "time_ps": np.array([5000.0, 5000.0, 15000.0, 2000.0, 5000.0, 25000.0, 5000.0, 7500.0, 5000.0]),
            "amplitude": np.array([50.0, 50.0, 40.0, 20.0, 20.0, 25.0, 20.0, 20.0, 3.0]),
            "noise_sigma": np.ones(9),
            "fwhm_ps": np.array([4000.0, 4000.0, 4000.0, 4000.0, 4000.0, 4000.0, 3000.0, 5000.0, 4000.0])}


def test_resolution_on_a_hand_built_truth_with_known_answers():
    from fwcore.studies.evaluate import score_resolution

    # kept: pulse 1 +300 ps; pulse 2 both (-400, +600 ps); pulse 3 its group's centre (1.5 ns from either echo)
    # and its far echo; pulse 4 150 ps past its group's centre (1.4 and 1.1 ns from its echoes, within 0.5 W of the
    # centre); pulse 5 a ghost 3 ns off its weak echo
    found = {"pulse_id": np.array([1, 2, 2, 3, 3, 4, 5]),
             "time_ps": np.array([5300.0, 4600.0, 15600.0, 3500.0, 25000.0, 6400.0, 8000.0])}
    scored = score_resolution(hand_built_truth(), found)
    assert scored.pulse_width_ps == 4000.0
    assert scored.resolvable == 4 and scored.matched == 4 and scored.recall == 1.0
    # right: the 4 matched and the two group centres; wrong: the ghost
    assert scored.kept == 7 and scored.right == 6 and scored.precision == pytest.approx(6 / 7)
    cm = np.array([300.0, -400.0, 600.0, 0.0]) * 0.0299792458 / 2  # ps -> cm (two-way, in air)
    assert scored.range_rmse_cm == pytest.approx(np.sqrt(np.mean(cm ** 2)), rel=1e-3)
    by = {b.label: (b.true_echoes, b.matched) for b in scored.by_separation}
    # pulse 4's pair at 0.625 W, pulse 3's at 0.75 W (neither split), pulse 2's at 2.5 W, pulse 3's far one 5 W
    assert by == {"< 0.5 W": (0, 0), "0.5-0.75 W": (2, 0), "0.75-1 W": (2, 0), "1-1.5 W": (0, 0),
                  "1.5-2 W": (0, 0), ">= 2 W": (3, 3)}


def test_a_group_whose_member_is_found_gives_no_second_right_echo():
    from fwcore.studies.evaluate import score_resolution

    # pulse 3: its 5,000 ps echo found within 1 ns, and another echo at the group's centre: the same surfaces twice
    found = {"pulse_id": np.array([3, 3, 4]), "time_ps": np.array([5200.0, 3500.0, 9000.0])}
    scored = score_resolution(hand_built_truth(), found)
    assert scored.kept == 3 and scored.right == 1  # pulse 4's 9,000 ps: 1.5 ns from its echo, 2.75 from the centre
    by = {b.label: (b.true_echoes, b.matched) for b in scored.by_separation}
    assert by["0.75-1 W"] == (2, 1)


def test_evaluate_reports_resolvable_rows(high_snr_run):
    from fwcore.studies.evaluate import resolution_of_run

    rows = evaluate_run(high_snr_run / "run", high_snr_run / "sim.truth.parquet")
    scored = resolution_of_run(high_snr_run / "run", high_snr_run / "sim.truth.parquet")
    resolvable = next(r for r in rows if r["split"] == "resolvable: >= 1 W apart, SNR >= 5")
    assert resolvable["true_echoes"] == scored.resolvable and resolvable["recall"] == scored.recall
    assert resolvable["precision"] == scored.precision and resolvable["range_rmse_cm"] == scored.range_rmse_cm
    assert scored.recall > 0.95 and 0.9 < scored.precision <= 1.0
    bins = [r for r in rows if r["split"].endswith("apart, SNR >= 5") and r is not resolvable]
    assert [r["true_echoes"] for r in bins] == [b.true_echoes for b in scored.by_separation]


def test_evaluate_refuses_the_truth_of_another_flight(high_snr_run, tmp_path, capsys):
    """A truth that shares no pulse with the run would give a table of 0 and nan: refused, exit 2, nothing written."""
    other = tmp_path / "other.las"
    assert main(["simulate", "--pulses", "50", "--seed", "5", "--output", str(other), *HIGH_SNR]) == 0
    capsys.readouterr()
    out = tmp_path / "evaluation.md"
    assert main(["evaluate", str(high_snr_run / "run"), "--truth", str(tmp_path / "other.truth.parquet"),
                 "--output", str(out)]) == 2
    assert "shares no pulse with" in capsys.readouterr().err and not out.exists()


def test_evaluate_puts_the_ideal_engine_beside_each_resolvable_split(high_snr_run):
    rows = evaluate_run(high_snr_run / "run", high_snr_run / "sim.truth.parquet")
    splits = [r["split"] for r in rows]
    resolvable = splits.index("resolvable: >= 1 W apart, SNR >= 5")
    ideal = rows[resolvable + 1]
    assert ideal["split"] == "resolvable, at the joint CRLB (an ideal engine)"
    assert ideal["true_echoes"] == rows[resolvable]["true_echoes"] and 0.9 < ideal["recall"] <= 1.0
    assert [s for s in splits if s.endswith("(an ideal engine)")][1:] == [
        f"{w}, at the joint CRLB (an ideal engine)" for w in ("0.75-1 W", "1-1.5 W", "1.5-2 W", ">= 2 W")]
    limit = rows[resolvable + 2]  # told the widths, an engine does at least as well
    assert limit["split"] == "resolvable, widths known (the limit)"
    assert ideal["recall"] <= limit["recall"] <= 1.0 and limit["range_rmse_cm"] <= ideal["range_rmse_cm"]
