"""Every value a request can send the viewer, checked before any file is opened: the Try settings (generated from
the config's declarations), presets, pulse ids, boxes and limits."""

import re

import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.view import params
from pipeline.view.params import TRY_SETTINGS, BadRequest


def test_the_try_settings_are_the_config_s_declared_refits_and_their_caps_are_valid_settings():
    assert TRY_SETTINGS["max_echoes"] == ("int", 1, 24) and TRY_SETTINGS["select_echoes"] == ("bool",)
    assert TRY_SETTINGS["min_amplitude_ratio"] == ("float", 0.0, 1.0)
    assert TRY_SETTINGS["model"] == ("choice", ["system", "generalized", "gaussian", "auto"])
    assert len(TRY_SETTINGS) == 13
    for name, spec in TRY_SETTINGS.items():
        if spec[0] in ("int", "float"):
            for cap in spec[1:]:  # a refit at either cap is a configuration the engine takes
                assert getattr(DecompositionConfig().replace(**{name: cap}), name) == cap


def test_a_refit_s_changes_are_checked_one_by_one():
    assert params.try_changes(None) == {}
    assert params.try_changes({"max_echoes": 24, "min_snr": 2, "select_echoes": False, "optimizer": "lm"}) == {
        "max_echoes": 24, "min_snr": 2, "select_echoes": False, "optimizer": "lm"}
    for changes, said in [({"max_echoes": 25}, "max_echoes must lie in [1, 24], not 25"),
                          ({"max_echoes": 2.5}, "max_echoes must be a whole number"),
                          ({"min_snr": True}, "min_snr must be a number"),
                          ({"min_snr": float("nan")}, "min_snr must lie in [0, 1000]"),
                          ({"select_echoes": 1}, "select_echoes must be true or false"),
                          ({"optimizer": "newton"}, "optimizer must be one of none, lm,"),
                          ({"seed": 3}, "'seed' cannot be changed in a refit"),
                          (["max_echoes"], "changes must be an object")]:
        with pytest.raises(BadRequest, match=re.escape(said)):
            params.try_changes(changes)


def test_presets_pulse_ids_boxes_and_limits():
    assert params.preset("") is None and params.preset("paper") == "paper"
    with pytest.raises(BadRequest, match="preset must be one of fast, paper, not 'quick'"):
        params.preset("quick")
    assert params.pulse_id("-12") == -12 and params.pulse_id(2 ** 63 - 1) == 2 ** 63 - 1
    for bad, said in [(True, "whole number"), ("1e3", "whole number"), (2 ** 63, "64-bit")]:
        with pytest.raises(BadRequest, match=said):
            params.pulse_id(bad)
    assert params.box({"box": ["1,2,3,4"]}) == (1.0, 2.0, 3.0, 4.0) and params.box({}) is None
    with pytest.raises(BadRequest, match="xmin <= xmax"):
        params.box({"box": ["2,1,3,4"]})
    assert params.limit({"limit": ["999999"]}, 10, cap=500) == 500 and params.limit({}, 10) == 10
    assert params.flag({"kept": ["1"]}, "kept") and not params.flag({}, "kept")
    with pytest.raises(BadRequest, match="missing parameter 'run'"):
        params.name("", "run")
