"""The engine on real waveforms: NEON (Harvard Forest) and Leica ALS."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.width import csv_pulse_fwhm_ps
from fwcore.engine.records import WaveformBatch
from fwcore.io.neon import read_neon_csv
from fwcore.rng import pulse_seed

# DE at the MDE paper's comparison settings
PAPER_DE = dict(optimizer="de", population=100, generations=100)


@pytest.fixture(scope="module")
def neon(neon_dir):
    waveforms = read_neon_csv(neon_dir / "return_waveforms.csv")
    config = DecompositionConfig()
    pulse = nominal_pulse(csv_pulse_fwhm_ps(read_neon_csv(neon_dir / "outgoing_pulses.csv")))
    batch = WaveformBatch.from_waveforms(waveforms.samples, 1000.0,
                                         [pulse_seed(0, i) for i in waveforms.waveform_id], waveforms.valid)
    return batch, config, pulse


@pytest.fixture(scope="module")
def neon_results(neon):
    batch, config, pulse = neon
    return {name: decompose_batch(batch, config.replace(**kw), pulse)
            for name, kw in (("none", dict(optimizer="none")), ("mde", {}), ("de", PAPER_DE))}


def test_neon_sample_facts(neon_dir, neon):
    batch, config, pulse = neon
    assert len(batch) == 250
    # the outgoing pulses are about 15 ns wide (FWHM)
    assert 12_000 < pulse.fwhm_ps < 18_000


def test_neon_every_waveform_gets_a_result(neon_results):
    for result in neon_results.values():
        assert (result.status == 0).all()
        assert np.isfinite(result.fit_error).all()


def test_neon_mde_and_de_lower_the_initial_fit_error(neon_results):
    initial = neon_results["none"].fit_error.mean()
    assert neon_results["mde"].fit_error.mean() < 0.5 * initial
    assert neon_results["de"].fit_error.mean() < initial


def test_neon_beats_the_published_decompositions(neon_results):
    # sum |model - raw| over valid samples, mean over waveforms: waveformlidar 1453 DN, gdecomp ~1230 DN,
    # white noise alone ~230 DN; the engine's default must reach 300 DN
    assert neon_results["mde"].fit_error_raw.mean() <= 300.0


def test_neon_raw_polish_lowers_the_raw_error_where_the_denoised_fit_fails(neon, neon_results):
    batch, config, pulse = neon
    unpolished = decompose_batch(batch, config.replace(raw_polish=False), pulse)
    polished = neon_results["mde"]  # the default: the raw polish on
    changed = polished.fit_error_raw != unpolished.fit_error_raw
    # the gate sends only part of the waveforms to the polish, and it never raises a waveform's raw error
    assert 0.05 * len(batch) < changed.sum() < 0.5 * len(batch)
    assert (polished.fit_error_raw[changed] < unpolished.fit_error_raw[changed] + 1e-9).mean() > 0.9
    assert polished.fit_error_raw.mean() < unpolished.fit_error_raw.mean() - 10.0
    # the polish moves echoes, it does not add or remove them
    np.testing.assert_array_equal(np.diff(polished.echo_offsets), np.diff(unpolished.echo_offsets))


def test_leica_mde_and_de_lower_the_initial_fit_error(leica_waveforms):
    waves = leica_waveforms[:200]
    batch = WaveformBatch.from_waveforms(list(waves), 2000.0, [pulse_seed(0, i) for i in range(len(waves))])
    config, pulse = DecompositionConfig(), nominal_pulse()  # the default 4 ns pulse
    initial = decompose_batch(batch, config.replace(optimizer="none"), pulse)
    mde = decompose_batch(batch, config, pulse)
    de = decompose_batch(batch, config.replace(**PAPER_DE), pulse)
    assert (mde.status == 0).all()
    assert mde.fit_error.mean() < initial.fit_error.mean()
    assert de.fit_error.mean() < initial.fit_error.mean()
    # the file does not give the pulse width; with the default 4 ns pulse the widest returns
    # (over 3 x 4 ns) are flagged too wide, but 9 in 10 waveforms keep at least one echo
    kept = np.add.reduceat((mde.reject == 0).astype(int), mde.echo_offsets[:-1])
    assert (kept[np.diff(mde.echo_offsets) > 0] >= 1).mean() > 0.9


def test_leica_keeps_no_echo_the_noise_cannot_support_under_the_ground(leica_dir):
    # with the filter's SNR floor at 2 sigma, 7 kept echoes of 1.5-2.2 DN (sigma 0.7-0.85) lay 5-40 m under
    # the sample's lowest system return; at 3 sigma, the initial estimate's own threshold, none does
    from fwcore.instrument.measure import file_system_pulse
    from fwcore.io import read_pulses
    from fwcore.pulses import echo_positions, pulse_waveforms

    path = leica_dir / "leica_a.las"
    pulses = read_pulses(path)
    config = DecompositionConfig()
    pulse = file_system_pulse(path, pulses.return_xyz.shape[0], config)
    result = decompose_batch(pulse_waveforms(pulses, 0), config, pulse)
    z = echo_positions(pulses, result, pulse.range_offset_ps)[result.reject == 0, 2]
    assert z.size > 1400
    assert z.min() > pulses.return_xyz[:, 2].min() - 5.0
