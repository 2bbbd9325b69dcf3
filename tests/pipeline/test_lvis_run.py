"""`fwl run` on an LVIS L1B file written from its data dictionary: the ground and the canopy's height where the
file placed them, in EPSG:4979."""

import numpy as np
import pyarrow.dataset as ds

from pipeline.cli import main
from tests.fwcore.io.lvis_files import STEP_M, write_lvis


def test_lvis_pulses_carry_their_ground_and_canopy_height(tmp_path):
    path = tmp_path / "LVIS1B_forest.h5"
    truth = write_lvis(path, 24, seed=4)
    out = tmp_path / "run"
    assert main(["run", str(path), "--output", str(out), "--formats", "parquet", "--optimizer", "lm"]) == 0
    pulses = ds.dataset(str(out / "pulses"), format="parquet").to_table().to_pandas().sort_values("pulse_id")
    assert len(pulses) == 24 and (pulses.metrics_reason == "").all()
    true_ground = truth["z0"] - truth["ground"] * STEP_M
    assert np.median(np.abs(pulses.ground_z.to_numpy() - true_ground)) < 0.1
    # the canopy layer's top edge is 15 samples above its centre: RH100 near (ground - top) samples
    canopy = (truth["ground"] - truth["top"]) * STEP_M
    rh100 = np.stack(pulses.rh.to_numpy())[:, 100]
    assert np.median(np.abs(rh100 - canopy)) < 1.5
    assert (pulses.cover > 0).all() and (pulses.cover < 1).all()
