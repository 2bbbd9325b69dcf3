"""Model-order selection: its BIC decisions against a SciPy reference, and what it does to waveforms."""

import math

import numpy as np
import pytest

from fwcore.engine.model import analytic_shape, model_of_individual, waveform_model
from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.engine.records import WaveformBatch
from fwcore.engine.selection import add_missing_echoes, drop_unneeded_echoes
from tests.fwcore import naive

PULSE_SIGMA = 3.0
FWHM_PS = PULSE_SIGMA * 2 * math.sqrt(2 * math.log(2)) * 1000.0
CONFIG = DecompositionConfig()
PULSE = nominal_pulse(FWHM_PS)
SQ2 = math.sqrt(2)


@pytest.mark.parametrize("flank_amplitude, needed", [(25.0, True), (0.0, False)])
def test_drop_decision_matches_a_scipy_refit(flank_amplitude, needed):
    # a strong echo and a too-close flank echo (flagged by the filter): the truth has the flank or not
    times = np.arange(120.0)
    sigma = 1.0
    truth = np.array([20.0, 200.0, 50.0, PULSE_SIGMA, SQ2, flank_amplitude, 55.0, PULSE_SIGMA, SQ2])
    raw = model_of_individual(truth, times) + np.random.default_rng(7).normal(0, sigma, times.size)
    start = truth.copy()
    start[5] = max(flank_amplitude, 8.0)  # an optimizer's guess of the flank
    lower = np.array([15, 0, 45, 1, SQ2, 0, 50, 1, SQ2], float)
    upper = np.array([25, 400, 55, 9, SQ2, 100, 60, 9, SQ2], float)
    p = CONFIG.replace(model="gaussian").kernel_params(Model.GAUSSIAN, 0.0)
    weights = np.full(times.size, 1 / sigma)
    best, _, _, n, dropped, _ = drop_unneeded_echoes(p, analytic_shape(), start.copy(), lower, upper, 2, times, raw,
                                                     raw, weights, 0.0, 119.0, PULSE_SIGMA * 2.3548, sigma)
    without, with_ = naive.chi2_without_echo(start, 1, times, raw, sigma, lower, upper)
    assert (without - with_ > 3 * math.log(times.size)) == needed  # the reference's verdict
    assert (n == 2) == needed and dropped == (0 if needed else 1)


def test_the_same_pulses_under_two_seeds_keep_the_same_echoes():
    # the default converges (tol) and polishes: seeds change the path, not the answer
    rng = np.random.default_rng(9)
    t = np.arange(200.0)
    waves = []
    for _ in range(60):
        n = int(rng.integers(1, 4))
        pos = np.sort(rng.uniform(20, 180, n))
        waves.append(waveform_model(t, 15.0, rng.uniform(20, 150, n), pos, rng.uniform(2.5, 4, n),
                                    rng.uniform(1.3, 1.8, n)) + rng.normal(0, 1.0, t.size))
    runs = [decompose_batch(WaveformBatch.from_waveforms(waves, 1000.0, rng.integers(0, 2**63, len(waves))), CONFIG,
                            PULSE)
            for _ in range(2)]
    same = total = 0
    for i in range(len(waves)):
        a, b = runs[0].waveform(i), runs[1].waveform(i)
        pa, pb = a.position[a.kept], b.position[b.kept]
        total += max(pa.size, pb.size)
        # 1 cm along the beam is 0.067 ns: 0.067 samples at 1 ns
        same += sum(np.abs(pb - u).min() < 0.067 for u in pa) if pb.size else 0
    assert same >= 0.995 * total


def _add_step(truth, start, floor_ratio, seed=3):
    """add_missing_echoes on a Gaussian waveform drawn from `truth`, starting from the one-echo `start`."""
    times = np.arange(160.0)
    raw = model_of_individual(truth, times) + np.random.default_rng(seed).normal(0, 1.0, times.size)
    lower = np.array([15, 0, 20, 1, SQ2], float)
    upper = np.array([25, 1000, 140, 9, SQ2], float)
    p = CONFIG.replace(model="gaussian", min_amplitude_ratio=floor_ratio,
                       min_snr=0.0).kernel_params(Model.GAUSSIAN, 0.0)
    weights = np.ones(times.size)
    return add_missing_echoes(p, analytic_shape(), start.copy(), lower, upper, 1, raw, np.ones(times.size, bool),
                              times, raw, raw, weights, 0, 159, PULSE_SIGMA, 1.0)


def test_the_add_step_finds_a_missed_shoulder():
    # a 30% echo 1.5 pulse FWHM behind the main one, missing from the fit the step starts from
    truth = np.array([20.0, 300.0, 50.0, PULSE_SIGMA, SQ2, 90.0, 50.0 + 1.5 * FWHM_PS / 1000, PULSE_SIGMA, SQ2])
    best, _, _, n, added, used = _add_step(truth, truth[:5], 0.05)
    assert (n, added) == (2, 1) and used > 0
    assert best[6] == pytest.approx(truth[6], abs=0.2) and best[5] == pytest.approx(90.0, rel=0.1)


@pytest.mark.parametrize("floor_ratio, expected", [(0.05, 0), (0.0, 1)])
def test_the_add_step_leaves_an_echo_the_filter_calls_weak(floor_ratio, expected):
    # a 3% echo 30 samples behind a strong one: 12 sigma, well above the residual's threshold, but below the
    # filter's 5% floor it is no missed return, and no refit is spent on it
    truth = np.array([20.0, 400.0, 50.0, PULSE_SIGMA, SQ2, 12.0, 80.0, PULSE_SIGMA, SQ2])
    _, _, _, n, added, used = _add_step(truth, truth[:5], floor_ratio)
    assert (n, added) == (1 + expected, expected)
    assert (used > 0) == bool(expected)


def _tall_canopy(rng, n_waves):
    """LVIS-like waveforms of tropical forest: 1024 samples, 8-12 layers over 40-60 m and the ground."""
    t = np.arange(1024.0)
    waves, truth = [], []
    for _ in range(n_waves):
        k = int(rng.integers(8, 13))
        ground = rng.uniform(600, 700)
        pos = np.sort(np.r_[ground - np.sort(rng.choice(np.arange(14.0, 400.0, 14.0), k - 1, replace=False)), ground])
        amp = np.r_[rng.uniform(25, 120, k - 1), rng.uniform(150, 300)]
        waves.append(waveform_model(t, 100.0, amp, pos, rng.uniform(3.0, 4.0, k), rng.uniform(1.3, 1.6, k))
                     + rng.normal(0, 2.0, t.size))
        truth.append(pos)
    return waves, truth


def test_a_local_refit_keeps_the_echoes_of_the_full_refit_on_tall_canopy():
    rng = np.random.default_rng(11)
    waves, truth = _tall_canopy(rng, 30)
    batch = WaveformBatch.from_waveforms(waves, 1000.0, np.arange(len(waves)))
    pulse = nominal_pulse(3.5 * 2 * math.sqrt(2 * math.log(2)) * 1000.0)
    local = decompose_batch(batch, DecompositionConfig(), pulse, threads=1)
    full = decompose_batch(batch, DecompositionConfig(local_refit_echoes=1000), pulse, threads=1)
    assert (local.per_waveform["n_echoes_initial"] > 6).sum() >= 20  # the local refit's case
    assert not np.array_equal(local.position, full.position)  # it ran: the paths differ
    recall, same, total = {}, 0, 0
    for name, result in (("local", local), ("full", full)):
        found = sum(np.abs(result.waveform(i).position[result.waveform(i).kept] - u).min() < 1.0
                    for i, pos in enumerate(truth) for u in pos)
        recall[name] = found / sum(p.size for p in truth)
    for i in range(len(waves)):
        a, b = local.waveform(i), full.waveform(i)
        pa, pb = a.position[a.kept], b.position[b.kept]
        total += max(pa.size, pb.size)
        same += sum(np.abs(pb - u).min() < 0.1 for u in pa) if pb.size else 0
    assert recall["local"] >= recall["full"] - 0.01 and recall["local"] > 0.8
    assert same >= 0.95 * total  # kept echoes within a tenth of a sample of the full refit's


def _dense_canopy(rng, n_waves):
    """Tall canopy whose layers overlap: 6-14 of them 6-30 samples apart (pulse FWHM 8.2), 8-120 DN at noise 2, over a
    ground of 80-300 DN, in 1024-sample records; each with its signal's window (40 samples either side)."""
    t = np.arange(1024.0)
    waves, truth, windows = [], [], []
    for _ in range(n_waves):
        k = int(rng.integers(6, 15))
        ground = rng.uniform(600, 700)
        pos = np.sort(np.r_[ground - np.cumsum(rng.uniform(6, 30, k - 1)), ground])
        amp = np.r_[rng.uniform(8, 120, k - 1), rng.uniform(80, 300)]
        waves.append(waveform_model(t, 100.0, amp, pos, rng.uniform(3.0, 4.5, k), rng.uniform(1.3, 1.6, k))
                     + rng.normal(0, 2.0, t.size))
        truth.append(pos)
        windows.append((int(pos.min()) - 40, int(pos.max()) + 40))
    return waves, truth, windows


def test_screened_drops_on_long_records_keep_the_truth_of_full_refits():
    # the same shots as short records (every drop candidate refitted to convergence) and inside 1024-sample records
    # (a candidate far above the BIC's price after a few LM steps stays): recall and precision against the truth
    waves, truth, windows = _dense_canopy(np.random.default_rng(5), 60)
    pulse = nominal_pulse(3.5 * 2 * math.sqrt(2 * math.log(2)) * 1000.0)
    long_valid = [np.zeros(w.size, bool) for w in waves]
    for v, (lo, hi) in zip(long_valid, windows):
        v[lo:hi] = True
    screened = decompose_batch(WaveformBatch.from_waveforms(waves, 1000.0, np.arange(60), long_valid), CONFIG, pulse,
                               threads=1)
    short = decompose_batch(WaveformBatch.from_waveforms([w[lo:hi] for w, (lo, hi) in zip(waves, windows)], 1000.0,
                                                         np.arange(60)), CONFIG, pulse, threads=1)
    score = {}
    for name, result, shift in (("screened", screened, 0), ("full", short, 1)):
        found = good = kept = 0
        for i, pos in enumerate(truth):
            echoes = result.waveform(i)
            at = echoes.position[echoes.kept] + (windows[i][0] if shift else 0)
            found += sum(at.size > 0 and np.abs(at - u).min() < 1.0 for u in pos)
            good += sum(np.abs(pos - u).min() < 1.0 for u in at)
            kept += at.size
        score[name] = (found / sum(p.size for p in truth), good / kept)
    assert score["full"][0] > 0.8 and score["full"][1] > 0.9  # a canopy the selection has work on
    assert score["screened"][0] >= score["full"][0] - 0.01 and score["screened"][1] >= score["full"][1] - 0.01
    assert screened.per_waveform["nfev"].sum() < short.per_waveform["nfev"].sum()
