"""The truth of a simulated flight: the LAS and its truth table written chunk by chunk, the files beside it (the
trajectory, the calibration patch) and their names."""

import json

import laspy
import numpy as np
import pyarrow.parquet as pq
import pytest

from fwcore.io import read_pulses
from fwcore.io.writer import write_waveform_las
from fwcore.studies import simulate
from fwcore.studies.simulate import SceneConfig, SensorConfig, sensor_position, simulate_flight
from fwcore.studies.truth import (TRUTH_METADATA_KEY, calibration_path, trajectory_path, truth_path,
                                  write_calibration_reference, write_flight, write_trajectory)


def test_the_files_beside_a_flight_are_named_after_it(tmp_path):
    las = tmp_path / "north" / "sim.las"
    assert (truth_path(las), trajectory_path(las), calibration_path(las)) == (
        tmp_path / "north" / "sim.truth.parquet", tmp_path / "north" / "sim.trajectory.csv",
        tmp_path / "north" / "sim.calibration.json")


def test_the_trajectory_spans_the_flight_and_10_ms_either_side(tmp_path):
    scene = SceneConfig()
    path = write_trajectory(tmp_path / "t.csv", 2000, scene)  # 20 ms at 100 kHz
    assert path.read_text().splitlines()[0] == "gps_time,x,y,z"
    rows = np.loadtxt(path, delimiter=",", skiprows=1)
    # 20 000 knots over 40 ms would be 500 kHz: the pulse rate, 100 kHz, is the finest step written
    np.testing.assert_allclose(np.diff(rows[:, 0]), 1e-5, atol=2e-6)
    assert rows[0, 0] == pytest.approx(scene.start_gps_time - 0.01, abs=1e-6)
    assert rows[-1, 0] == pytest.approx(scene.start_gps_time + 0.03, abs=1e-5)
    np.testing.assert_allclose(rows[:, 1:], sensor_position(rows[:, 0], scene), atol=1e-4)


def test_the_calibration_patch_is_the_scene_s(tmp_path):
    scene = SceneConfig(radiometry=True)
    value = json.loads(write_calibration_reference(tmp_path / "c.json", 1000, scene).read_text())
    end = sensor_position(np.array([scene.start_gps_time + 1000 / scene.pulse_rate_hz]), scene)[0, 0]
    assert value == {"bbox": [0.0, scene.patch_y_m[0], pytest.approx(end), scene.patch_y_m[1]],
                     "reflectance": scene.patch_reflectance, "beam_divergence_mrad": scene.beam_divergence_mrad}


@pytest.mark.parametrize("layout", ["las13-wdp", "las14-internal"])
def test_a_flight_of_several_chunks_is_written_chunk_by_chunk_and_reads_back(tmp_path, monkeypatch, layout):
    one_chunk = simulate_flight(300, seed=4, source_file="sim.las")  # before chunks: one stream for the flight
    monkeypatch.setattr(simulate, "CHUNK_PULSES", 300)  # 750 pulses: 2.5 chunks, not aligned with scan lines
    written = write_flight(tmp_path / "sim.las", 750, SensorConfig(), SceneConfig(), seed=4, layout=layout)
    flight = simulate_flight(750, seed=4, source_file="sim.las")
    # the file streamed chunk by chunk is the flight in memory written in one go
    whole = write_waveform_las(tmp_path / "whole" / "sim.las", flight.pulses, layout)
    assert whole.read_bytes() == written.las.read_bytes()
    if layout == "las13-wdp":
        assert (tmp_path / "whole" / "sim.wdp").read_bytes() == (tmp_path / "sim.wdp").read_bytes()

    back = read_pulses(written.las)
    assert len(back) == written.n_pulses == 750
    np.testing.assert_array_equal(back.pulse_id, flight.pulses.pulse_id)
    np.testing.assert_array_equal(back.packet_offset, flight.pulses.packet_offset)
    np.testing.assert_array_equal(back.samples, flight.pulses.samples)
    assert np.all(np.diff(back.gps_time) > 0)  # the line flies on across chunks
    # chunk 0 is the one-chunk flight of the same seed; chunk 1 draws from a stream of its own
    np.testing.assert_array_equal(back.samples[:300 * 200], one_chunk.pulses.samples)
    np.testing.assert_array_equal(back.pulse_id[:300], one_chunk.pulses.pulse_id)
    assert not np.array_equal(back.samples[300 * 200:600 * 200], one_chunk.pulses.samples)

    las = laspy.read(written.las)
    assert las.header.point_count == len(las.points) == written.n_returns == flight.pulses.return_xyz.shape[0]
    np.testing.assert_array_equal(las.header.mins, [las.x.min(), las.y.min(), las.z.min()])
    np.testing.assert_array_equal(las.header.maxs, [las.x.max(), las.y.max(), las.z.max()])
    by_return = np.bincount(las.return_number, minlength=16)[1:]
    kept = len(las.header.number_of_points_by_return)  # 5 in LAS 1.3, 15 in 1.4
    np.testing.assert_array_equal(las.header.number_of_points_by_return, by_return[:kept])

    table = pq.read_table(written.truth)
    assert table.num_rows == written.n_echoes == flight.truth["time_ps"].size
    assert pq.ParquetFile(written.truth).num_row_groups == 3  # one a chunk
    np.testing.assert_array_equal(table["pulse_id"].to_numpy(), flight.truth["pulse_id"])
    np.testing.assert_array_equal(table["z"].to_numpy(), flight.truth["z"])
    assert set(table["pulse_id"].to_numpy()) == set(back.pulse_id)
    assert json.loads(table.schema.metadata[TRUTH_METADATA_KEY])["seed"] == 4


def test_a_flight_that_fails_after_chunks_were_written_leaves_no_partial_files(tmp_path, monkeypatch):
    monkeypatch.setattr(simulate, "CHUNK_PULSES", 100)
    short = SensorConfig(samples_per_packet=170)  # enough for the first three chunks' trees, not the fourth's
    assert len(list(write_flight(tmp_path / "ok.las", 300, short, SceneConfig(), seed=1).las.parent.iterdir())) == 4
    with pytest.raises(ValueError, match="packet is too short"):
        write_flight(tmp_path / "sim.las", 400, short, SceneConfig(), seed=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.las", "ok.trajectory.csv", "ok.truth.parquet", "ok.wdp"]
