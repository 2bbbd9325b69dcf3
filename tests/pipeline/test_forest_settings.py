"""The forest's settings of a run: checked before any folder is touched, and only what differs from the defaults
in the run's fingerprint (a run with the defaults resumes a folder made before these options existed)."""

import pytest

from pipeline.forest_settings import ForestSettings


def test_the_defaults_add_nothing_to_the_fingerprint():
    assert ForestSettings().fingerprint() == {}


def test_what_differs_from_the_defaults_is_in_the_fingerprint():
    given = ForestSettings(stratum="ENT_NAm", l2a_algorithms="all", pulse_metrics="full")
    assert given.fingerprint() == {"stratum": "ENT_NAm", "l2a_algorithms": "all", "pulse_metrics": "full"}
    assert ForestSettings(l2a_algorithms="2").fingerprint() == {"l2a_algorithms": "2"}


def test_an_unknown_stratum_is_a_value_error_naming_it():
    with pytest.raises(ValueError, match="NOT_A_STRATUM"):
        ForestSettings(stratum="NOT_A_STRATUM").checked()


def test_unknown_pulse_metrics_are_a_value_error_listing_the_choices():
    with pytest.raises(ValueError, match="echoes, full"):
        ForestSettings(pulse_metrics="some").checked()


def test_a_known_stratum_is_kept():
    assert ForestSettings(stratum="ENT_NAm").checked().stratum == "ENT_NAm"
