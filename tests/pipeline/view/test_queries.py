"""The viewer's queries (DuckDB over the run's Parquet tables) against the same tables read with pyarrow: one
pulse's echoes and row, the pulse to show first, the rejected rows, a file's time span; the colour scale and the
histograms on hand-made arrays."""

import numpy as np

from pipeline.view import queries


def test_a_pulse_s_echoes_and_row_are_the_tables(viewed):
    echoes, pulses = viewed.echoes(), viewed.pulses()
    pulse = pulses.sort_values(["n_echoes", "gps_time"], ascending=[False, True]).iloc[0]
    assert queries.first_pulse(viewed.run) == (pulse["source_file"], int(pulse["pulse_id"]))
    mine = echoes[(echoes.source_file == pulse["source_file"]) & (echoes.pulse_id == pulse["pulse_id"])]
    found = queries.pulse_echoes(viewed.run, pulse["source_file"], int(pulse["pulse_id"]))
    assert [e["echo_index"] for e in found] == sorted(mine.echo_index) and len(found) == pulse["n_echoes"]
    assert [e["time_ps"] for e in found] == list(mine.sort_values("echo_index").time_ps)
    row, part = queries.pulse_row(viewed.run, pulse["source_file"], int(pulse["pulse_id"]))
    assert row["gps_time"] == pulse["gps_time"] and part.endswith(".parquet") and "geometry" not in row
    assert queries.pulse_row(viewed.run, pulse["source_file"], -5) is None
    span = queries.gps_time_range(viewed.run, "leica_a.las")
    assert span == (pulses.gps_time.min(), pulses.gps_time.max())
    assert queries.rejected(viewed.run)["total"] == 0 and queries.source_files(viewed.run) == ["leica_a.las"]


def test_the_pulse_list_orders_by_what_it_says(viewed):
    pulses = viewed.pulses()
    listed = queries.pulse_list(viewed.run, "echoes", 5)
    assert [p["n_echoes"] for p in listed] == sorted(pulses.n_echoes, reverse=True)[:5]


def test_the_colour_scale_and_histograms_on_known_values():
    values = np.concatenate([np.arange(101.0), [np.nan, np.inf]])
    assert queries.colour_range(values) == {"cmin": 2.0, "cmax": 98.0, "below": 2, "above": 2}
    assert queries.colour_range(np.array([np.nan])) == {"cmin": None, "cmax": None, "below": 0, "above": 0}
    counts = queries._histogram(np.array([1.0, 1.0, 3.0, np.nan]), integer=True)
    assert list(counts["edges"]) == [0.5, 1.5, 2.5, 3.5] and list(counts["counts"]) == [2, 0, 1]
    assert queries._histogram(np.array([])) == {"edges": [], "counts": []}
