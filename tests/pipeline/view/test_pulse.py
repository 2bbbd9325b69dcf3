"""One pulse of a run, again: the file's pulse as run.json records it (one record; an earlier run's flattened keys
read the same), and another preset's method and pulse for Try, the run's model and seed kept."""

import pytest

from fwcore.engine.config import DecompositionConfig, Model, Optimizer
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, SystemPulse
from fwcore.instrument.response import gaussian_response
from pipeline.view.pulse import load_pulse, run_pulse, try_config, try_pulse

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
