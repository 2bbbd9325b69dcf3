"""The driver's progress bar: the pulses of the ranges whose marks are there, each mark counted once, a mark being
written not yet; the time left said in hours, minutes and seconds."""

import io

from pipeline.progress import ProgressBar, _duration
from pipeline.sinks import write_json


def test_the_progress_bar_counts_the_marks_ranges_leave(tmp_path):
    stream = io.StringIO()
    bar = ProgressBar(tmp_path, 1000, stream, interactive=True)
    write_json(tmp_path / "a-000000000000.json", {"pulses": 300, "rejected": 2})
    write_json(tmp_path / "a-000000000400.json", {"pulses": 200, "rejected": 0})
    (tmp_path / "a-000000000800.json.tmp").write_text("{")  # being written: not counted
    bar.poll()
    bar.poll()  # each mark counts once
    assert (bar.done, bar.rejected) == (500, 2)
    line = bar.line()
    assert "500/1,000 pulses  50%" in line and "rejected 2" in line and "ETA" in line


def test_a_mark_an_earlier_run_left_is_not_counted_again_and_the_last_line_ends_the_bar(tmp_path):
    write_json(tmp_path / "a-000000000000.json", {"pulses": 300, "rejected": 1})  # reused by a resumed run
    write_json(tmp_path / "a-000000000400.json", {"pulses": 100, "rejected": 0})
    stream = io.StringIO()
    with ProgressBar(tmp_path, 100, stream, interactive=True, every=60.0, already=["a-000000000000.json"]) as bar:
        pass
    assert (bar.done, bar.rejected) == (100, 0)
    drawn = stream.getvalue().split("\r")  # redrawn in place: the first draw, then the final one
    assert drawn[0] == "" and "0/100 pulses   0%" in drawn[1]
    assert "100/100 pulses 100%" in drawn[-1] and drawn[-1].endswith("rejected 0\n")
    quiet = io.StringIO()  # not a terminal: no line before line_every, none at the end
    with ProgressBar(tmp_path, 100, quiet, interactive=False, every=60.0):
        pass
    assert quiet.getvalue() == ""


def test_durations_read_as_a_clock():
    assert [_duration(s) for s in (0, 59.4, 61, 3599, 3600, 3725.6)] == [
        "0:00", "0:59", "1:01", "59:59", "1:00:00", "1:02:06"]
