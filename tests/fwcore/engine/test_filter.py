"""The echo filter: its codes against the naive reference, close pairs, a too-wide echo under the system model."""

from __future__ import annotations

import numpy as np

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_waveform
from fwcore.engine.model import tabulated_model
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape
from tests.fwcore import naive


def test_filter_matches_the_naive_reference():
    from fwcore.engine.filter import REJECT_REASONS, filter_echoes

    rng = np.random.default_rng(4)
    for _ in range(50):
        n = int(rng.integers(1, 8))
        position = np.sort(rng.uniform(-5, 105, n))
        amplitude, width = rng.uniform(0, 100, n), rng.uniform(1, 25, n)
        args = (0.0, 100.0, 8.0, 2.0, 4.0, 0.05, 1.0, 0.5, 3.0, float(rng.choice([1.0, 0.35, 0.6])))
        codes = filter_echoes(amplitude, position, width, *args[:3], noise_sigma=args[3], min_snr=args[4],
                              min_amplitude_ratio=args[5], min_separation_factor=args[6], min_width_factor=args[7],
                              max_width_factor=args[8], first_echo_ratio=args[9])
        assert [REJECT_REASONS[c] for c in codes] == naive.mark_spurious(amplitude, position, width, *args)


def test_of_a_close_pair_the_first_stays_when_it_is_strong_enough():
    from fwcore.engine.filter import REJECT_REASONS, filter_echoes

    # a shoulder at 40% of the stronger echo 5 samples later (pulse FWHM 8): one unresolved return
    amplitude, position, width = np.array([40.0, 100.0]), np.array([50.0, 55.0]), np.array([8.0, 8.0])

    def reasons(ratio):
        codes = filter_echoes(amplitude, position, width, 0.0, 100.0, 8.0, first_echo_ratio=ratio)
        return [REJECT_REASONS[c] for c in codes]

    assert reasons(1.0) == ["too_close", ""]  # the method's rule: the weaker goes
    assert reasons(0.35) == ["", "too_close"]  # the first surface
    assert reasons(0.5) == ["too_close", ""]  # below half of the later: a bump, not a surface


def test_a_too_wide_echo_is_flagged_under_the_system_model():
    riegl = named_response("riegl")
    shape = echo_shape(riegl, 1000.0, 4.0)
    t = np.arange(120.0)
    y = tabulated_model(t, 3.0, 80.0, 50.0, 3.6 * shape.s_min, shape)  # 3.6 x the response's FWHM
    config = DecompositionConfig(model="system", fit_target="raw")
    d = decompose_waveform(np.round(y + np.random.default_rng(2).normal(0, 0.3, t.size)), 1000.0, 0, config,
                           pulse=nominal_pulse(riegl.fwhm_ps, response=riegl))
    widest = int(np.argmax(d.fwhm))
    assert d.fwhm[widest] * 1000.0 > 3.0 * riegl.fwhm_ps and d.reject_reason[widest] == "too_wide"
