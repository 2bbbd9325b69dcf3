"""The method's flags and the pulse's: the one DecompositionConfig, and what is given of every file's pulse."""

import argparse

import pytest

from fwcore.config import DecompositionConfig
from fwcore.instrument.pulse import PulseOverrides
from fwcore.instrument.response import named_response
from pipeline.options import add_method_arguments, decomposition_config, pulse_overrides


def parse(*flags: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_method_arguments(parser)
    return parser.parse_args(list(flags))


def test_the_pulse_flags_are_not_settings_of_the_method():
    args = parse("--system-pulse-fwhm-ps", "9000", "--shape-tolerance", "0.03", "--min-snr", "4")
    assert decomposition_config(args) == DecompositionConfig(min_snr=4.0)
    assert pulse_overrides(args) == PulseOverrides(fwhm_ps=9000.0, shape_tolerance=0.03)
    assert pulse_overrides(parse()) == PulseOverrides()  # nothing given: every file's pulse measured


def test_the_paper_preset_takes_its_model_exact_unless_a_flag_says_otherwise():
    assert pulse_overrides(parse("--preset", "paper")) == PulseOverrides(shape_tolerance=0.0)
    assert pulse_overrides(parse("--preset", "paper", "--shape-tolerance", "0.05")).shape_tolerance == 0.05
    assert pulse_overrides(parse("--preset", "fast")) == PulseOverrides()


def test_a_named_response_is_read_once_with_the_given_width():
    given = pulse_overrides(parse("--system-response", "riegl"))
    assert given.response == named_response("riegl") and given.fwhm_ps is None
    gaussian = pulse_overrides(parse("--system-response", "gaussian", "--system-pulse-fwhm-ps", "6000"))
    assert gaussian.response.fwhm_ps == pytest.approx(6000.0, rel=1e-3)
    assert pulse_overrides(parse("--system-response", "gaussian")).response.fwhm_ps == pytest.approx(4000.0, rel=1e-3)
