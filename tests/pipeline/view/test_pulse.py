"""One pulse of a run, again: the file's pulse as run.json records it (one record; an earlier run's flattened keys
read the same), and another preset's method and pulse for Try, the run's model and seed kept; where a shot's
ground, RH and modes lie on its waveform, and what the products' columns say of it, on hand-made rows."""

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig, Model, Optimizer
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, SystemPulse
from fwcore.instrument.response import gaussian_response
from pipeline.view.pulse import RawPulse, forest_markers, load_pulse, run_pulse, shot_details, try_config, try_pulse

PULSE = SystemPulse(10337.0, "single returns (95)", 0.05, "single returns (95)", -1213.25, "single returns (268)",
                    gaussian_response(10337.0), "system", "system: at held-out samples ...")
ROW = {"system_pulse_fwhm_ps": 10337.0, "shape_tolerance": 0.05}


def test_the_run_s_pulse_is_read_back_from_its_record_or_an_earlier_run_s_flat_keys():
    summary = {"inputs": [{"name": "other.las"}, {"name": "a.las", "system_pulse": PULSE.to_dict()}]}
    assert run_pulse(summary, "a.las", ROW) == PULSE
    flat = {"name": "a.las", "system_pulse_fwhm_ps": 10337.0, "system_pulse_fwhm_source": "single returns (95)",
            "shape_tolerance": 0.05, "shape_tolerance_source": "single returns (95)", "range_offset_ps": -1213.25,
            "range_offset_source": "single returns (268)", "system_response": PULSE.response.to_dict(),
            "model": "system", "model_choice": "system: at held-out samples ..."}
    assert run_pulse({"inputs": [flat]}, "a.las", ROW) == PULSE
    # no record at all (an input the run.json does not list): the row's width and tolerance
    bare = run_pulse({"inputs": []}, "a.las", ROW)
    assert (bare.fwhm_ps, bare.shape_tolerance, bare.fwhm_source, bare.response) == (10337.0, 0.05, "the run's", None)
    assert run_pulse({}, "a.las", {}).fwhm_ps == DEFAULT_PULSE_FWHM_PS


def test_another_preset_changes_the_method_and_what_it_says_of_the_pulse_only():
    assert try_pulse(PULSE, "paper").shape_tolerance == 0.0 and try_pulse(PULSE, "paper").shape_source == "configured"
    assert try_pulse(PULSE, "fast") == PULSE == try_pulse(PULSE, None)
    base = DecompositionConfig(model=Model.SYSTEM, seed=7)
    paper = try_config(base, "paper", {"max_echoes": 4})
    assert (paper.optimizer, paper.generations, paper.model, paper.seed, paper.max_echoes) == (
        Optimizer.MDE, 80, Model.SYSTEM, 7, 4)
    assert try_config(base, None, {"min_snr": 2.0}) == base.replace(min_snr=2.0)
    with pytest.raises(ValueError, match="unknown decomposition settings \\['prune'\\]"):
        try_config(base, None, {"prune": True})
    with pytest.raises(ValueError, match="preset must be one of fast, paper"):
        try_config(base, "quick", {})


def test_a_pulse_of_the_viewed_run_comes_back_with_its_file_s_recorded_pulse(viewed):
    pulses = viewed.pulses()
    row = pulses.iloc[0]
    raw, config, pulse, found = load_pulse(viewed.run, row["source_file"], int(row["pulse_id"]))
    assert raw.samples.size == row["n_samples"] and raw.sample_spacing_ps == row["sample_spacing_ps"]
    assert pulse.fwhm_ps == row["system_pulse_fwhm_ps"] and pulse.shape_tolerance == row["shape_tolerance"]
    assert pulse.fwhm_source != "the run's"  # from run.json's record, not rebuilt from the row
    assert config.optimizer is Optimizer.LM and found["pulse_id"] == row["pulse_id"]  # the fast preset's


def _gedi_like() -> RawPulse:
    """A GEDI-like waveform: 1 ns samples, the first at 812.0 m, 0.15 m lower a sample."""
    none = np.zeros(0)
    return RawPulse(np.zeros(1000), 1000.0, 0, none, none.astype(int), none.astype(int), first_z=812.0,
                    metres_per_sample=0.15)


def test_a_shot_s_modes_below_its_ground_are_the_passed_over_ones():
    rh = [None] * 101
    rh[25], rh[50], rh[75], rh[98] = -0.3, 0.6, 3.0, 7.5
    row = {"ground_z": 795.5, "rh": rh, "mode_z": np.array([803.0, 795.5000305, 793.25, 790.1], dtype=np.float32)}
    markers = forest_markers(_gedi_like(), row)
    # (812.0 - 795.5) / 0.15 = 110 samples of 1000 ps
    assert markers["ground_time_ps"] == pytest.approx(110_000.0) and markers["ground_z"] == 795.5
    assert [m["k"] for m in markers["rh"]] == [25, 50, 75, 98]
    assert markers["rh"][-1]["time_ps"] == pytest.approx((812.0 - 803.0) / 0.15 * 1000)
    # the ground's own mode (float32: 3e-5 m off) is no passed-over one; the two below it are
    assert [m["passed_over"] for m in markers["modes"]] == [False, False, True, True]
    assert markers["modes"][2]["time_ps"] == pytest.approx((812.0 - 793.25) / 0.15 * 1000)
    # no mode_z column (a run before it, a non-GEDI run): the ground and RH alone
    assert forest_markers(_gedi_like(), {"ground_z": 795.5, "rh": rh})["modes"] == []
    assert forest_markers(_gedi_like(), {"ground_z": None, "rh": rh}) is None
    assert forest_markers(_gedi_like(), {"ground_z": float("nan"), "rh": rh}) is None


def test_a_shot_s_products_are_what_its_row_holds_and_ids_stay_exact():
    row = {"pulse_id": 19640119700108618, "shot_number": 19640119700108618, "lfid": None, "selected_algorithm": 2,
           "agbd": 42.25, "agbd_se": 6.5, "agbd_stratum": "GSW_SAm", "agbd_reason": "", "top_z": 803.0}
    assert shot_details(row) == {"shot_number": "19640119700108618", "selected_algorithm": 2, "top_z": 803.0,
                                 "agbd": 42.25, "agbd_se": 6.5, "agbd_stratum": "GSW_SAm"}
    # no biomass, and why; an LVIS shot's LFID and shot number
    assert shot_details({"shot_number": 7, "agbd": float("nan"), "agbd_se": None,
                         "agbd_reason": "no stratum: give --stratum"}) == \
        {"shot_number": "7", "agbd": None, "agbd_reason": "no stratum: give --stratum"}
    # a small-footprint pulse's top_z and agbd_reason alone are no shot's products
    assert shot_details({"top_z": 32.8, "agbd": None, "agbd_reason": "not a large footprint"}) is None
    assert shot_details({"lfid": 2333001003, "shot_number": 277275}) == {"lfid": "2333001003", "shot_number": "277275"}
    # a LAS run (the columns absent, or present and null): nothing to show
    assert shot_details({"pulse_id": 5, "gps_time": 1.0}) is None
    assert shot_details({"shot_number": None, "lfid": None, "selected_algorithm": None, "agbd_reason": ""}) is None
