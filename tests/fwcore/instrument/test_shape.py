"""The system response as the kernels' table: echo_shape's rows (a Gaussian response gives Gaussian rows of the
widths asked), and an echo placed at its response lobe's centroid."""

import numpy as np
import pytest

from fwcore.engine.model import tabulated_area, tabulated_model, table_peak_offset
from fwcore.instrument.peak import main_lobe
from fwcore.instrument.response import SystemResponse, gaussian_response
from fwcore.instrument.shape import ROW_STEP, echo_shape, lobe_centroid_ps
from tests.fwcore import naive

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))


def test_the_lobe_centroid_of_a_hand_drawn_response():
    response = SystemResponse((-2000, -1000, 0, 1000, 2000, 3000, 4000), (0, 0.5, 1, 0.75, 0.5, 0.25, 0), "drawn")
    # the lobe above 5% of the peak is -1000..3000: (-500 + 0 + 750 + 1000 + 750) / (0.5 + 1 + 0.75 + 0.5 + 0.25)
    assert lobe_centroid_ps(response) == pytest.approx(2000.0 / 3.0, rel=1e-12)
    assert lobe_centroid_ps(gaussian_response(4000.0)) == pytest.approx(0.0, abs=1e-9)  # symmetric


def test_a_gaussian_response_gives_gaussian_rows_of_the_widths_asked():
    shape = echo_shape(gaussian_response(4000.0), 1000.0)
    # 4000 ps at 1000 ps a sample: the narrowest row is sigma 4 / 2 sqrt(2 ln 2) samples, the widest 3x it
    assert shape.tabulated and shape.rows.shape[0] == 48 == round(2.0 / ROW_STEP) + 1
    assert shape.s_min == pytest.approx(4.0 / FWHM_PER_SIGMA, rel=1e-3)
    assert shape.s_step == pytest.approx(shape.s_min * ROW_STEP, rel=1e-12) and shape.step == 1.0 / 16.0
    t = (np.arange(shape.rows.shape[1]) - shape.origin) * shape.step
    for row in (0, 20, 47):
        s = shape.s_min + row * shape.s_step
        inside = shape.rows[row] > 0
        np.testing.assert_allclose(shape.rows[row][inside], np.exp(-0.5 * (t[inside] / s) ** 2), atol=2e-3)
        assert shape.areas[row] == pytest.approx(s * np.sqrt(2.0 * np.pi), rel=2e-3)
    assert shape.rows.max(axis=1) == pytest.approx(1.0)


@pytest.mark.parametrize("s", [1.75, 2.4, 3.9])
def test_tabulated_echo_matches_the_naive_reference(riegl_response, s):
    shape = echo_shape(riegl_response, 1000.0)
    t = np.linspace(10.0, 50.0, 401)
    expected = naive.response_echo(riegl_response.times, riegl_response.response, 1000.0, 80.0, 21.3, s, t)
    got = tabulated_model(t, 0.0, 80.0, 21.3, s, shape)
    np.testing.assert_allclose(got, expected, atol=80.0 * 1e-2)  # rows interpolated in width: within 1% of the peak
    # the area is the echo's integral
    assert tabulated_area(shape, s) == pytest.approx(np.trapezoid(got / 80.0, t), rel=2e-3)


def test_an_echo_sits_at_its_response_lobes_centroid(leica_response):
    shape = echo_shape(leica_response, 2000.0)
    t = np.arange(-20.0, 30.0, 1.0 / 64.0)
    echo = tabulated_model(t, 0.0, 1.0, 0.0, shape.s_min, shape)
    lobe = main_lobe(echo, int(np.argmax(echo)), 0.05)
    inside = slice(lobe[0], lobe[1] + 1)
    assert np.sum(t[inside] * echo[inside]) / np.sum(echo[inside]) == pytest.approx(0.0, abs=0.02)
    # and the shape says where the echo peaks
    assert t[np.argmax(echo)] == pytest.approx(table_peak_offset(shape, shape.s_min), abs=2 * shape.step)


def test_the_table_measures_widths_only_up_to_the_widest_row_and_gives_the_same_rows(monkeypatch, leica_dir):
    """The broadened FWHMs measured up to the first past the widest row (the grid beyond infinite) give Leica's
    measured response the same table, array for array, as measuring the whole grid; and the grid's widest third
    is never convolved."""
    import fwcore.instrument.shape as shape_module
    from fwcore.instrument.measure import measure_input_response
    from fwcore.instrument.peak import half_height_width

    response = measure_input_response(leica_dir / "leica_a.las")
    measured = []
    spy = shape_module._broadened_fwhms

    def counted(t, base, sigmas, widest):
        found = spy(t, base, sigmas, widest)
        measured.append((np.isfinite(found).sum(), sigmas.size))
        return found

    monkeypatch.setattr(shape_module, "_broadened_fwhms", counted)
    fast = shape_module._echo_table(response, 1000.0, 4.0)
    monkeypatch.setattr(shape_module, "_broadened_fwhms", lambda t, base, sigmas, widest: np.array(
        [half_height_width(t, shape_module._broaden(base, s)) for s in sigmas]))
    whole = shape_module._echo_table(response, 1000.0, 4.0)
    for name in ("rows", "slopes", "areas", "support", "peak_offsets", "half_widths"):
        assert np.array_equal(getattr(fast, name), getattr(whole, name)), name
    (done, grid), = measured
    assert done < 0.75 * grid


def test_a_table_handed_over_is_the_one_echo_shape_gives(monkeypatch):
    """A run's plan hands its file's echo table to the workers (pipeline.transforms): echo_shapes_of lists the tables
    made here, and after hand_over_echo_shapes echo_shape gives the handed table without making one."""
    import fwcore.instrument.shape as shape_module
    from fwcore.instrument.shape import echo_shapes_of, hand_over_echo_shapes

    response = gaussian_response(3300.0)
    made = shape_module._echo_table(response, 1000.0, 3.5)
    monkeypatch.setattr(shape_module, "_MADE", {})
    assert echo_shapes_of(response) == []
    hand_over_echo_shapes(response, [(1000.0, 3.5, made)])
    monkeypatch.setattr(shape_module, "_echo_table", lambda *args: pytest.fail("made again"))
    assert echo_shape(response, 1000.0, 3.5) is made
    assert [(s, f) for s, f, _ in echo_shapes_of(response)] == [(1000.0, 3.5)]
    assert echo_shapes_of(gaussian_response(4000.0)) == []
