"""The L4A model table shipped with the package is the shared L4A granule's, written again from it; the granule's
land cover read as an L2A's (version 002 L2A and L4A share land_cover_data/pft_class and region_class)."""

import json
from pathlib import Path

import numpy as np
import pytest

from fwcore.io.errors import WaveformFileError
from fwcore.io.gedi import land_cover_classes
from fwcore.io.gedi_l4a import read_l4a_models, read_l4a_shots, write_model_table
from fwcore.metrics.biomass import MODEL_TABLE

GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
L4A = GEDI / "GEDI04_A_2021150031254_O13948_03_T06447_02_002_01_V002.h5"
L2A_V001 = GEDI / "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"


def test_the_shipped_table_is_the_granule_s(tmp_path):
    written = write_model_table(L4A, tmp_path / "models.json")
    assert json.loads(written.read_text()) == json.loads(MODEL_TABLE.read_text())
    table = read_l4a_models(L4A)
    assert len(table["strata"]) == 35 and table["source"]["doi"] == "10.3334/ORNLDAAC/2056"
    ebt = table["strata"]["EBT_SA"]
    assert ebt["rh_index"] == [50, 98] and len(ebt["par"]) == 3 and np.shape(ebt["vcov"]) == (3, 3)
    assert ebt["par"][0] == pytest.approx(-134.77015686) and ebt["bias_correction_value"] == pytest.approx(1.1055282)
    assert table["pft"]["2"] == "EBT" and table["region"]["6"] == "SA"


def test_land_cover_joined_by_shot_number():
    shots = read_l4a_shots(L4A)
    beam = "BEAM0010"  # pft 0, 2 and 6 in one beam
    import h5py
    with h5py.File(L4A) as f:
        numbers = f[beam]["shot_number"][:].astype(np.int64)
        pft, region = f[beam]["land_cover_data/pft_class"][:], f[beam]["land_cover_data/region_class"][:]
    asked = np.r_[numbers[::-1], 12345]  # reversed, and a shot the granule has not
    found_pft, found_region = land_cover_classes(L4A, beam, asked)
    assert list(found_pft) == list(pft[::-1]) + [255] and list(found_region) == list(region[::-1]) + [255]
    assert set(pft) == {0, 2, 6} and shots["pft_class"].size == 966


def test_a_version_001_l2a_names_no_land_cover():
    import h5py
    with h5py.File(L2A_V001) as f:
        beam = next(k for k in f if k.startswith("BEAM"))
        shots = f[beam]["shot_number"][:5].astype(np.int64)
    assert land_cover_classes(L2A_V001, beam, shots) == (None, None)
    assert land_cover_classes(None, beam, shots) == (None, None)


def test_not_an_l4a_granule():
    with pytest.raises(WaveformFileError, match="not a GEDI L4A granule"):
        read_l4a_models(L2A_V001)
