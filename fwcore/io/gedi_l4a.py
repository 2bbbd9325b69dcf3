"""NASA GEDI L4A granules (HDF5): the biomass models NASA applied (`ANCILLARY/model_data`, one a prediction stratum)
and, per shot, what it predicted (`agbd`, `agbd_se`, the predictors `xvar`, every algorithm's in `agbd_prediction/`).

The model table is what fwcore.metrics.biomass ships as package data; `python -m fwcore.io.gedi_l4a GRANULE OUT`
writes it again from any L4A granule (the table is the same in every granule of a release).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from fwcore.io.errors import WaveformFileError
from fwcore.io.hdf5 import hdf5_file

L4A_DOI = "10.3334/ORNLDAAC/2056"
ATTRIBUTION = ("NASA GEDI L4A Footprint Level Aboveground Biomass Density, Version 2 (Dubayah, R., Armston, J., "
               "Kellner, J.R., Duncanson, L., et al., ORNL DAAC, doi:" + L4A_DOI + "); the models: Kellner, J.R., "
               "Armston, J., Duncanson, L. (2023), Algorithm Theoretical Basis Document for GEDI Footprint "
               "Aboveground Biomass Density, Earth and Space Science 10, e2022EA002516. Copied from the "
               "granule's ANCILLARY/model_data, pft_lut and region_lut; NASA data, no restriction on use.")
_TEXT = ("model_name", "fit_stratum", "x_transform", "y_transform", "bias_correction_name")
_NUMBERS = ("rse", "dof", "response_max_value", "bias_correction_value", "npar", "model_id", "model_group")


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _model(row) -> dict:
    """One stratum's model as plain JSON values: its npar coefficients, predictors and covariance only."""
    npar = int(row["npar"])
    k = npar - 1  # predictors: one RH metric each
    return {**{f: _text(row[f]) for f in _TEXT},
            **{f: row[f].item() for f in _NUMBERS},
            "rh_index": row["rh_index"][:k].astype(int).tolist(),
            "predictor_max_value": row["predictor_max_value"][:k].astype(float).tolist(),
            "par": row["par"][:npar].astype(float).tolist(),
            "vcov": row["vcov"][:npar, :npar].astype(float).tolist()}


def read_l4a_models(path: str | Path) -> dict:
    """The granule's model table: every prediction stratum's model, the plant functional type and region codes,
    the granule it came from and the attribution."""
    with hdf5_file(path, "GEDI L4A granule") as f:
        if "ANCILLARY/model_data" not in f:
            raise WaveformFileError(f"{path}: not a GEDI L4A granule (no ANCILLARY/model_data)")
        rows = f["ANCILLARY/model_data"][:]
        pft = {int(r["pft_class"]): _text(r["pft_name"]) for r in f["ANCILLARY/pft_lut"][:]}
        region = {int(r["region_class"]): _text(r["region_name"]) for r in f["ANCILLARY/region_lut"][:]}
        identity = dict(f["METADATA/DatasetIdentification"].attrs) if "METADATA/DatasetIdentification" in f else {}
    return {"source": {"granule": Path(path).name, "l4a_githash": _text(identity.get("gedi_l4a_githash", "")),
                       "doi": L4A_DOI, "attribution": ATTRIBUTION},
            "pft": {str(k): v for k, v in sorted(pft.items())},
            "region": {str(k): v for k, v in sorted(region.items())},
            "strata": {_text(r["predict_stratum"]): _model(r) for r in rows}}


def read_l4a_shots(path: str | Path, algorithm: int | None = None) -> dict[str, np.ndarray]:
    """Every beam's shots, joined: shot_number, predict_stratum, pft_class, region_class, l4_quality_flag,
    selected_algorithm and the prediction (agbd, agbd_se, agbd_t, agbd_t_se, xvar) of the selected algorithm,
    or with `algorithm` that algorithm's (agbd_prediction/*_aN)."""
    suffix = "" if algorithm is None else f"_a{algorithm}"
    where = "" if algorithm is None else "agbd_prediction/"
    fields = ("agbd", "agbd_se", "agbd_t", "agbd_t_se", "xvar", "l4_quality_flag")
    parts: dict[str, list] = {}
    with hdf5_file(path, "GEDI L4A granule") as f:
        for beam in sorted(k for k in f if k.startswith("BEAM")):
            g = f[beam]
            values = {"shot_number": g["shot_number"][:].astype(np.int64),
                      "predict_stratum": np.array([_text(s) for s in g["predict_stratum"][:]], dtype=object),
                      "pft_class": g["land_cover_data/pft_class"][:], "region_class": g["land_cover_data/region_class"][:],
                      "selected_algorithm": g["selected_algorithm"][:],
                      **{k: g[f"{where}{k}{suffix}"][:] for k in fields}}
            for k, v in values.items():
                parts.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in parts.items()}


def write_model_table(granule: str | Path, out: str | Path) -> Path:
    """The granule's model table (read_l4a_models) as the JSON file fwcore.metrics.biomass reads."""
    out = Path(out)
    out.write_text(json.dumps(read_l4a_models(granule), indent=1, sort_keys=True) + "\n")
    return out


if __name__ == "__main__":  # python -m fwcore.io.gedi_l4a GEDI04_A_....h5 fwcore/metrics/data/l4a_models.json
    print(write_model_table(sys.argv[1], sys.argv[2]))
