"""The response of a NEON-layout CSV: on its outgoing pulses where given, else on the returns' single echoes."""

import pytest

from fwcore.instrument.response import csv_response, response_of_waveforms
from fwcore.io.neon import read_neon_csv


def test_csv_response_from_the_outgoing_pulses_else_the_returns(neon_dir):
    returns = read_neon_csv(neon_dir / "return_waveforms.csv")
    outgoing = read_neon_csv(neon_dir / "outgoing_pulses.csv")
    given = csv_response(returns.samples, returns.valid, 1000.0, outgoing)
    assert given.source == "outgoing pulses (115 of 229 strong single returns)"
    assert given.fwhm_ps == pytest.approx(14816.3, abs=0.1)
    echoes = csv_response(returns.samples, returns.valid, 1000.0)
    assert echoes.source == "isolated echoes (56 of 111 strong single returns)"
    assert echoes.fwhm_ps == pytest.approx(19731.0, abs=0.1)  # targets widen the forest's returns


def test_too_few_strong_returns_measure_nothing(neon_dir):
    outgoing = read_neon_csv(neon_dir / "outgoing_pulses.csv")
    assert response_of_waveforms([y[v] for y, v in zip(outgoing.samples[:10], outgoing.valid[:10])], 1000.0,
                                 "ten") is None
