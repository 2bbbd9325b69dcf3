"""The method's command-line options, generated from DecompositionConfig's fields, each reaching the config; and the
pulse's flags, what is given of every file's pulse instead of a setting of the method."""

from __future__ import annotations

import argparse
import dataclasses
import enum

import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import PulseOverrides
from fwcore.instrument.response import named_response
from pipeline.cli import build_parser
from pipeline.options import COMPARED, add_method_arguments, decomposition_config, pulse_overrides
from tests.fwcore.engine.test_config import other_value

OPTIONS = [f for f in dataclasses.fields(DecompositionConfig) if f.metadata.get("option")]


def _flags(command: str) -> set[str]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return {s for a in sub._actions for s in a.option_strings}


@pytest.mark.parametrize("field", OPTIONS, ids=lambda f: f.name)
def test_every_option_reaches_the_config(field):
    value = other_value(field.name)
    flag = "--" + field.name.replace("_", "-")
    if isinstance(value, bool):
        given = [flag if value else "--no-" + flag[2:]]
    else:
        given = [flag, str(value.value if isinstance(value, enum.Enum) else value)]
    config = decomposition_config(build_parser().parse_args(["run", *given]))
    assert getattr(config, field.name) == value
    assert config.replace(**{field.name: getattr(DecompositionConfig(), field.name)}) == DecompositionConfig()


def test_every_method_command_has_the_options_and_compare_chooses_its_own_optimizers_and_models():
    flags = {"--" + f.name.replace("_", "-") for f in OPTIONS}
    for command in ("run", "watch", "decompose-csv"):
        assert flags <= _flags(command), command
    compared = {"--" + name.replace("_", "-") for name in COMPARED}
    assert flags - compared <= _flags("compare") and not compared & _flags("compare") - {"--model"}
    assert "--optimizers" in _flags("compare")


def test_a_flag_not_given_leaves_the_preset_and_toml_values(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[decomposition]\nraw_polish = false\nmin_snr = 4\n")
    config = decomposition_config(build_parser().parse_args(["run", "--preset", "paper", "--config", str(path)]))
    assert config.raw_polish is False and config.min_snr == 4 and config.generations == 80


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


def _dask_runner_loaded_after(flags: list[str]) -> str:
    """What a fresh process says after check_beam_args(flags): whether Beam's Dask runner module got imported."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; from pipeline.options import check_beam_args; check_beam_args(sys.argv[1:]); "
            "print('apache_beam.runners.dask.dask_runner' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    return subprocess.run([sys.executable, "-c", code, *flags], capture_output=True, text=True, check=True,
                          env=env).stdout.strip()


def test_the_dask_runner_is_imported_only_for_its_flags():
    """A DirectRunner run's options leave dask, distributed and pandas unloaded (0.3 s of its start); the Dask
    runner's flags are still known, and a mistyped one still named."""
    from pipeline.options import OptionError, check_beam_args

    assert _dask_runner_loaded_after(["--direct_num_workers=2"]) == "False"
    assert _dask_runner_loaded_after(["--dask_client_address=localhost:1"]) == "True"
    from apache_beam.runners.dask.dask_runner import DaskOptions

    options = check_beam_args(["--dask_client_address=localhost:1"])
    assert options.view_as(DaskOptions).address == "localhost:1"
    with pytest.raises(OptionError, match="did you mean --direct_num_workers"):
        check_beam_args(["--direct_num_worker=2"])
