"""Aboveground biomass density per footprint as GEDI's L4A predicts it (Kellner, Armston & Duncanson 2023, the L4A
algorithm document): the model of the shot's prediction stratum (plant functional type x world region, e.g.
EBT_SA) applied to its RH metrics.

For the stratum's model (all of L4A's version 2 models are sqrt/sqrt with Snowdon's bias correction):

    x        = [1, sqrt(RH_k + 100) for k in rh_index]     the predictors (L4A's xvar; RH in metres)
    agbd_t   = par . x                                    the prediction in fit units
    agbd_t_se = sqrt(x' vcov x + rse^2)                    its standard error in fit units
    agbd     = C agbd_t^2  (0 where agbd_t < 0)            C: the bias correction (Snowdon)
    agbd_se  = C agbd_t_se^2

which reproduces the L4A granule's agbd, agbd_se, agbd_t and agbd_t_se from its xvar for every shot and algorithm
(the shared granule: 966 shots x 7 algorithms; tests/fwcore/metrics/test_biomass.py). NASA does not clip the
predictors at predictor_max_value, nor the prediction at response_max_value (shots above both keep their value),
and stores 0 for a negative agbd_t: so does this. The models are NASA's table (data/l4a_models.json, copied from
an L4A granule by fwcore.io.gedi_l4a, attributed there), read once.

This is L4A's per-shot prediction from a waveform's RH, not L4B's gridded inference (a cell's mean biomass with
its sampling and model error): a map of these values per cell is a mean of predictions.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import numpy as np

MODEL_TABLE = Path(__file__).parent / "data" / "l4a_models.json"
RH_OFFSET_M = 100.0  # L4A adds 100 m to every RH before the square root: no negative RH reaches it
# the footprints L4A's models were fit for (GEDI's ~25 m, simulated from airborne lidar); LVIS's ~20 m is close
LARGE_FOOTPRINT_FORMATS = ("GEDI L1B", "LVIS L1B")
NO_STRATUM = ("no stratum: no L2A land cover names it (land_cover_data/pft_class and region_class of a version 002 "
              "granule beside the L1B) and no --stratum was given")
NOT_IN_L2A = 255  # the land-cover code of a shot the L2A granule beside does not hold (fwcore.io.gedi)
NOT_LARGE = "not a large footprint: L4A's models are for GEDI's 25 m footprints (use fwl footprints --stratum)"
NO_RH = "no RH (see metrics_reason)"
STRATUM_HELP = ("biomass: the GEDI L4A prediction stratum (plant functional type _ region, e.g. ENT_NAm, EBT_SA) "
                "whose model gives large-footprint shots their agbd where no version 002 L2A land cover names it")


@dataclasses.dataclass(frozen=True)
class BiomassModel:
    """One prediction stratum's L4A model."""

    stratum: str
    model_name: str
    fit_stratum: str
    rh_index: tuple[int, ...]  # which RH metrics are the predictors
    par: np.ndarray  # intercept, then one coefficient a predictor
    vcov: np.ndarray  # the coefficients' covariance
    rse: float  # the residual standard error (fit units)
    bias_correction: float  # Snowdon's ratio: back from sqrt units to Mg/ha
    predictor_max_value: np.ndarray  # the calibration data's largest predictors (not a clip: NASA extrapolates)
    response_max_value: float

    def predictors(self, rh: np.ndarray) -> np.ndarray:
        """L4A's xvar of RH0..RH100 rows (metres): sqrt(RH_k + 100) for the model's k."""
        return np.sqrt(np.asarray(rh, float)[:, list(self.rh_index)] + RH_OFFSET_M)

    def predict(self, xvar: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """agbd, agbd_se (Mg/ha), agbd_t and agbd_t_se (fit units) of predictor rows (L4A's xvar)."""
        x = np.column_stack([np.ones(len(xvar)), np.asarray(xvar, float)[:, :len(self.rh_index)]])
        t = x @ self.par
        t_se = np.sqrt(np.einsum("ni,ij,nj->n", x, self.vcov, x) + self.rse ** 2)
        agbd = np.where(t > 0, self.bias_correction * t ** 2, 0.0)  # L4A stores 0 for a negative prediction
        return agbd, self.bias_correction * t_se ** 2, t, t_se


@dataclasses.dataclass(frozen=True)
class ModelTable:
    """NASA's L4A models by prediction stratum, and the land-cover codes that name the strata."""

    strata: dict[str, BiomassModel]
    pft: dict[int, str]  # L2A/L4A land_cover_data/pft_class -> ENT, EBT, DNT, DBT, GSW
    region: dict[int, str]  # land_cover_data/region_class -> Eu, NAs, Au, Af, SAs, SA, NAm
    source: dict  # the granule, the DOI and the attribution


def _model(stratum: str, m: dict) -> BiomassModel:
    if (m["x_transform"], m["y_transform"], m["bias_correction_name"]) != ("sqrt", "sqrt", "Snowdon"):
        raise ValueError(f"{MODEL_TABLE}: {stratum}'s model is {m['x_transform']}/{m['y_transform']} with "
                         f"{m['bias_correction_name']}: only L4A version 2's sqrt/sqrt Snowdon models are known")
    return BiomassModel(stratum, m["model_name"], m["fit_stratum"], tuple(m["rh_index"]), np.array(m["par"], float),
                        np.array(m["vcov"], float), float(m["rse"]), float(m["bias_correction_value"]),
                        np.array(m["predictor_max_value"], float), float(m["response_max_value"]))


@functools.lru_cache(maxsize=1)
def l4a_models() -> ModelTable:
    """The shipped model table (read once)."""
    table = json.loads(MODEL_TABLE.read_text())
    return ModelTable({s: _model(s, m) for s, m in table["strata"].items()},
                      {int(k): v for k, v in table["pft"].items()}, {int(k): v for k, v in table["region"].items()},
                      table["source"])


def check_stratum(name: str) -> str:
    """A prediction stratum's name as the table spells it; a ValueError listing the valid ones otherwise."""
    strata = l4a_models().strata
    if name in strata:
        return name
    folded = {s.lower(): s for s in strata}
    if name.lower() in folded:
        return folded[name.lower()]
    raise ValueError(f"unknown biomass stratum {name!r}: L4A's prediction strata are plant functional type _ "
                     f"region, one of {', '.join(sorted(strata))}")


def strata_of_land_cover(pft_class: np.ndarray, region_class: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per shot, the stratum its L2A land cover names (PFT_region, '' where L4A has no model: water, urban,
    snow, unclassified) and why not ('' where named, and where L2A has not the shot: NOT_IN_L2A)."""
    table = l4a_models()
    names = np.full(len(pft_class), "", dtype=object)
    reasons = np.full(len(pft_class), "", dtype=object)
    for i, (p, r) in enumerate(zip(np.asarray(pft_class).tolist(), np.asarray(region_class).tolist())):
        name = f"{table.pft.get(p, '?')}_{table.region.get(r, '?')}"
        if p == NOT_IN_L2A:
            continue
        if name in table.strata:
            names[i] = name
        else:
            reasons[i] = f"no L4A model for the shot's land cover (L2A pft_class {p}, region_class {r})"
    return names, reasons


@dataclasses.dataclass(frozen=True)
class ShotBiomass:
    """Per shot: agbd and agbd_se (Mg/ha; NaN where not predicted), the stratum whose model gave them and why not."""

    agbd: np.ndarray
    agbd_se: np.ndarray
    stratum: np.ndarray  # object: names, '' where none
    reason: np.ndarray  # object: '' where predicted
    algorithm: np.ndarray | None = None  # GEDI: the L2A algorithm whose RH gave agbd (int8, 0: none; L4A's choice)


def predict_agbd(rh: np.ndarray, strata: np.ndarray, reasons: np.ndarray | None = None) -> ShotBiomass:
    """Each shot's L4A prediction from its RH0..RH100 (metres; rows of NaN: not measured) by its stratum's model
    (names; '' with its reason in `reasons`: none)."""
    rh = np.asarray(rh, float).reshape(-1, 101)
    n = len(rh)
    strata = np.asarray(strata, dtype=object)
    reason = np.array(reasons if reasons is not None else [""] * n, dtype=object)
    reason = np.where((strata == "") & (reason == ""), NO_STRATUM, reason)
    agbd, se = np.full(n, np.nan), np.full(n, np.nan)
    models = l4a_models().strata
    for name in sorted(set(strata.tolist()) - {""}):
        rows = np.flatnonzero(strata == name)
        model = models[name]
        x = model.predictors(rh[rows])
        ok = np.isfinite(x).all(axis=1)
        reason[rows[~ok]] = NO_RH
        a, s, _, _ = model.predict(x[ok])
        agbd[rows[ok]], se[rows[ok]] = a, s
    return ShotBiomass(agbd, se, strata, reason)


def shot_strata(n: int, large_footprint: bool, stratum: str | None = None, pft_class: np.ndarray | None = None,
                region_class: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per waveform of a batch of n its prediction stratum ('' where none) and why none: where they are large
    footprints, the stratum its land cover names (L2A's pft_class / region_class, where recorded), else `stratum`
    (e.g. --stratum ENT_NAm, checked); small footprints: none (NOT_LARGE)."""
    if not large_footprint:
        return np.full(n, "", dtype=object), np.full(n, NOT_LARGE, dtype=object)
    given = check_stratum(stratum) if stratum else ""
    if pft_class is not None and region_class is not None:
        names, reasons = strata_of_land_cover(pft_class, region_class)
        if given:  # the land cover's first; --stratum for shots the L2A granule does not hold
            names = np.where((names == "") & (reasons == ""), given, names)
        return names, reasons
    return np.full(n, given, dtype=object), np.full(n, "", dtype=object)


def footprint_biomass(rh: np.ndarray, large_footprint: bool, stratum: str | None = None,
                      pft_class: np.ndarray | None = None, region_class: np.ndarray | None = None) -> ShotBiomass:
    """Biomass of a batch of waveforms from their RH, by the strata shot_strata gives them."""
    n = len(np.asarray(rh).reshape(-1, 101))
    names, reasons = shot_strata(n, large_footprint, stratum, pft_class, region_class)
    if not large_footprint:
        return ShotBiomass(np.full(n, np.nan), np.full(n, np.nan), names, reasons)
    return predict_agbd(rh, names, reasons)
