"""The ground filter: each pulse's last echo, the cloth on them, a ditch's floor found from its banks."""

import numpy as np
import pytest

from fwcore.terrain.ground import GroundConfig, classify_ground, cloth_ground, last_echoes, low_noise


def test_the_last_echo_of_each_pulse_whatever_the_row_order():
    pulse = np.array([7, 3, 7, 3, 9, 7])
    echo = np.array([0, 1, 2, 0, 0, 1])
    np.testing.assert_array_equal(last_echoes(pulse, echo), [False, True, True, False, True, False])


def _forest(rng, ditch: bool):
    """Ground on a 12 % slope (with a ditch 1.2 m deep), a canopy layer 8-20 m over half of it: (x, y, z, pulse,
    echo_index, truth ground)."""
    n = 20_000
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 60, n)
    ground = 100 + 0.12 * x + 0.05 * y + rng.normal(0, 0.03, n)
    if ditch:
        ground -= 1.2 * np.exp(-0.5 * ((x - 30) / 1.5) ** 2)
    tree = x + y > 60
    canopy = ground + rng.uniform(8, 20, n)
    # a pulse under a tree: a canopy echo (a little off, the beam is slanted) then the ground
    xs = np.concatenate([x[tree] + 0.3, x])
    ys = np.concatenate([y[tree], y])
    zs = np.concatenate([canopy[tree], ground])
    pulse = np.concatenate([np.flatnonzero(tree), np.arange(n)])
    echo = np.concatenate([np.zeros(tree.sum(), int), np.where(tree, 1, 0)])
    truth = np.concatenate([np.zeros(tree.sum(), bool), np.ones(n, bool)])
    return xs, ys, zs, pulse, echo, truth


def test_ground_on_a_slope_under_canopy_is_the_last_echoes():
    x, y, z, pulse, echo, truth = _forest(np.random.default_rng(1), ditch=False)
    ground = classify_ground(x, y, z, last_echoes(pulse, echo))
    np.testing.assert_array_equal(ground, truth)


def test_a_ditch_the_cloth_bridges_is_found_by_the_densification():
    x, y, z, pulse, echo, truth = _forest(np.random.default_rng(2), ditch=True)
    last = last_echoes(pulse, echo)
    stiff = GroundConfig(cloth_resolution=3.0, rigidness=3, class_threshold=0.3, refine_passes=0)
    bottom = truth & (np.abs(x - 30) < 1.0)
    cloth = classify_ground(x, y, z, last, stiff)
    refined = classify_ground(x, y, z, last, GroundConfig(cloth_resolution=3.0, rigidness=3, class_threshold=0.3))
    assert cloth[bottom].mean() < refined[bottom].mean()
    assert refined[bottom].mean() == 1.0 and not refined[~truth].any()


def test_the_cloth_alone_and_its_settings_checked():
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 30, 3000), rng.uniform(0, 30, 3000)
    z = 50 + 0.1 * x + np.where(np.arange(3000) % 10 == 0, 15.0, 0.0)  # every tenth point a branch
    ground = cloth_ground(x, y, z)
    branch = np.arange(3000) % 10 == 0
    assert not ground[branch].any() and ground[~branch].mean() > 0.99  # the cloth misses a few at the plot's edges
    with pytest.raises(ValueError, match="rigidness"):
        GroundConfig(rigidness=4)


def test_an_echo_far_below_the_ground_is_noise_and_does_not_hang_the_cloth():
    x, y, z, pulse, echo, truth = _forest(np.random.default_rng(5), ditch=True)
    z = z.copy()
    i = np.flatnonzero(truth)[7]
    z[i] -= 19.0  # a spurious echo past the ground
    noise = low_noise(x, y, z)
    assert noise[i] and noise.sum() == 1  # the ditch's floor is not noise
    truth[i] = False
    np.testing.assert_array_equal(classify_ground(x, y, z, last_echoes(pulse, echo)), truth)


def test_the_cloth_gives_the_same_ground_every_time():
    """The cloth's OpenMP loop raced (5 of 8 repeats of this cloud differed by 9-21 points on two cores)."""
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 60, 60_000), rng.uniform(0, 60, 60_000)
    z = 0.1 * x + rng.normal(0, 0.05, x.size)
    canopy = rng.random(x.size) < 0.5
    z[canopy] += rng.uniform(0, 20, canopy.sum())
    first = cloth_ground(x, y, z)
    assert 0.3 < first.mean() < 0.7
    for _ in range(6):
        np.testing.assert_array_equal(cloth_ground(x, y, z), first)
