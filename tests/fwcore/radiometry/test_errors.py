"""Radiometry's one error: a ValueError (the command line reports it as a bad input) that the trajectory's and the
options' code both raise, naming the file or the option."""

import pytest

from fwcore.radiometry.equations import parse_calibration_reference
from fwcore.radiometry.errors import RadiometryError
from fwcore.radiometry.trajectory import load_trajectory


def test_the_trajectory_and_the_options_raise_the_one_radiometry_error(tmp_path):
    assert issubclass(RadiometryError, ValueError)
    with pytest.raises(RadiometryError, match=r"--trajectory .*missing\.csv: no such file"):
        load_trajectory(tmp_path / "missing.csv", None)
    with pytest.raises(RadiometryError):
        parse_calibration_reference("not a reference")
