"""The plausibility rule on a LAS 1.3 format 4 file written with late noise bumps far under the ground: no kept
echo stays more than 5 m under the lowest surface, and the weak true ground under canopy stays."""

import numpy as np

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.filter import REJECT_REASONS, UNDER_GROUND
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import read_pulses
from fwcore.io.writer import write_waveform_las
from fwcore.plausibility import UNDER_GROUND_M, filter_under_ground, local_floor
from fwcore.pulses import echo_positions, pulse_waveforms
from fwcore.studies.evaluate import match_echoes
from fwcore.studies.simulate import RANGE_M_PER_PS, SensorConfig, simulate_flight

BUMP_DELAY_PS = 60_000.0  # 9 m of range past the pulse's last surface


def test_the_local_floor_is_the_lowest_low_quantile_of_the_cells_around():
    x = np.array([1.0, 2.0, 7.0, 12.0, 30.0])
    z = np.array([10.0, 12.0, 8.0, 20.0, 0.0])
    floor = local_floor(x, np.zeros(5), z, np.array([1.0, 12.0, 30.0, 50.0]), np.zeros(4), cell=5.0)
    # (1): its cell's 10.0 and the next's 8.0; (12): 8.0 in the cell before; (30): its own 0; (50): nothing near
    np.testing.assert_array_equal(floor, [8.0, 8.0, 0.0, np.inf])


def test_no_kept_echo_stays_far_under_the_ground_of_a_written_las_13_file(tmp_path):
    sensor = SensorConfig(samples_per_packet=240)
    flight = simulate_flight(400, sensor, seed=5)
    pulses, truth = flight.pulses, flight.truth
    rank = {int(p): i for i, p in enumerate(pulses.pulse_id)}
    last = np.full(len(pulses), -np.inf)
    np.maximum.at(last, [rank[int(p)] for p in truth["pulse_id"]], truth["time_ps"])
    t = np.arange(sensor.samples_per_packet) * sensor.sample_spacing_ps
    bumped = np.flatnonzero(last + BUMP_DELAY_PS < t[-1] - 8_000.0)[::8]
    for i in bumped:  # a weak bump (5 sigma) 9 m past the last surface: an afterpulse or noise in the long record
        wave = pulses.samples[pulses.sample_offsets[i]:pulses.sample_offsets[i + 1]]
        wave += np.round(5.0 * sensor.noise_sigma * np.exp(-0.5 * ((t - last[i] - BUMP_DELAY_PS) / 1700.0) ** 2))
    path = write_waveform_las(tmp_path / "bumps.las", pulses, "las13-wdp")
    read = read_pulses(path)
    result = decompose_batch(pulse_waveforms(read, 0), DecompositionConfig(), nominal_pulse(4000.0), threads=1)
    xyz = echo_positions(read, result, 0.0)
    times = result.position * read.sample_spacing_ps[result.echo_waveform]
    t_idx, f_idx = match_echoes(truth["pulse_id"], truth["time_ps"], read.pulse_id[result.echo_waveform], times,
                                1000.0)
    ground_z = np.full(len(read), np.inf)  # each pulse's true lowest surface
    np.minimum.at(ground_z, [rank[int(p)] for p in truth["pulse_id"]], truth["z"])
    under = xyz[:, 2] < ground_z[result.echo_waveform] - UNDER_GROUND_M
    assert ((result.reject == 0) & under).sum() >= 0.5 * bumped.size  # the bumps are fitted and kept at first
    weak_ground = (truth["surface"][t_idx] == "ground") & (truth["amplitude"][t_idx] < 6.0 * sensor.noise_sigma)
    weak_kept = f_idx[weak_ground & (result.reject[f_idx] == 0)]
    assert weak_kept.size >= 3

    before = result.reject.copy()
    from fwcore.plausibility import lowest_system_return
    own = lowest_system_return(read)[result.echo_waveform]
    e = np.flatnonzero((result.reject == 0) & under)
    print("DBG", own[e] - xyz[e, 2], result.echo_waveform[e], np.diff(read.return_offsets)[result.echo_waveform[e]])
    marked = filter_under_ground(read, result, xyz)
    assert not ((result.reject == 0) & under).any()
    assert marked == (result.reject == UNDER_GROUND).sum() == ((before == 0) & (result.reject != 0)).sum()
    assert REJECT_REASONS[UNDER_GROUND] == "under_ground"
    assert (result.reject[weak_kept] == 0).all()  # the weak true ground under canopy stays
    assert RANGE_M_PER_PS * BUMP_DELAY_PS > 2 * UNDER_GROUND_M * 0.85
