import numpy as np
import pyarrow as pa
import pytest

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.decompose import smoothing_sigma_samples
from fwcore.instrument.pulse import nominal_pulse
from fwcore.engine.records import WAVEFORM_CODES, WAVEFORM_RESULT
from pipeline.tables import COLUMNS, RECORD_COLUMNS, pulse_tables, table_schema
from tests.fwcore.naive import gaussian_smooth


def test_the_waveform_tables_have_a_column_for_every_field_of_the_result_record():
    # the tables take the record's fields by RECORD_COLUMNS: a field without a column would not be written
    assert set(RECORD_COLUMNS) <= set(table_schema("csv waveforms").names)
    assert set(RECORD_COLUMNS) - {"status"} <= set(table_schema("pulses").names)  # pulses/: decomposed ones only
    for column, field in RECORD_COLUMNS.items():
        kind = "string" if field in WAVEFORM_CODES else {"i": "integer", "f": "floating"}[WAVEFORM_RESULT[field].kind]
        assert getattr(pa.types, f"is_{kind}")(COLUMNS[column].type), column


# ---------------------------------------------------------------- every column recomputed from the waveform and the fit

@pytest.fixture(scope="module")
def leica_tables(leica_dir):
    """The Leica sample's first 20 pulses decomposed (generalized Gaussians), their tables as the run writes them,
    and what they were made from."""
    from fwcore.engine.decompose import decompose_batch
    from fwcore.io import PointRange, read_pulses
    from fwcore.pulses import pulse_waveforms

    pulses = read_pulses(PointRange(str(leica_dir / "leica_a.las"), 0, 20, max_pulses=20))
    config = DecompositionConfig(model=Model.GENERALIZED, generations=10)
    pulse = nominal_pulse(5000.0)
    batch = pulse_waveforms(pulses, config.seed)
    result = decompose_batch(batch, config, pulse)
    xyz = np.zeros((result.amplitude.size, 3))
    echoes, table = pulse_tables("leica_a.las", pulses, result, config, pulse, xyz, result.status == 0)
    return pulses, batch, result, config, echoes.to_pandas(), table.to_pandas()


def test_string_columns_by_code_and_repeated_are_arrow_strings():
    from pipeline.tables import _coded_strings, _strings

    got = _coded_strings(("", "weak", "too_close"), np.array([2, 0, 1, 1], dtype=np.int8))
    assert got.type == pa.string() and got.to_pylist() == ["too_close", "", "weak", "weak"]
    assert _strings("lm", 3).to_pylist() == ["lm", "lm", "lm"] and _strings("lm", 0).type == pa.string()
    assert len(_strings("lm", 0)) == 0 and _coded_strings(("a",), np.array([], dtype=np.int8)).to_pylist() == []


def test_fit_error_is_the_sum_of_absolute_residuals_as_documented(leica_tables):
    pulses, batch, result, config, _, table = leica_tables
    sigma = smoothing_sigma_samples(config, nominal_pulse(5000.0), batch.sample_spacing_ps)
    assert len(table) == len(pulses) and COLUMNS["fit_error"].unit == COLUMNS["fit_error_raw"].unit == "DN"
    assert "absolute residuals" in COLUMNS["fit_error"].meaning
    for i, row in table.iterrows():
        raw = batch.samples[batch.offsets[i]:batch.offsets[i + 1]]
        residual = result.waveform(i).model(np.arange(raw.size, dtype=float)) - raw
        denoised = gaussian_smooth(raw, sigma[i])  # all of a LAS packet's samples are valid
        model = residual + raw
        np.testing.assert_allclose(row.fit_error, np.abs(model - denoised).sum(), rtol=1e-9)
        np.testing.assert_allclose(row.fit_error_raw, np.abs(residual).sum(), rtol=1e-9)
        np.testing.assert_allclose(row.rmse, np.sqrt(np.mean(residual ** 2)), rtol=1e-9)
        np.testing.assert_allclose(row.r2, 1 - (residual ** 2).sum() / ((raw - raw.mean()) ** 2).sum(), rtol=1e-9)
        # the fit's squared sum is not what fit_error holds (the schema once said so)
        assert not np.isclose(row.fit_error_raw, (residual ** 2).sum(), rtol=1e-3)


def test_echo_columns_are_the_fitted_echoes_in_their_units(leica_tables):
    pulses, _, result, _, echoes, _ = leica_tables
    owner = result.echo_waveform
    for e, row in echoes.iterrows():
        i = owner[e]
        fit, k = result.waveform(int(i)), e - result.echo_offsets[i]
        spacing, gain = pulses.sample_spacing_ps[i], pulses.digitizer_gain[i]
        t = np.linspace(fit.position[k] - 20, fit.position[k] + 20, 40_001)  # samples, 0.001 apart
        echo = fit.echo(k, t)
        peak = int(np.argmax(echo))
        np.testing.assert_allclose(row.amplitude, echo[peak], rtol=1e-6)  # DN above the background
        np.testing.assert_allclose(row.amplitude_volts, row.amplitude * gain, rtol=1e-12)
        above = t[echo >= echo[peak] / 2]  # the echo is symmetric: its centre is halfway between its half heights
        np.testing.assert_allclose(row.time_ps, (above[0] + above[-1]) / 2 * spacing, atol=0.001 * spacing)
        np.testing.assert_allclose(row.fwhm_ps, (above[-1] - above[0]) * spacing, atol=0.002 * spacing)
        wide = np.linspace(fit.position[k] - 2000, fit.position[k] + 2000, 200_001)  # a low alpha's long tails
        np.testing.assert_allclose(row.energy, np.trapezoid(fit.echo(k, wide), wide) * spacing, rtol=1e-4)  # DN ps
        # Chauve's form with t in ps: A exp(-|t - u|^(alpha^2) / (2 sigma^2)) at a point of the flank
        at = row.time_ps + 0.3 * row.fwhm_ps
        chauve = row.amplitude * np.exp(-abs(at - row.time_ps) ** (row.alpha ** 2) / (2 * row.sigma_chauve ** 2))
        np.testing.assert_allclose(chauve, fit.echo(k, np.array([at / spacing]))[0], rtol=1e-6)
        np.testing.assert_allclose(row.background, fit.background, rtol=1e-12)
