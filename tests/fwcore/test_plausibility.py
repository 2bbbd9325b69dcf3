"""The plausibility rule (fwcore.plausibility) on files written to provoke it: a LAS 1.3 format 4 flight with late
weak bumps far under the ground (the system's own returns beside the waveforms), and a GEDI L1B granule (no system
returns) with the same: no kept echo stays more than 5 m under the ground, the weak true ground under canopy
stays, and the filtered echoes carry their reason."""

import h5py
import numpy as np
import pyproj

from fwcore.engine.config import DecompositionConfig
from fwcore.engine.decompose import decompose_batch
from fwcore.engine.filter import REJECT_REASONS, UNDER_GROUND
from fwcore.instrument.measure import file_system_pulse
from fwcore.instrument.pulse import nominal_pulse
from fwcore.io import read_pulses
from fwcore.io.crs import horizontal_metres
from fwcore.io.writer import write_waveform_las
from fwcore.plausibility import CELL_M, UNDER_GROUND_M, filter_under_ground, local_floor, lowest_surfaces
from fwcore.pulses import echo_positions, pulse_waveforms
from fwcore.studies.evaluate import match_echoes
from fwcore.studies.gedi_granule import METRES_PER_SAMPLE, NOISE_MEAN, write_granule
from fwcore.studies.simulate import RANGE_M_PER_PS, SensorConfig, simulate_flight

BUMP_DELAY_PS = 60_000.0  # 9 m of range past the ground


def test_the_local_floor_is_the_lowest_of_the_other_pulses_lowest_surfaces():
    # pulses 0-3 in one 5 m cell, pulse 4 five cells away, pulse 5 without a surface
    surfaces = np.array([[1.0, 0, 10.0], [2.0, 0, 12.0], [3.0, 0, -30.0], [4.0, 0, 11.0], [30.0, 0, 0.0],
                         [np.nan] * 3])
    at_x = np.array([1.0, 3.0, 9.0, 30.0, 30.0, np.nan])
    floor = local_floor(surfaces, at_x, np.zeros(6), np.array([0, 2, 5, 4, 0, 0]), cell=5.0)
    # (1, pulse 0): the others' -30; (3, pulse 2): its own -30 left out, 10 the lowest of the rest; (9): the
    # next cell's -30; (30, pulse 4): nothing but its own; (30, pulse 0): pulse 4's; no position, no floor
    np.testing.assert_array_equal(floor, [-30.0, 10.0, -30.0, np.nan, 0.0, np.nan])


def _bumped_flight(tmp_path):
    """A simulated flight written as LAS 1.3 format 4, with a weak bump (5 sigma) 9 m of range past the ground
    of every 6th pulse whose last surface is the ground: an afterpulse or noise in the long record."""
    sensor = SensorConfig(samples_per_packet=240)
    flight = simulate_flight(400, sensor, seed=5)
    pulses, truth = flight.pulses, flight.truth
    index = {int(p): i for i, p in enumerate(pulses.pulse_id)}
    rank = np.array([index[int(p)] for p in truth["pulse_id"]])
    last = np.full(len(pulses), -1)
    np.maximum.at(last, rank, np.arange(rank.size))  # each pulse's last true echo
    t = np.arange(sensor.samples_per_packet) * sensor.sample_spacing_ps
    ends = truth["time_ps"][last]
    ground = truth["surface"][last] == "ground"
    bumped = np.flatnonzero(ground & (ends + BUMP_DELAY_PS < t[-1] - 8_000.0))[::6]
    for i in bumped:
        wave = pulses.samples[pulses.sample_offsets[i]:pulses.sample_offsets[i + 1]]
        wave += np.round(5.0 * sensor.noise_sigma * np.exp(-0.5 * ((t - ends[i] - BUMP_DELAY_PS) / 1700.0) ** 2))
    return write_waveform_las(tmp_path / "bumps.las", pulses, "las13-wdp"), truth, sensor, bumped


def _true_ground(truth, xy):
    """At each xy: the lowest true ground within 3 m, else the nearest true ground (under a roof)."""
    g = truth["surface"] == "ground"
    gx, gy, gz = truth["x"][g], truth["y"][g], truth["z"][g]
    d = np.hypot(gx[None, :] - xy[:, :1], gy[None, :] - xy[:, 1:2])
    return np.where((d < 3.0).any(axis=1), np.where(d < 3.0, gz[None, :], np.inf).min(axis=1), gz[d.argmin(axis=1)])


def test_no_kept_echo_stays_far_under_the_ground_of_a_written_las_13_file(tmp_path):
    path, truth, sensor, bumped = _bumped_flight(tmp_path)
    read = read_pulses(path)
    assert read.return_xyz.shape[0] > len(read)  # the system's own returns are in the file
    result = decompose_batch(pulse_waveforms(read, 0), DecompositionConfig(), nominal_pulse(4000.0), threads=1)
    xyz = echo_positions(read, result, 0.0)
    own = np.full(len(read), np.inf)
    np.minimum.at(own, read.return_pulse(), read.return_xyz[:, 2])
    np.testing.assert_array_equal(lowest_surfaces(read, result, xyz)[:, 2], own)  # the system's, not our echoes
    under = xyz[:, 2] < _true_ground(truth, xyz) - UNDER_GROUND_M
    assert ((result.reject == 0) & under).sum() >= 0.5 * bumped.size  # the bumps are fitted and kept at first
    times = result.position * read.sample_spacing_ps[result.echo_waveform]
    t_idx, f_idx = match_echoes(truth["pulse_id"], truth["time_ps"], read.pulse_id[result.echo_waveform], times,
                                1000.0)
    ground = truth["surface"][t_idx] == "ground"
    kept_ground = f_idx[ground & (result.reject[f_idx] == 0)]
    weak_ground = f_idx[ground & (truth["amplitude"][t_idx] < 6.0 * sensor.noise_sigma) & (result.reject[f_idx] == 0)]
    assert weak_ground.size >= 3  # weak true ground echoes (under canopy) the engine keeps

    before = result.reject.copy()
    marked = filter_under_ground(read, result, xyz)
    assert not ((result.reject == 0) & under).any()
    assert marked == (result.reject == UNDER_GROUND).sum() == ((before == 0) & (result.reject != 0)).sum()
    assert marked <= under.sum() + 2  # hardly an echo above the true ground - 5 m goes
    assert REJECT_REASONS[UNDER_GROUND] == "under_ground"
    assert (result.reject[kept_ground] == 0).all()  # every kept true ground echo stays, the weak under canopy too
    assert RANGE_M_PER_PS * BUMP_DELAY_PS > 2 * UNDER_GROUND_M * 0.85


def test_a_gedi_granule_without_system_returns_is_judged_by_its_range(tmp_path):
    path = tmp_path / "GEDI01_B_bumps.h5"
    truth = write_granule(path, 40, seed=3, beams=("BEAM0000",), faults=False)
    samples = np.arange(800.0)
    bumped = np.arange(0, 40, 3)
    with h5py.File(path, "r+") as f:  # an afterpulse, a tenth of the ground's peak, 150 samples (22 m) under it
        rx = f["BEAM0000/rxwaveform"][:].reshape(40, 800)
        for i in bumped:
            peak = rx[i].max() - NOISE_MEAN
            rx[i] += (0.1 * peak * np.exp(-0.5 * ((samples - truth.ground_index[i] - 150) / 6.5) ** 2)).astype(np.float32)
        f["BEAM0000/rxwaveform"][...] = rx.ravel()
    read = read_pulses(path)
    assert read.return_xyz.shape[0] == 0 and len(read) == 40
    system = file_system_pulse(path, len(read), DecompositionConfig())  # from the recorded outgoing pulses
    result = decompose_batch(pulse_waveforms(read, 0), DecompositionConfig(), system, threads=1)
    xyz = echo_positions(read, result, 0.0)
    depth = (truth.ground_index[result.echo_waveform] - result.position) * METRES_PER_SAMPLE  # + above the ground
    kept = result.reject == 0
    deep = kept & (depth < -UNDER_GROUND_M - 5.0)
    assert deep.sum() >= 0.5 * bumped.size
    ground = kept & (np.abs(depth) < 3.0)
    cell = CELL_M / horizontal_metres(pyproj.CRS.from_epsg(4979).to_wkt())  # GEDI's positions are degrees
    marked = filter_under_ground(read, result, xyz, cell)
    assert (result.reject[deep] == UNDER_GROUND).all()
    assert (result.reject[ground] == 0).all()
    assert marked == deep.sum()
