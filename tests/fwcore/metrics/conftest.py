"""The shared GEDI beams as NASA distributes them: L1B waveforms and the L2A and L2B products of the same shots,
joined by shot number (never by position)."""

from pathlib import Path

import numpy as np
import pytest

GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
L1B = GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
L2A = GEDI / "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"
L2B = GEDI / "GEDI02_B_2019108080338_O01964_T05337_02_001_01_sub.h5"
TX_FIELDS = ("tx_egsigma", "tx_egsigma_error", "tx_eggamma", "tx_eggamma_error")


def _algorithm(beam, a: int, ia: np.ndarray) -> dict:
    """L2A's results of algorithm `a` for the shots `ia`: its ground and RH (m) and its intermediate results."""
    processing = beam[f"rx_processing_a{a}"]
    rh = beam[f"geolocation/rh_a{a}"]
    return {"ground_z": beam[f"geolocation/elev_lowestmode_a{a}"][:][ia],
            "rh": rh[:][ia] / (100.0 if rh.dtype.kind == "i" else 1.0),  # centimetres in the _aN fields
            **{k: processing[k][:][ia] for k in ("zcross", "selected_mode", "rx_nummodes", "rx_modelocs",
                                                 "rx_modeamps", "rx_modelocalenergy", "rx_iwaveamps", "toploc",
                                                 "botloc", "mean")}}


@pytest.fixture(scope="session")
def gedi_beams() -> list[dict]:
    """Per beam: the L1B arrays a reader needs, read straight with h5py, and NASA's L2A/L2B values joined to them."""
    import h5py

    beams = []
    with h5py.File(L1B) as l1, h5py.File(L2A) as l2a, h5py.File(L2B) as l2b:
        for name in (k for k in l1 if k.startswith("BEAM")):
            g = l1[name]
            shots = g["shot_number"][:]
            start = g["rx_sample_start_index"][:].astype(np.int64) - 1  # 1-based in the file
            count = g["rx_sample_count"][:].astype(np.int64)
            flat = g["rxwaveform"][:].astype(np.float64)
            z0, zl = g["geolocation/elevation_bin0"][:], g["geolocation/elevation_lastbin"][:]
            a_index = {s: i for i, s in enumerate(l2a[name]["shot_number"][:])}
            b_index = {s: i for i, s in enumerate(l2b[name]["shot_number"][:])}
            ia = np.array([a_index[s] for s in shots])
            ib = np.array([b_index[s] for s in shots])
            beams.append({
                "beam": name,
                "samples": np.concatenate([flat[s:s + c] for s, c in zip(start, count)]),
                "offsets": np.r_[0, np.cumsum(count)],
                "noise_mean": g["noise_mean_corrected"][:], "noise_sd": g["noise_stddev_corrected"][:],
                "first_z": z0, "metres_per_sample": (z0 - zl) / (count - 1),
                "cos_zenith": np.abs(np.sin(g["geolocation/local_beam_elevation"][:].astype(np.float64))),
                "pulse": np.stack([g[f][:].astype(np.float64) for f in TX_FIELDS], axis=1),
                "rh": l2a[name]["rh"][:][ia], "ground_z": l2a[name]["elev_lowestmode"][:][ia],
                "quality": l2a[name]["quality_flag"][:][ia],
                "toploc": l2a[name]["rx_processing_a1/toploc"][:][ia],
                "botloc": l2a[name]["rx_processing_a1/botloc"][:][ia],
                "zcross": l2a[name]["rx_processing_a1/zcross"][:][ia],
                **{k: l2b[name][k][:][ib].astype(np.float64) for k in
                   ("cover", "pai", "rv", "rg", "pgap_theta", "rhov", "rhog", "rossg", "omega", "cover_z", "pai_z",
                    "pavd_z")},
                "l2b_cos_zenith": np.abs(np.sin(l2b[name]["geolocation/local_beam_elevation"][:][ib].astype(float))),
                "algorithms": {a: _algorithm(l2a[name], a, ia) for a in range(1, 7)},
            })
    return beams
