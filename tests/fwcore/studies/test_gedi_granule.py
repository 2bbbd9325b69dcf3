"""Granules written in GEDI L1B's layout hold what the reader expects of real ones: 1-based start indices, a
lastbin count - 1 samples below bin0, and the faults each beam is given."""

import h5py
import numpy as np

from fwcore.studies.gedi_granule import METRES_PER_SAMPLE, TX_SAMPLES, write_granule


def test_the_layout_and_the_faults(tmp_path):
    path = tmp_path / "GEDI01_B_written.h5"
    truth = write_granule(path, 6, seed=1, beams=("BEAM0101", "BEAM1000"), samples=120)
    with h5py.File(path) as f:
        g = f["BEAM1000"]
        assert g["beam"][0] == 8 and g["rx_sample_start_index"][0] == 1
        count, start = g["rx_sample_count"][:], g["rx_sample_start_index"][:]
        assert count[1] == 0 and start[1] == 0  # the shot without samples
        assert start[2] == 1 + count[0] and g["rxwaveform"].shape == (int(count.sum()),)
        assert g["txwaveform"].shape == (6 * TX_SAMPLES,) and g["stale_return_flag"][2] == 1
        z0, zl = g["geolocation/elevation_bin0"][:], g["geolocation/elevation_lastbin"][:]
        assert np.isnan(z0[3]) and np.isclose(z0[0] - zl[0], 119 * METRES_PER_SAMPLE)
    assert truth.reject.tolist() == ["", "samples", "stale", "geolocation", "", ""] * 2
    assert (truth.top_index <= truth.ground_index).all() and len(set(truth.shot_number.tolist())) == 12
