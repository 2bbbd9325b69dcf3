"""LVIS L1B files in the product's layout: sample counts, longitudes east of 180, no SIGMEAN, a damaged shot; the
real files' LFID and shot numbers."""

from pathlib import Path

import numpy as np
import pytest

from fwcore.io import describe_file, format_of, plan_point_ranges, read_pulses
from fwcore.io.errors import WaveformFileError
from fwcore.io.formats import LVIS_L1B
from fwcore.io.lvis import NOT_FINITE, open_lvis
from tests.fwcore.io.lvis_files import STEP_M, write_lvis


@pytest.mark.parametrize("samples,east", [(1024, False), (512, True)])
def test_every_sample_is_placed_between_the_first_and_last(tmp_path, samples, east):
    path = tmp_path / "LVIS1B_test.h5"
    truth = write_lvis(path, 10, samples=samples, east_of_180=east)
    assert format_of(path) is LVIS_L1B and open_lvis(path).last == samples - 1
    pulses = read_pulses(path)
    assert len(pulses) == 10 and np.allclose(pulses.sample_spacing_ps, 2 * STEP_M / 299792458.0e-12)
    t_last = (samples - 1) * pulses.sample_spacing_ps
    last = pulses.anchor + (pulses.anchor_location_ps - t_last)[:, None] * pulses.direction
    assert np.allclose(last[:, 2], truth["z0"] - (samples - 1) * STEP_M)
    assert (pulses.anchor[:, 0] < -100).all()  # 254.5 east is -105.5
    assert describe_file(path)["samples"] == samples


def test_noise_from_the_first_samples_without_sigmean_and_a_damaged_shot_rejected(tmp_path):
    path = tmp_path / "LVIS1B_damaged.h5"
    write_lvis(path, 8, with_sigmean=False, bad_shot=3)
    ranges = plan_point_ranges(path, 3)
    batches = [read_pulses(r) for r in ranges]
    assert sum(len(b) for b in batches) == 7 and [r for b in batches for _, r in b.rejected] == [NOT_FINITE]
    noise = np.concatenate([b.noise_mean for b in batches])
    assert np.allclose(noise, 100.0, atol=1.0)


def test_an_hdf5_without_the_layout_names_what_is_missing(tmp_path):
    import h5py

    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["RXWAVE"] = np.zeros((2, 4))
        f["Z0"] = np.zeros(2)
    with pytest.raises(WaveformFileError, match="missing LAT0, LON0, SHOTNUMBER"):
        open_lvis(path)


@pytest.mark.parametrize("name,first_shot", [("LVIS_Mondah_level1b.SPLIT.8.h5", 9418932),
                                             ("lvis_level1_clip_shared.h5", 9427649)])
def test_real_files_carry_their_lfid_and_shot_number(name, first_shot):
    """AfriSAR 2016, Mondah (Gabon): the file's own uint32 LFID and SHOTNUMBER, and rLVIS's float64 rewrite of the
    same flight; the pulse id packs the shot number with its LFID's rank in the file (one LFID here: rank 0)."""
    import h5py

    path = Path(__file__).resolve().parents[3] / "examples" / "data" / "lvis" / name
    pulses = read_pulses(path)
    with h5py.File(path, "r") as f:
        lfid, shot = f["LFID"][:], f["SHOTNUMBER"][:]
    assert pulses.lfid.dtype == np.int64 and pulses.shot_number.dtype == np.int64
    assert pulses.lfid.tolist() == [1657455141] * len(shot) and pulses.lfid.tolist() == lfid.astype(int).tolist()
    assert pulses.shot_number[0] == first_shot and pulses.shot_number.tolist() == shot.astype(int).tolist()
    assert (pulses.pulse_id == pulses.shot_number).all() and pulses.pulse_id[0] == first_shot


def test_lfids_past_2_31_give_positive_unique_ids_in_every_range(tmp_path):
    """LFID and SHOTNUMBER are each uint32: LFID << 32 | shot overflows int64 from LFID 2^31. Two LFIDs past it
    (uint32's largest among them), the same shot numbers under both, read whole and in ranges of 3: every id
    positive and unique, the LFID's rank in the file (sorted) in the high 32 bits, the same in every range."""
    path = tmp_path / "LVIS1B_lfids.h5"
    lfid = np.array([2**32 - 1] * 4 + [2_259_812_001] * 4)
    write_lvis(path, 8, lfid=lfid, shot_number=np.r_[np.arange(5, 9), np.arange(5, 9)])
    whole = read_pulses(path)
    assert whole.lfid.tolist() == lfid.tolist() and whole.shot_number.tolist() == [5, 6, 7, 8] * 2
    assert whole.pulse_id.tolist() == [(1 << 32) + s for s in (5, 6, 7, 8)] + [5, 6, 7, 8]
    ranged = np.concatenate([read_pulses(r).pulse_id for r in plan_point_ranges(path, 3)])
    assert ranged.tolist() == whole.pulse_id.tolist()


def test_ranges_are_of_equal_size_within_the_limit(tmp_path):
    """6,000 shots at 5,000 a range: two of 3,000 (not 5,000 and 1,000: one worker idle for most of the run);
    8 at 3: 3, 3, 2; every shot in exactly one range."""
    path = tmp_path / "LVIS1B_ranges.h5"
    write_lvis(path, 8, samples=64, tx_samples=16)
    assert [(r.start, r.stop) for r in plan_point_ranges(path, 3)] == [(0, 3), (3, 6), (6, 8)]
    assert [(r.start, r.stop) for r in plan_point_ranges(path, 5)] == [(0, 4), (4, 8)]
    assert [(r.start, r.stop) for r in plan_point_ranges(path, 8)] == [(0, 8)]
