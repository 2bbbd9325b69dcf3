"""The strong-echo fit: a pulse of one strong echo and candidates the filter would drop, fitted as that echo alone."""

import math

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig, PRESETS
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.model import PARAMS_PER_ECHO, tabulated_model
from fwcore.engine.records import WaveformBatch
from fwcore.engine.strong_echo import strongest_alone
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.response import named_response
from fwcore.instrument.shape import echo_shape

RIEGL = named_response("riegl")
PULSE = nominal_pulse(RIEGL.fwhm_ps, response=RIEGL)
SHAPE = echo_shape(RIEGL, 1000.0)
SYSTEM = DecompositionConfig(model="system")
FWHM = RIEGL.fwhm_ps / 1000.0  # samples


def individual(*echoes):
    """[background, (A, u, s, alpha)...] of (amplitude, position) echoes at the response's width."""
    x = [10.0]
    for amplitude, position in echoes:
        x += [amplitude, position, SHAPE.s_min, math.sqrt(2.0)]
    return np.array(x)


def test_the_strongest_echo_stands_alone_only_where_every_other_would_be_filtered_as_weak():
    p = SYSTEM.kernel_params(SYSTEM.model, 0.0)
    noise = 3.0
    # 3% of the strong echo, 2 pulse widths behind it: weak (under 5% of the largest)
    assert strongest_alone(individual((60.0, 30.0), (2000.0, 20.0)), 2, 0.0, 61.0, FWHM, noise, p) == 1
    # 40% of it, 1.5 pulse widths before it: both are kept, so no echo stands alone
    assert strongest_alone(individual((2000.0, 20.0), (800.0, 20.0 + 1.5 * FWHM)), 2, 0.0, 61.0, FWHM, noise, p) == -1
    # 40% of it but half a pulse width away: too close, not weak (a piece of a broadened return): the full path
    assert strongest_alone(individual((800.0, 20.0 - 0.5 * FWHM), (2000.0, 20.0)), 2, 0.0, 61.0, FWHM, noise,
                           p) == -1
    # 4% of it and half a pulse width away: weak
    assert strongest_alone(individual((80.0, 20.0 - 0.5 * FWHM), (2000.0, 20.0)), 2, 0.0, 61.0, FWHM, noise,
                           p) == 1
    # a pulse of one candidate has nothing to set aside
    assert strongest_alone(individual((2000.0, 20.0)), 1, 0.0, 61.0, FWHM, noise, p) == -1


def waveforms(n, second, seed=11):
    """n 62-sample 16-bit RIEGL-like waveforms: a strong echo of the response (2,000-4,000 DN over a noise of 3 DN)
    at 20-21 samples, its afterpulse 1 +/- 0.7 x the response's own (the residual a fit to the one table leaves),
    and `second` = (share of the strong echo's amplitude, samples behind it) or None."""
    rng = np.random.default_rng(seed)
    t = np.arange(62.0)
    delay, height = RIEGL.afterpulse()
    sigma = RIEGL.fwhm_ps / 1000.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    truth, out = [], []
    for _ in range(n):
        a, u = rng.uniform(2000.0, 4000.0), rng.uniform(20.0, 21.0)
        y = tabulated_model(t, 30.0, a, u, SHAPE.s_min, SHAPE)
        y += rng.uniform(-0.7, 0.7) * height * a * np.exp(-0.5 * ((t - u - delay / 1000.0) / sigma) ** 2)
        if second is not None:
            y += tabulated_model(t, 0.0, second[0] * a, u + second[1], SHAPE.s_min, SHAPE)
        out.append(np.round(y + rng.normal(0.0, 3.0, t.size)))
        truth.append(u)
    return out, np.array(truth)


def kept_per_pulse(result):
    return np.add.reduceat((result.reject == 0).astype(int), result.echo_offsets[:-1])


def decompose(waves, config):
    return decompose_batch(WaveformBatch.from_waveforms(waves, 1000.0, np.arange(len(waves))), config, PULSE,
                           threads=1)


@pytest.mark.parametrize("preset", ["default", "fast"])
def test_a_strong_echo_and_its_afterpulse_residue_costs_fewer_jacobians_for_the_same_echo(preset):
    waves, truth = waveforms(40, None)
    base = (PRESETS[preset].config() if preset in PRESETS else DecompositionConfig()).replace(model="system")
    alone = decompose(waves, base)
    joint = decompose(waves, base.replace(strong_echo_fit=False))
    kept = alone.reject == 0
    # one kept echo a pulse either way, where the echo is
    assert kept.sum() == (joint.reject == 0).sum() == 40
    assert np.abs(alone.position[kept] - truth).max() < 0.05  # samples: 7 mm of range
    assert np.abs(alone.position[kept] - joint.position[joint.reject == 0]).max() < 0.02
    # the residue was proposed (the flight's mechanism), and fitting it is what the strong-echo fit saves
    assert alone.n_echoes_initial.sum() > 40
    assert alone.nfev.sum() < 0.85 * joint.nfev.sum()


@pytest.mark.parametrize("second", [(0.4, 2.0), (0.08, 1.2)])
def test_an_echo_the_filter_keeps_takes_the_full_path_bit_for_bit(second):
    # a second surface of 40% two pulse widths behind, or of 8% 1.2 widths behind (weak, but over the 5% floor)
    waves, truth = waveforms(20, (second[0], second[1] * FWHM))
    alone = decompose(waves, SYSTEM)
    joint = decompose(waves, SYSTEM.replace(strong_echo_fit=False))
    assert np.array_equal(alone.position, joint.position) and np.array_equal(alone.amplitude, joint.amplitude)
    assert np.array_equal(alone.nfev, joint.nfev)
    assert np.array_equal(kept_per_pulse(alone), np.full(20, 2))
    first = alone.position[alone.echo_offsets[:-1]]
    assert np.abs(first - truth).max() < 0.05
