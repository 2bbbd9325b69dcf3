"""Fixtures of the fwcore tests: the Leica and RIEGL responses measured once on the bundled files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fwcore.instrument.measure import pulses_response
from fwcore.instrument.response import SystemResponse
from fwcore.io import PointRange, read_pulses

DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
LEICA = DATA / "leica_als" / "leica_a.las"
RIEGL = DATA / "pulsewaves" / "riegl_example3.pls"


@pytest.fixture(scope="session")
def leica_response() -> SystemResponse:
    pulses = read_pulses(LEICA)
    return pulses_response(pulses, np.flatnonzero(np.diff(pulses.return_offsets) == 1), "single returns")


@pytest.fixture(scope="session")
def riegl_response() -> SystemResponse:
    pulses = read_pulses(PointRange(str(RIEGL), 0, 5000))
    return pulses_response(pulses, np.arange(len(pulses)), "isolated echoes")
