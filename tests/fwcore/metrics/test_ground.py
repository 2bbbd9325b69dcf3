import numpy as np

from fwcore.metrics.ground import lowest_mode, modes


def test_the_lowest_of_two_modes_is_the_ground_at_its_subbin():
    x = np.arange(200.0)
    wave = 50 * np.exp(-0.5 * ((x - 60.3) / 4) ** 2) + 80 * np.exp(-0.5 * ((x - 120.6) / 4) ** 2)
    position, amplitude = modes(wave, 4)
    assert np.allclose(position, [60.25, 120.5]) and amplitude[1] > amplitude[0]
    assert lowest_mode(wave, 40.0, 140.0, 10.0, 4) == 120.5
    assert lowest_mode(wave, 40.0, 100.0, 10.0, 4) == 60.25  # the signal ends before the second
    assert np.isnan(lowest_mode(wave, 40.0, 140.0, 100.0, 4))  # no mode clears the threshold
