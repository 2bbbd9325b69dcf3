"""GEDI L1B granules: the shared real one (four beams, 164 shots) read against h5py directly, and granules written
in its layout with the variants real ones hold (beams of other sizes, shots without samples, stale returns,
missing geolocation)."""

from pathlib import Path

import h5py
import numpy as np
import pytest

from fwcore.io import describe_file, format_of, plan_point_ranges, read_pulses
from fwcore.io.errors import WaveformFileError
from fwcore.io.formats import GEDI_L1B, kind_of
from fwcore.io.gedi import NO_GEOLOCATION, NO_SAMPLES, NOISE_FIELDS, NOISE_SD_PER_END_SPREAD, STALE, noise_recorded, \
    open_gedi
from fwcore.pulses import pulse_waveforms
from fwcore.studies.gedi_granule import write_granule

GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
L1B = GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
L2A = GEDI / "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"


def test_the_format_is_told_by_its_groups_not_only_its_signature():
    assert format_of(L1B) is GEDI_L1B and kind_of(L1B).format is GEDI_L1B
    assert kind_of(L2A).format is None and "give the L1B" in kind_of(L2A).words
    with pytest.raises(WaveformFileError, match="L2A and L2B granules hold no waveforms"):
        open_gedi(L2A)


def test_every_shot_is_in_one_range_that_never_crosses_a_beam():
    granule = open_gedi(L1B)
    assert granule.beams == ("BEAM0001", "BEAM0010", "BEAM0101", "BEAM1000") and granule.point_count == 164
    ranges = plan_point_ranges(L1B, 20)
    assert sum(r.n_pulses for r in ranges) == 164
    assert all(granule.beam_of(r.start)[0] == granule.beam_of(r.stop - 1)[0] for r in ranges)


def test_the_real_granule_reads_as_h5py_sees_it():
    pulses = read_pulses(L1B)
    with h5py.File(L1B) as f:
        g = f["BEAM0101"]
        i = 7
        start, count = int(g["rx_sample_start_index"][i]) - 1, int(g["rx_sample_count"][i])
        expected = g["rxwaveform"][start:start + count]
        shot = int(g["shot_number"][i])
        z0, zl = g["geolocation/elevation_bin0"][i], g["geolocation/elevation_lastbin"][i]
        lon_last = g["geolocation/longitude_lastbin"][i]
        noise = g["noise_mean_corrected"][i]
    row = int(np.flatnonzero(pulses.pulse_id == shot)[0])
    assert np.array_equal(pulses.pulse_samples(row), expected.astype(np.float64))
    assert pulses.channel[row] == 5 and pulses.noise_mean[row] == noise  # BEAM0101: beam 5
    assert pulses.outgoing_samples(row).size == 128
    # the last sample lands on lastbin: count - 1 steps, not count
    t_last = (count - 1) * pulses.sample_spacing_ps[row]
    last = pulses.anchor[row] + (pulses.anchor_location_ps[row] - t_last) * pulses.direction[row]
    assert abs(last[2] - zl) < 1e-6 and abs(last[0] - lon_last) < 1e-9 and pulses.anchor[row, 2] == z0
    assert len(pulses) == 164 and not pulses.rejected


def test_describe_names_the_beams_and_the_crs():
    info = describe_file(L1B)
    assert info["format"] == "GEDI L1B" and info["crs"] == "EPSG:4979" and info["shots"] == 164
    assert info["beams"]["BEAM0101"]["shots"] == 73 and info["beams"]["BEAM0101"]["samples"]["min"] > 700


def test_a_written_granule_rejects_what_cannot_be_used_and_counts_add_up(tmp_path):
    path = tmp_path / "GEDI01_B_test.h5"
    truth = write_granule(path, 12, seed=3, beams=("BEAM0000", "BEAM0110", "BEAM1011"), samples=300)
    seen, rejected = 0, {}
    for r in plan_point_ranges(path, 5):
        batch = read_pulses(r)
        seen += len(batch)
        rejected.update(dict(batch.rejected))
        assert np.isfinite(batch.anchor).all() and (np.diff(batch.sample_offsets) == 300).all()
        pulse_waveforms(batch, 1)  # the engine's input builds from every read row
    assert seen + len(rejected) == 36
    expected = {int(s): r for s, r in zip(truth.shot_number, truth.reject) if r}
    words = {"samples": NO_SAMPLES, "stale": STALE, "geolocation": NO_GEOLOCATION}
    assert rejected == {s: words[r] for s, r in expected.items()}


def test_the_l2a_beside_gives_its_selected_algorithms_settings(tmp_path):
    from fwcore.io.gedi import l2a_beside, l2a_settings

    assert l2a_beside(L1B) == L2A
    algorithm, settings = l2a_settings(L2A)
    assert algorithm == 1 and settings == {"smoothing_width": 6.5, "smoothing_width_zcross": 6.5,
                                           "front_threshold_sd": 3.0, "back_threshold_sd": 6.0, "subbins": 4,
                                           "select_mode": False, "pulse_sep_thresh": 8.0,
                                           "cumulative_energy_minimum": 0.0, "cumulative_energy_thresh": 0.0,
                                           "energy_thresh": 50.0, "amp_thresh": 50.0, "max_modes": 20}
    second = l2a_settings(L2A, 2)[1]  # algorithm 2: the zcross smoothing of 3.5 and mode selection
    assert second["smoothing_width_zcross"] == 3.5 and second["select_mode"] is True
    assert second["cumulative_energy_minimum"] == 1.5 and second["cumulative_energy_thresh"] == 2.5
    assert l2a_beside(tmp_path / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5") is None


def test_a_granule_with_only_the_required_datasets_reads(tmp_path):
    """Without noise, flags, angles, times or transmitted pulses: the noise from the first samples, the beam at
    nadir, no flags; without a required dataset the file is refused naming it."""
    from fwcore.io.gedi import OPTIONAL

    full = tmp_path / "full.h5"
    write_granule(full, 8, seed=2, beams=("BEAM0011",), samples=800, faults=False)
    bare = tmp_path / "bare.h5"
    with h5py.File(full) as src, h5py.File(bare, "w") as dst:
        for name in ("shot_number", "rx_sample_count", "rx_sample_start_index", "rxwaveform"):
            src.copy(f"BEAM0011/{name}", dst.require_group("BEAM0011"), name)
        for name in ("elevation_bin0", "elevation_lastbin", "latitude_bin0", "latitude_lastbin", "longitude_bin0",
                     "longitude_lastbin"):
            src.copy(f"BEAM0011/geolocation/{name}", dst.require_group("BEAM0011/geolocation"), name)
    assert not any(name in h5py.File(bare)["BEAM0011"] for name in OPTIONAL)
    pulses = read_pulses(bare)
    assert len(pulses) == 8 and pulses.transmit_shape is None and (pulses.cos_zenith == 1.0).all()
    # the written granule's noise is white (3.3), not smoothed as a real L1B's: the factor real granules need over
    # their ends' spread (NOISE_SD_PER_END_SPREAD) overstates it here, as the docs say of granules unlike L1B's
    assert np.allclose(pulses.noise_mean, 205.0, atol=2.0)
    assert np.allclose(pulses.noise_sd, NOISE_SD_PER_END_SPREAD * 3.3, rtol=0.15) and np.ptp(pulses.noise_sd) == 0
    with h5py.File(bare, "r+") as f:
        del f["BEAM0011/geolocation/elevation_lastbin"]
    with pytest.raises(WaveformFileError, match="without geolocation/elevation_lastbin"):
        open_gedi(bare)


def test_without_l1bs_noise_fields_the_noise_is_estimated_per_beam_and_l2a_still_reproduced(tmp_path):
    """The shared granule with noise_mean_corrected / noise_stddev_corrected removed (as subsetting tools do): each
    beam's noise sd from its waveforms' ends is within 10 % of L1B's, and every L2A algorithm's ground and RH98
    still agree with L2A's (ground median 0, 90th percentile a quarter sample; RH98 within 0.10 m)."""
    from fwcore.metrics.algorithms import L2A_ALGORITHMS
    from fwcore.metrics.pulses import vertical_axis, zenith_cosine
    from fwcore.metrics.waveform import waveform_metrics

    bare = tmp_path / L1B.name
    bare.write_bytes(L1B.read_bytes())
    with h5py.File(bare, "r+") as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            for name in NOISE_FIELDS:
                del f[beam][name]
    assert noise_recorded(L1B) and not noise_recorded(bare)
    full, estimated = read_pulses(L1B), read_pulses(bare)
    assert np.array_equal(full.pulse_id, estimated.pulse_id)
    for channel in np.unique(full.channel):
        beam = full.channel == channel
        assert abs(np.median(estimated.noise_sd[beam]) / np.median(full.noise_sd[beam]) - 1) < 0.10
        off = np.abs(estimated.noise_mean[beam] - full.noise_mean[beam]) / full.noise_sd[beam]
        assert np.median(off) < 0.3  # the mean within a third of a noise sd (a DN or less, of means near 205)
    first_z, drop = vertical_axis(estimated)
    with h5py.File(L2A) as f:
        at = {int(s): (b, i) for b in f if b.startswith("BEAM") for i, s in enumerate(f[b]["shot_number"][:])}
        for a, settings in L2A_ALGORITHMS.items():
            m = waveform_metrics(estimated.samples, estimated.sample_offsets, estimated.noise_mean,
                                 estimated.noise_sd, first_z, drop, zenith_cosine(estimated),
                                 estimated.transmit_shape, settings)
            ground = np.array([f[at[s][0]][f"geolocation/elev_lowestmode_a{a}"][at[s][1]] for s in full.pulse_id])
            rh98 = np.array([f[at[s][0]][f"geolocation/rh_a{a}"][at[s][1], 98] for s in full.pulse_id]) / 100.0
            d = np.abs(m.ground_z - ground)
            assert np.median(d) < 1e-3 and np.percentile(d, 90) <= 0.04, a
            assert np.percentile(np.abs(m.rh[:, 98] - rh98), 90) <= 0.12, a
