"""L4A's choice of algorithm (fwcore.metrics.l4a_algorithm) against NASA's L4A granule: every shot's
selected_algorithm from its algorithms' grounds, land cover and algorithm 10's mode flag; the waveform's peak above
the noise against L2A's rx_assess/rx_maxamp; the peak limit and the tree types by hand."""

from pathlib import Path

import h5py
import numpy as np

from fwcore.metrics.biomass import l4a_models
from fwcore.metrics.l4a_algorithm import MAXAMP_LIMIT, l4a_algorithm, rx_maxamp, stratum_parts

GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
L4A = GEDI / "GEDI04_A_2021150031254_O13948_03_T06447_02_002_01_V002.h5"
L2A = GEDI / "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"


def _l4a_shots() -> dict[str, np.ndarray]:
    fields = ("geolocation/elev_lowestmode_a1", "geolocation/elev_lowestmode_a2", "geolocation/elev_lowestmode_a10",
              "agbd_prediction/selected_mode_flag_a10", "land_cover_data/pft_class", "land_cover_data/region_class",
              "selected_algorithm")
    with h5py.File(L4A) as f:
        beams = [k for k in f if k.startswith("BEAM")]
        shots = {k.rsplit("/", 1)[-1]: np.concatenate([f[b][k][:] for b in beams]) for k in fields}
        # the granule's own code -> name tables: decide by name, whatever the numbering
        shots["pft_lut"] = {int(c): n.decode() for c, n in f["ANCILLARY/pft_lut"][:]}
        shots["region_lut"] = {int(c): n.decode() for c, n in f["ANCILLARY/region_lut"][:]}
    return shots


def _strata(shots) -> np.ndarray:
    return np.array([f"{shots['pft_lut'].get(p, '?')}_{shots['region_lut'].get(r, '?')}"
                     for p, r in zip(shots["pft_class"].tolist(), shots["region_class"].tolist())], dtype=object)


def test_every_shot_of_the_l4a_granule_as_l4a_selected():
    shots = _l4a_shots()
    assert shots["region_lut"][6] == "SA" and shots["pft_lut"][2] == "EBT"  # SA is 6 here, not gedipy's 4/5
    # the granule carries no rx_maxamp: a peak under the limit for every shot (L4A chose algorithm 2 for 187, which
    # the rule allows only under it)
    peak = np.zeros(len(shots["selected_algorithm"]))
    chosen = l4a_algorithm(_strata(shots), peak, shots["elev_lowestmode_a1"], shots["elev_lowestmode_a2"],
                           shots["elev_lowestmode_a10"], shots["selected_mode_flag_a10"])
    nasa = shots["selected_algorithm"]
    assert np.array_equal(chosen, nasa), np.c_[chosen, nasa][chosen != nasa][:10]
    assert {int(a): int((nasa == a).sum()) for a in np.unique(nasa)} == {1: 256, 2: 187, 5: 43, 10: 480}


def test_the_strata_the_rule_reads_are_the_model_tables():
    """The model table's code -> name tables (which name the strata in the pipeline) agree with the granule's."""
    shots = _l4a_shots()
    table = l4a_models()
    assert all(table.region[c] == n for c, n in shots["region_lut"].items())
    assert all(table.pft[c] == n for c, n in shots["pft_lut"].items() if c in table.pft)


def test_peak_limit_and_tree_types_by_hand():
    strata = np.array(["ENT_NAm", "ENT_NAm", "GSW_NAm", "EBT_SA", "EBT_SA", "EBT_Eu", "DBT_Eu", ""], dtype=object)
    peak = np.array([399.9, MAXAMP_LIMIT, 10, 10, 10, 10, 10, 10])
    a1 = np.full(8, 100.0)
    a2 = np.array([99.9, 99.0, 99.0, 100.0, 99.0, 99.0, np.nan, 99.0])
    a10 = np.array([90, 90, 90, 97.9, 98.1, 90, 90, 90.0])
    flag = np.array([4, 4, 4, 4, 4, 0, 0, 0])
    got = l4a_algorithm(strata, peak, a1, a2, a10, flag)
    # 2 under the peak limit; 1 at it; grass never 2; EBT_SA 5 (a10 > 2 m below, flag 4), else 2 (a2 below a1);
    # EBT outside Af/SA never 10; a NaN ground compares false; no stratum: 1
    assert got.tolist() == [2, 1, 1, 5, 2, 2, 1, 1]
    assert got.dtype == np.int8
    flag[3] = 1
    assert l4a_algorithm(strata, peak, a1, a2, a10, flag)[3] == 10
    assert l4a_algorithm(strata, peak, a1, a2)[3] == 1  # without algorithm 10's ground: 1 or 2 only
    assert [p.tolist() for p in stratum_parts(strata[[0, 3, 7]])] == [["ENT", "EBT", ""], ["NAm", "SA", ""]]


def test_peak_above_noise_is_l2a_rx_maxamp(gedi_beams):
    """max(rxwaveform) - noise_mean_corrected is L2A's rx_assess/rx_maxamp, for every shot of the shared beams."""
    with h5py.File(L2A) as f:
        for beam in gedi_beams:
            group = f[beam["beam"]]
            index = {s: i for i, s in enumerate(group["shot_number"][:])}
            with h5py.File(GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5") as l1b:
                shots = l1b[beam["beam"]]["shot_number"][:]
            nasa = group["rx_assess/rx_maxamp"][:][[index[s] for s in shots]]
            ours = rx_maxamp(beam["samples"], beam["offsets"], beam["noise_mean"])
            assert np.allclose(ours, nasa, rtol=0, atol=1e-3), beam["beam"]
    empty = rx_maxamp(np.array([1.0, 5.0, 3.0]), np.array([0, 0, 3]), np.array([1.0, 1.0]))
    assert np.isnan(empty[0]) and empty[1] == 4.0
