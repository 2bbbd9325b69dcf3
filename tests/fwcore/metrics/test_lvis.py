"""LVIS's own metrics against LVIS's own Level 2 of the same real shots (the shared clip, tropical forest, Gabon),
joined by LFID and shot number: LVIS's L2 took 39 of the 99 shots from another receiver channel than the one the
L1B holds, so those are checked apart (their ground only), never tuned to."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fwcore.instrument.width import recorded_pulse_fwhm_ps
from fwcore.io.lvis import read_lvis
from fwcore.metrics.lvis import LVIS_L2, LvisSettings, lvis_metrics, lvis_relative_heights, signal_start
from fwcore.metrics.pulses import FWHM_PER_SIGMA, top_heights, vertical_axis, zenith_cosine
from fwcore.metrics.waveform import NO_SIGNAL
from tests.fwcore.io.lvis_files import read_level2

LVIS = Path(__file__).resolve().parents[3] / "examples" / "data" / "lvis"
L1B = LVIS / "lvis_level1_clip_shared.h5"
L2 = LVIS / "lvis_level2_clip_shared.txt"


def clip_metrics(settings: LvisSettings = LVIS_L2, pulses=None):
    """The clip's shots, their metrics (the transmitted pulse's sigma measured from the file's TXWAVE, as a run
    does) and the sigma."""
    pulses = pulses or read_lvis(L1B)
    fwhm_ps, _ = recorded_pulse_fwhm_ps(pulses)
    sigma = fwhm_ps / float(np.median(pulses.sample_spacing_ps)) / FWHM_PER_SIGMA
    first_z, drop = vertical_axis(pulses)
    shape = np.tile([sigma, sigma / 3.0, 1.0, 0.3], (len(pulses), 1))
    metrics = lvis_metrics(pulses.samples, pulses.sample_offsets, pulses.noise_mean, pulses.noise_sd, first_z, drop,
                           zenith_cosine(pulses), shape, sigma, settings)
    return pulses, metrics, sigma


@pytest.fixture(scope="module")
def joined():
    """Per Level 2 shot: its row in the L1B, our metrics there and LVIS's."""
    pulses, metrics, _ = clip_metrics()
    level2 = read_level2(L2)
    row = {(a, s): i for i, (a, s) in enumerate(zip(pulses.lfid, pulses.shot_number))}
    rows = np.array([row[(a, s)] for a, s in zip(level2["lfid"], level2["shot_number"])])
    return pulses, metrics, level2, rows


def p50_p90(d: np.ndarray) -> tuple[float, float]:
    d = np.abs(d[np.isfinite(d)])
    return float(np.median(d)), float(np.percentile(d, 90))


def test_channel_1_shots_reproduce_lvis_level2(joined):
    pulses, metrics, level2, rows = joined
    same = (level2["channel"] == 1).all(axis=1)
    assert same.sum() == 60 and all(metrics.reason[i] == "" for i in rows)
    ground = p50_p90(metrics.ground_z[rows][same] - level2["zg"][same])
    assert ground[0] <= 0.01 and ground[1] <= 0.02  # the issue asks 0.10 / 0.30; LVIS's ZG is reproduced to 1 cm
    top = p50_p90(top_heights(pulses, metrics)[rows][same] - level2["zh"][same])
    assert top[0] <= 0.10 and top[1] <= 0.30
    rh = {k: p50_p90(metrics.rh[rows][same][:, k] - level2["rh"][k][same]) for k in (10, 25, 50, 75, 95, 98, 100)}
    assert rh[98][0] <= 0.10 and rh[98][1] <= 0.30  # asked: 0.50 / 2.0
    assert rh[50][0] <= 0.10 and rh[50][1] <= 0.50  # asked: median 0.50
    assert rh[10][0] <= 0.20 and rh[25][0] <= 0.10 and rh[75][0] <= 0.05 and rh[95][0] <= 0.05
    assert rh[100][0] <= 0.10 and rh[100][1] <= 0.30  # RH100: ZH over ZG


def test_other_channel_shots_share_only_the_ground(joined):
    """LVIS's L2 took ZH and RH of these shots from another receiver: the ground agrees, the top does not."""
    pulses, metrics, level2, rows = joined
    other = (level2["channel"] == 2).all(axis=1)
    assert other.sum() == 39
    assert p50_p90(metrics.ground_z[rows][other] - level2["zg"][other])[0] <= 0.10
    assert p50_p90(top_heights(pulses, metrics)[rows][other] - level2["zh"][other])[0] > 1.0


def test_a_hand_checked_shot():
    """Shot 9427649: SIGMEAN 62.9, the first 50 samples' sd 1.72. Its raw ground return peaks between samples 671
    (561 DN) and 672 (555 DN): ZG at 671.5, z = Z0 - 671.5 (Z0 - Z1023) / 1023 = 130.862 - 100.651
    = 30.211 (LVIS: 30.21). The samples
    rise 66, 66, 70, 74 at 479..482, past 62.9 + 5 x 1.72 = 71.5 between 481 and 482: ZH at 481.5, 58.690 m (LVIS:
    58.69); RH100 = 190 x 0.149889 = 28.479 m, 28.47 to the cm below (LVIS: 28.48, its ZH - ZG)."""
    pulses, metrics, _ = clip_metrics()
    i = int(np.flatnonzero(pulses.shot_number == 9427649)[0])
    wave = pulses.pulse_samples(i)
    assert wave[671] == 561 and wave[672] == 555 and wave[479:483].tolist() == [66, 66, 70, 74]
    assert pulses.noise_mean[i] == pytest.approx(62.9, abs=1e-4)
    assert pulses.noise_sd[i] == pytest.approx(1.72, abs=0.005)
    assert metrics.ground_index[i] == 671.5 and metrics.toploc[i] == 481.5
    assert metrics.ground_z[i] == pytest.approx(30.211, abs=0.001)
    assert top_heights(pulses, metrics)[i] == pytest.approx(58.690, abs=0.001)
    assert metrics.rh[i, 100] == pytest.approx(28.47, abs=1e-5)


def test_energy_above_the_noise_is_not_lvis_definition(joined):
    """GEDI's energy (the waveform less the noise mean) puts RH10 a metre above LVIS's and RH98 below it: LVIS's
    cumulative energy is the smoothed waveform itself."""
    _, _, level2, rows = joined
    same = (level2["channel"] == 1).all(axis=1)
    _, gedi_energy, _ = clip_metrics(dataclasses.replace(LVIS_L2, energy_above_noise=True))
    assert p50_p90(gedi_energy.rh[rows][same][:, 10] - level2["rh"][10][same])[0] > 0.5
    assert p50_p90(gedi_energy.rh[rows][same][:, 98] - level2["rh"][98][same])[0] > 0.5


def test_a_shot_without_signal_is_null_with_its_reason():
    """A real shot's noise (its first 50 samples, repeated): nothing rises 5 sd above the noise mean."""
    pulses = read_lvis(L1B)
    n = pulses.sample_offsets[1]
    noise = np.resize(pulses.samples[:50], n)
    assert np.isnan(signal_start(noise, pulses.noise_mean[0], pulses.noise_sd[0]))
    quiet = dataclasses.replace(pulses, samples=np.concatenate([noise, pulses.samples[n:]]))
    _, metrics, _ = clip_metrics(pulses=quiet)
    assert metrics.reason[0] == NO_SIGNAL and np.isnan(metrics.ground_z[0]) and np.isnan(metrics.rh[0]).all()
    assert metrics.reason[1:] == [""] * (len(pulses) - 1)


@pytest.mark.parametrize("name", ["lvis_level1_clip_shared.h5", "LVIS_Mondah_level1b.SPLIT.8.h5"])
def test_the_kernel_gives_signal_start_and_lvis_relative_heights(name):
    """lvis_metrics' kernel against the NumPy steps it replaces (signal_start, lvis_relative_heights), a shot at a
    time, on the clip and on Mondah's tall forest (RH100 to 51 m)."""
    pulses, metrics, sigma = clip_metrics(pulses=read_lvis(LVIS / name))
    first_z, drop = vertical_axis(pulses)
    checked = 0
    for i, reason in enumerate(metrics.reason):
        wave = pulses.pulse_samples(i)
        start = signal_start(wave, pulses.noise_mean[i], pulses.noise_sd[i])
        if reason == NO_SIGNAL:
            assert not start <= metrics.ground_index[i] or np.isnan(metrics.ground_index[i])
            continue
        assert metrics.toploc[i] == start
        rh = lvis_relative_heights(wave, pulses.noise_mean[i], start, metrics.botloc[i], metrics.ground_index[i],
                                   drop[i], sigma)
        assert np.allclose(metrics.rh[i], rh, rtol=0, atol=0.01 + 1e-9)  # within the cm L2 truncates to
        assert np.mean(metrics.rh[i] == rh) >= 0.99
        checked += 1
    assert checked >= 10
