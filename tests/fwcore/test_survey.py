import numpy as np
import pytest

from fwcore.config import DecompositionConfig
from fwcore.io import input_summary
from fwcore.records import WaveformBatch
from fwcore.survey import file_system_pulse, measure_range_offset

SPACING_PS = 1000.0


def single_echo_batch(n: int, seed: int) -> tuple[WaveformBatch, np.ndarray]:
    """n waveforms of one Gaussian echo (sigma 3 samples, 100 DN over 10 DN, white noise of 1 DN), and
    the echoes' centres in ps."""
    rng = np.random.default_rng(seed)
    t = np.arange(128.0)
    centre = rng.uniform(40.0, 80.0, n)
    waveforms = [10.0 + 100.0 * np.exp(-0.5 * ((t - c) / 3.0) ** 2) + rng.normal(0.0, 1.0, t.size) for c in centre]
    return WaveformBatch.from_waveforms(waveforms, SPACING_PS, np.arange(n)), centre * SPACING_PS


def test_range_offset_is_where_the_system_puts_returns_against_the_echo_centre():
    batch, centre_ps = single_echo_batch(40, seed=3)
    config = DecompositionConfig(system_pulse_fwhm_ps=2.3548 * 3.0 * SPACING_PS)
    offset, n = measure_range_offset(batch, config, centre_ps - 1250.0)  # a system reporting 1.25 ns early
    assert n == 40
    assert offset == pytest.approx(-1250.0, abs=10.0)  # the centre of a 100-sigma echo is known to ~5 ps
    offset, _ = measure_range_offset(batch, config, centre_ps)
    assert abs(offset) < 10.0


def test_leica_range_offset_is_measured_on_its_single_returns(leica_dir):
    path = leica_dir / "leica_a.las"
    pulse = file_system_pulse(path, input_summary(path).records, DecompositionConfig())
    # 272 of the first 300 single-return pulses keep one echo; the system sits 1.19 ns before its centre
    assert pulse.range_offset_source == "single returns (272)"
    assert pulse.range_offset_ps == pytest.approx(-1187.0, abs=1.0)
    assert pulse.fwhm_ps == pytest.approx(10980.0) and pulse.shape_tolerance == pytest.approx(0.0506, abs=1e-3)
