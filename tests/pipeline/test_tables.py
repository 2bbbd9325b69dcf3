import pyarrow as pa

from fwcore.records import WAVEFORM_CODES, WAVEFORM_RESULT
from pipeline.tables import COLUMNS, RECORD_COLUMNS, table_schema


def test_the_waveform_tables_have_a_column_for_every_field_of_the_result_record():
    # the tables take the record's fields by RECORD_COLUMNS: a field without a column would not be written
    assert set(RECORD_COLUMNS) <= set(table_schema("csv waveforms").names)
    assert set(RECORD_COLUMNS) - {"status"} <= set(table_schema("pulses").names)  # pulses/: decomposed ones only
    for column, field in RECORD_COLUMNS.items():
        kind = "string" if field in WAVEFORM_CODES else {"i": "integer", "f": "floating"}[WAVEFORM_RESULT[field].kind]
        assert getattr(pa.types, f"is_{kind}")(COLUMNS[column].type), column
