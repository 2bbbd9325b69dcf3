import h5py
import numpy as np

from tests.fwcore.metrics.conftest import L1B, L2A

from fwcore.metrics.signal import SIGMA_PER_WIDTH, gaussian_smooth, signal_extent, subbin_grid


def test_smoothing_keeps_the_area_and_the_centre_of_a_pulse():
    x = np.arange(300.0)
    pulse = 100.0 * np.exp(-0.5 * ((x - 150) / 3.0) ** 2)
    smoothed = gaussian_smooth(pulse, 6.5)
    assert np.isclose(smoothed.sum(), pulse.sum()) and np.argmax(smoothed) == 150
    expected_sigma = np.hypot(3.0, 6.5 * SIGMA_PER_WIDTH)  # Gaussians convolve by adding variances
    assert np.isclose(smoothed.max(), pulse.sum() / (expected_sigma * np.sqrt(2 * np.pi)), rtol=1e-3)


def test_smoothing_reproduces_nasas_smoothed_peak(gedi_beams):
    b = gedi_beams[0]
    with h5py.File(L2A) as f:
        pk_sm = dict(zip(f[b["beam"]]["shot_number"][:], f[b["beam"]]["rx_processing_a1/pk_sm"][:]))
    with h5py.File(L1B) as f:
        shots = f[b["beam"]]["shot_number"][:]
    ours = [gaussian_smooth(b["samples"][b["offsets"][i]:b["offsets"][i + 1]], 6.5).max() for i in range(len(shots))]
    assert np.median(np.abs(np.array(ours) - [pk_sm[s] for s in shots])) < 0.5  # DN, of peaks near 800


def test_extent_on_the_subbin_grid():
    values = np.r_[np.zeros(10), np.linspace(0, 10, 11), np.linspace(10, 0, 11), np.zeros(10)]
    x, fine = subbin_grid(values, 4)
    top, bottom = signal_extent(x, fine, 2.0, 5.0)
    assert top == 12.25 and bottom == 25.75  # first sub-bin above 2, last above 5
    assert np.isnan(signal_extent(x, fine, 20.0, 30.0)[0])


def test_the_zcross_smoothing_of_3_5_reproduces_nasas_mode_amplitudes(gedi_beams):
    """Algorithm 2's rx_modeamps (its zcross-smoothed waveform at each mode): L2A's truncated kernel for 3.5."""
    from fwcore.metrics.signal import smoothing_kernel

    assert smoothing_kernel(3.5) == (3.15, 7) and smoothing_kernel(6.5) == (5.8, 23)
    diff = []
    for b in gedi_beams:
        l2a = b["algorithms"][2]
        for i in range(len(b["offsets"]) - 1):
            smoothed = gaussian_smooth(b["samples"][b["offsets"][i]:b["offsets"][i + 1]], 3.5)
            n = int(l2a["rx_nummodes"][i])
            at = l2a["rx_modelocs"][i][:n]
            diff += list(np.interp(at, np.arange(smoothed.size), smoothed) - l2a["rx_modeamps"][i][:n])
    assert np.median(np.abs(diff)) < 0.15 and np.percentile(np.abs(diff), 90) < 0.6  # DN, of amplitudes 10-900
