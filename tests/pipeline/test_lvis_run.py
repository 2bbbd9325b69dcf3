"""`fwl run` on LVIS L1B files: one written from its data dictionary (the ground and the canopy's height where the
file placed them), and the real shared clip and Mondah file, whose pulses/ join LVIS's own Level 2 by lfid and
shot_number and give its ZG, ZH and RH."""

import json
from pathlib import Path

import h5py
import numpy as np
import pyarrow.dataset as ds
import pytest

from pipeline.cli import main
from tests.fwcore.io.lvis_files import STEP_M, read_level2, write_lvis

LVIS = Path(__file__).resolve().parents[2] / "examples" / "data" / "lvis"
CLIP_SHOTS = 100  # 99 of them in its Level 2, 60 of those from the L1B's receiver channel
FAST = ["--formats", "parquet", "--optimizer", "lm", "--model", "generalized"]  # no model chosen on held-out samples


def _pulses(out: Path):
    return ds.dataset(str(out / "pulses"), format="parquet").to_table().to_pandas()


def test_lvis_pulses_carry_their_ground_and_canopy_height(tmp_path):
    path = tmp_path / "LVIS1B_forest.h5"
    truth = write_lvis(path, 24, seed=4)
    out = tmp_path / "run"
    assert main(["run", str(path), "--output", str(out), "--formats", "parquet", "--optimizer", "lm"]) == 0
    pulses = _pulses(out).sort_values("pulse_id")
    assert len(pulses) == 24 and (pulses.metrics_reason == "").all()
    true_ground = truth["z0"] - truth["ground"] * STEP_M
    assert np.median(np.abs(pulses.ground_z.to_numpy() - true_ground)) < 0.1
    # the canopy layer's top edge is 15 samples above its centre: RH100 near (ground - top) samples
    canopy = (truth["ground"] - truth["top"]) * STEP_M
    rh100 = np.stack(pulses.rh.to_numpy())[:, 100]
    assert np.median(np.abs(rh100 - canopy)) < 1.5
    assert (pulses.cover > 0).all() and (pulses.cover < 1).all()
    assert (pulses.lfid == 1411500).all() and pulses.shot_number.tolist() == list(range(1000, 1024))


@pytest.fixture(scope="module")
def clip_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("lvis_clip") / "run"
    assert main(["run", str(LVIS / "lvis_level1_clip_shared.h5"), "--output", str(out), *FAST]) == 0
    return out


def test_the_clip_joins_lvis_level2_and_gives_its_metrics(clip_run):
    pulses = _pulses(clip_run)
    level2 = read_level2(LVIS / "lvis_level2_clip_shared.txt")
    row = {(a, s): i for i, (a, s) in enumerate(zip(pulses.lfid, pulses.shot_number))}
    pairs = [(i, row[(a, s)]) for i, (a, s) in enumerate(zip(level2["lfid"], level2["shot_number"])) if (a, s) in row]
    assert len(pairs) == 99
    theirs, ours = map(np.array, zip(*pairs))
    same = (level2["channel"][theirs] == 1).all(axis=1)  # the others' ZH and RH came from another receiver
    assert same.sum() == 60
    ground = np.abs(pulses.ground_z.to_numpy()[ours] - level2["zg"][theirs])[same]
    top = np.abs(pulses.top_z.to_numpy()[ours] - level2["zh"][theirs])[same]
    rh = np.stack(pulses.rh.to_numpy()[ours])
    rh98 = np.abs(rh[:, 98] - level2["rh"][98][theirs])[same]
    rh50 = np.abs(rh[:, 50] - level2["rh"][50][theirs])[same]
    # the targets: ground 0.10 / 0.30 m (median / 90th percentile), RH98 0.50 / 2.0, RH50 median 0.50
    assert np.median(ground) <= 0.10 and np.percentile(ground, 90) <= 0.30
    assert np.median(rh98) <= 0.50 and np.percentile(rh98, 90) <= 2.0 and np.median(rh50) <= 0.50
    assert np.median(top) <= 0.10 and np.percentile(top, 90) <= 0.30


def test_every_clip_shot_is_accounted_for(clip_run):
    pulses = _pulses(clip_run)
    rejected = ds.dataset(str(clip_run / "rejected"), format="parquet").to_table()
    summary = json.loads((clip_run / "run.json").read_text())
    assert len(pulses) + rejected.num_rows == CLIP_SHOTS == summary["counts"]["pulses_read"]
    (entry,) = summary["inputs"]
    assert entry["metric_settings_source"].startswith("LVIS Level 2's definitions")
    assert "'end_threshold_sd': 4.5" in entry["metric_settings_source"]
    measured = pulses.metrics_reason == ""
    assert pulses.ground_z[measured].notna().all() and pulses.ground_z[~measured].isna().all()
    assert pulses.top_z[measured].notna().all() and pulses.top_z[~measured].isna().all()


def test_the_mondah_file_keeps_its_ids(tmp_path):
    """Ten shots in the file's own types (uint16 waveforms, uint32 LFID and SHOTNUMBER)."""
    path = LVIS / "LVIS_Mondah_level1b.SPLIT.8.h5"
    out = tmp_path / "run"
    assert main(["run", str(path), "--output", str(out), *FAST]) == 0
    pulses = _pulses(out).sort_values("shot_number")
    with h5py.File(path, "r") as f:
        lfid, shot, z0 = f["LFID"][:].astype(int), f["SHOTNUMBER"][:].astype(int), f["Z0"][:]
    assert pulses.lfid.tolist() == lfid.tolist() and pulses.shot_number.tolist() == shot.tolist()
    assert (pulses.pulse_id.to_numpy() == shot).all()  # one LFID in the file: its rank 0 in the high bits
    assert (pulses.metrics_reason == "").all()
    # tropical forest: the top above the ground by tens of metres, both inside the waveform's 153 m
    assert (pulses.top_z.to_numpy() < z0[np.argsort(shot)]).all()
    assert (np.stack(pulses.rh.to_numpy())[:, 100] > 10).all()
