"""The file's pulse as the engine takes it, and what a user gives instead of measuring it."""

import json

import pytest

from fwcore.engine.config import Model
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, PulseOverrides, SystemPulse, nominal_pulse
from fwcore.instrument.response import gaussian_response


def test_the_echo_model_under_auto_is_the_files():
    chosen = SystemPulse(4000.0, "configured", 0.0, "configured", model="system")
    assert chosen.echo_model(Model.AUTO) is Model.SYSTEM
    assert chosen.echo_model(Model.GAUSSIAN) is Model.GAUSSIAN  # a model asked for is the model
    assert nominal_pulse().echo_model(Model.AUTO) is Model.AUTO  # no choice made: the engine's generalized


def test_the_echo_response_is_the_measured_one_else_the_gaussian_of_the_width():
    assert nominal_pulse(5000.0).echo_response().fwhm_ps == pytest.approx(5000.0, rel=1e-3)
    given = gaussian_response(3000.0)
    assert nominal_pulse(5000.0, response=given).echo_response() is given
    assert nominal_pulse().fwhm_ps == DEFAULT_PULSE_FWHM_PS == 4000.0


def test_a_pulse_round_trips_through_json():
    pulse = SystemPulse(10980.0, "single returns", 0.0506, "single returns", -1187.0, "single returns (272)",
                        gaussian_response(10980.0), "system", "system: ...")
    assert SystemPulse.from_dict(json.loads(json.dumps(pulse.to_dict()))) == pulse


def test_overrides_are_checked_and_replace_what_was_measured():
    with pytest.raises(ValueError, match="system pulse FWHM must be positive"):
        PulseOverrides(fwhm_ps=0.0)
    with pytest.raises(ValueError, match="shape_tolerance must be >= 0"):
        PulseOverrides(shape_tolerance=-0.1)
    measured = SystemPulse(10980.0, "single returns", 0.05, "single returns", -1187.0, "single returns (272)")
    given = PulseOverrides(fwhm_ps=9000.0, shape_tolerance=0.0).applied(measured)
    assert (given.fwhm_ps, given.fwhm_source, given.shape_tolerance, given.shape_source) == (
        9000.0, "configured", 0.0, "configured")
    assert given.range_offset_ps == -1187.0  # what no override names stays measured
    assert PulseOverrides().applied(measured) == measured
    assert PulseOverrides(fwhm_ps=9000.0).to_dict() == {"system_pulse_fwhm_ps": 9000.0, "shape_tolerance": None,
                                                         "system_response": None}


def test_the_paper_preset_takes_its_model_as_exact():
    assert PulseOverrides.of_preset("paper") == PulseOverrides(shape_tolerance=0.0)
    assert PulseOverrides.of_preset("fast") == PulseOverrides() == PulseOverrides.of_preset(None)
