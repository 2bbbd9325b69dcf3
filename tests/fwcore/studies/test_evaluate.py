"""`fwl simulate` -> `fwl run` -> `fwl evaluate`: accuracy against the truth of a simulated flight."""

import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from pipeline.cli import main
from fwcore.studies.evaluate import evaluate_run, match_echoes, range_crlb_cm
from fwcore.simulate import SensorConfig

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


def test_evaluate_refuses_the_truth_of_another_flight(high_snr_run, tmp_path, capsys):
    """A truth that shares no pulse with the run would give a table of 0 and nan: refused, exit 2, nothing written."""
    other = tmp_path / "other.las"
    assert main(["simulate", "--pulses", "50", "--seed", "5", "--output", str(other), *HIGH_SNR]) == 0
    capsys.readouterr()
    out = tmp_path / "evaluation.md"
    assert main(["evaluate", str(high_snr_run / "run"), "--truth", str(tmp_path / "other.truth.parquet"),
                 "--output", str(out)]) == 2
    assert "shares no pulse with" in capsys.readouterr().err and not out.exists()
