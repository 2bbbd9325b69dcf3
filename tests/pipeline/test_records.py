"""The records between the stages: a planned input and its pulse through JSON unchanged (a plan read back by a
resumed run), a range named for a person without its pulse's arrays, a rejection's fields in rejected/'s order."""

import json

from fwcore.instrument.pulse import SystemPulse
from fwcore.instrument.response import gaussian_response
from fwcore.io.records import PointRange
from pipeline.records import InputFile, ReadTask, Rejection
from pipeline.tables import REJECTED_SCHEMA

PULSE = SystemPulse(4312.5, "single returns (95)", 0.05, "single returns (95)", -1213.25, "single returns (268)",
                    gaussian_response(4312.5), "system", "system: at held-out samples ...")


def test_an_input_and_its_pulse_go_through_json_unchanged():
    source = InputFile("/data/a.las", "a.las", "a", PULSE, False, "WKT", "the file's", True, {"ground_sigma": 2.0},
                       "L2A beside it")
    again = InputFile.from_dict(json.loads(json.dumps(source.to_dict())))
    assert again == source and again.pulse.response == gaussian_response(4312.5)


def test_a_range_is_named_by_its_input_and_points():
    source = InputFile("/data/a.las", "a.las", "a", PULSE, True)
    task = ReadTask(source, PointRange("/data/a.las", 400, 800, n_pulses=310))
    assert (task.start, task.label) == (400, "a.las points 400-800")


def test_a_rejection_holds_the_rejected_table_s_columns():
    r = Rejection("a.las", "a", 400, 412, "decompose", "no echo above the noise")
    assert set(REJECTED_SCHEMA.names) <= set(r._fields)
    assert {k: getattr(r, k) for k in REJECTED_SCHEMA.names} == {
        "source_file": "a.las", "pulse_id": 412, "stage": "decompose", "reason": "no echo above the noise"}


def test_a_plan_written_before_the_pulse_was_named_so_reads_back():
    source = InputFile("/data/a.las", "a.las", "a", PULSE, False)
    written = source.to_dict()
    written["system"] = written.pop("pulse")  # the key of plans an earlier version wrote
    assert InputFile.from_dict(json.loads(json.dumps(written))) == source
