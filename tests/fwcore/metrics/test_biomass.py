"""GEDI L4A's biomass models (fwcore.metrics.biomass) against NASA's own L4A granule: every shot's agbd, agbd_se
and their fit-unit values from its predictors (xvar), for every algorithm; the same from the RH the predictors
come from; one stratum by hand; each shot's stratum from its land-cover codes."""

from pathlib import Path

import numpy as np
import pytest

from fwcore.io.gedi_l4a import read_l4a_shots
from fwcore.metrics.biomass import (NO_STRATUM, NOT_IN_L2A, NOT_LARGE, check_stratum, footprint_biomass, l4a_models,
                                    predict_agbd, strata_of_land_cover)

L4A = (Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
       / "GEDI04_A_2021150031254_O13948_03_T06447_02_002_01_V002.h5")
ALGORITHMS = (1, 2, 3, 4, 5, 6, 10)  # agbd_prediction/*_aN: L2A's six and L4A's setting group 10
FILL = -9999.0


def _predicted(shots):
    """The shots L4A predicted: a stratum and predictors (not the fill value)."""
    return (shots["predict_stratum"] != "") & (shots["xvar"][:, 0] != FILL)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_every_shot_of_every_algorithm_from_its_predictors(algorithm):
    shots = read_l4a_shots(L4A, algorithm)
    use = _predicted(shots)
    assert use.sum() >= 800  # of 966: the rest are L4A's fill
    models = l4a_models().strata
    for name in set(shots["predict_stratum"][use]):
        rows = np.flatnonzero(use & (shots["predict_stratum"] == name))
        model = models[name]
        agbd, se, t, t_se = model.predict(shots["xvar"][rows].astype(np.float64))
        nasa = {k: shots[k][rows].astype(np.float64) for k in ("agbd", "agbd_se", "agbd_t", "agbd_t_se")}
        # float32 predictors near a zero prediction: an absolute floor of 1e-4 Mg/ha
        assert np.all(np.abs(agbd - nasa["agbd"]) <= 1e-3 * nasa["agbd"] + 1e-4), (algorithm, name)
        assert np.all(np.abs(se / nasa["agbd_se"] - 1) <= 1e-5), (algorithm, name)
        assert np.all(np.abs(t_se / nasa["agbd_t_se"] - 1) <= 1e-5), (algorithm, name)
        assert np.all(np.abs(t - nasa["agbd_t"]) <= 1e-3 * np.abs(nasa["agbd_t"]) + 1e-4), (algorithm, name)
        negative = nasa["agbd_t"] < 0  # L4A stores 0 for a negative prediction, and its standard error as usual
        assert np.all(agbd[negative] == 0) and np.all(nasa["agbd"][negative] == 0)


def test_quality_shots_from_the_rh_they_came_from():
    """RH = xvar^2 - 100 (the RH of the algorithm L4A selected): predict_agbd from RH0..RH100 rows gives L4A's
    agbd and agbd_se for every quality shot, including those above the calibration's predictor_max_value."""
    shots = read_l4a_shots(L4A)
    use = _predicted(shots) & (shots["l4_quality_flag"] == 1)
    models = l4a_models().strata
    rh = np.full((use.sum(), 101), np.nan)
    strata = shots["predict_stratum"][use]
    xvar = shots["xvar"][use].astype(np.float64)
    beyond = 0
    for i, name in enumerate(strata):
        k = list(models[name].rh_index)
        rh[i, k] = xvar[i, :len(k)] ** 2 - 100.0
        beyond += bool((xvar[i, :len(k)] > models[name].predictor_max_value).any())
    found = predict_agbd(rh, strata)
    assert set(found.reason) == {""} and list(found.stratum) == list(strata)
    nasa_agbd, nasa_se = shots["agbd"][use].astype(np.float64), shots["agbd_se"][use].astype(np.float64)
    assert np.all(np.abs(found.agbd - nasa_agbd) <= 1e-3 * nasa_agbd + 1e-3)
    assert np.all(np.abs(found.agbd_se / nasa_se - 1) <= 1e-4)
    assert use.sum() >= 600 and beyond >= 5  # NASA extrapolates past predictor_max_value: so do we


def test_one_stratum_by_hand():
    """ENT_NAm (L4A's table: RH70 and RH98; par -114.35456848, 8.40065765, 3.34595799; Snowdon 1.0125337): a shot
    with RH70 20 m and RH98 25 m."""
    rh = np.full((1, 101), np.nan)
    rh[0, 70], rh[0, 98] = 20.0, 25.0
    t = -114.35456848 + 8.40065765 * np.sqrt(120.0) + 3.34595799 * np.sqrt(125.0)
    found = predict_agbd(rh, np.array(["ENT_NAm"], dtype=object))
    assert found.agbd[0] == pytest.approx(1.0125337 * t ** 2, rel=1e-6)
    assert found.agbd[0] == pytest.approx(230.225, abs=0.01)
    model = l4a_models().strata["ENT_NAm"]
    x = np.array([1.0, np.sqrt(120.0), np.sqrt(125.0)])
    assert found.agbd_se[0] == pytest.approx(1.0125337 * (x @ model.vcov @ x + 3.3100748 ** 2), rel=1e-6)


def test_each_shot_s_stratum_from_its_land_cover_codes():
    shots = read_l4a_shots(L4A)
    names, reasons = strata_of_land_cover(shots["pft_class"], shots["region_class"])
    assert list(names) == list(shots["predict_stratum"])  # EBT_SA, GSW_SA and '' (pft 0: no model)
    assert {"EBT_SA", "GSW_SA", ""} == set(names)
    assert all(("pft_class 0" in r) == (n == "") for n, r in zip(names, reasons))
    # codes from the table's look-up: 1 ENT, 7 NAm; 11 GSW, 4 Af; 255: a shot the L2A granule does not hold
    names, reasons = strata_of_land_cover(np.array([1, 11, NOT_IN_L2A]), np.array([7, 4, NOT_IN_L2A]))
    assert list(names) == ["ENT_NAm", "GSW_Af", ""] and list(reasons) == ["", "", ""]


def test_the_stratum_given_the_land_cover_first_and_the_footprint():
    rh = np.full((3, 101), np.nan)
    rh[:, 50], rh[:, 70], rh[:, 98] = 10.0, 15.0, 20.0
    pft, region = np.array([2, NOT_IN_L2A, 0]), np.array([6, NOT_IN_L2A, 0])
    found = footprint_biomass(rh, True, "ent_nam", pft, region)
    assert list(found.stratum) == ["EBT_SA", "ENT_NAm", ""]  # --stratum only where L2A has not the shot
    assert np.isfinite(found.agbd[:2]).all() and np.isnan(found.agbd[2])
    alone = footprint_biomass(rh, True, "ENT_NAm")
    assert alone.agbd[1] == pytest.approx(found.agbd[1]) and alone.agbd[0] != pytest.approx(found.agbd[0])
    assert set(footprint_biomass(rh, True).reason) == {NO_STRATUM}
    small = footprint_biomass(rh, False, "ENT_NAm")
    assert np.isnan(small.agbd).all() and set(small.reason) == {NOT_LARGE}


def test_a_wrong_stratum_names_the_valid_ones():
    assert check_stratum("ebt_sa") == "EBT_SA"
    with pytest.raises(ValueError, match="ENT_NAm.*") as err:
        check_stratum("ENT_NA")
    assert "EBT_SA" in str(err.value) and len(l4a_models().strata) == 35
