"""The output folder's names, from one module: a range's parts and mark, a file's outputs, the patterns that
find an input's files."""

import re
from types import SimpleNamespace

from pipeline import layout


def _task(stem: str = "leica_a", start: int = 400) -> SimpleNamespace:
    """What the names read of a ReadTask: its input's stem and its first point."""
    return SimpleNamespace(source=SimpleNamespace(stem=stem), start=start)


def test_a_range_s_files_are_named_by_its_stem_and_first_point(tmp_path):
    assert layout.part_name("leica_a", 400) == "leica_a-000000000400"
    paths = layout.part_paths(tmp_path, _task())
    assert {k: p.relative_to(tmp_path).as_posix() for k, p in paths.items()} == {
        "echoes": "echoes/leica_a-000000000400.parquet", "pulses": "pulses/leica_a-000000000400.parquet",
        "las": "parts/leica_a-000000000400.las", "mcap": "parts/leica_a-000000000400.mcap"}
    assert [p.relative_to(tmp_path).as_posix() for p in layout.range_files(tmp_path, _task())] == [
        "echoes/leica_a-000000000400.parquet", "pulses/leica_a-000000000400.parquet",
        "rejected/leica_a-000000000400.parquet", "parts/leica_a-000000000400.las", "parts/leica_a-000000000400.mcap"]
    assert layout.progress_mark(tmp_path, "leica_a", 400) == tmp_path / "parts" / "leica_a-000000000400.json"
    assert layout.plan_path(tmp_path, "leica_a") == tmp_path / "parts" / "plans" / "leica_a.json"


def test_a_file_s_outputs_and_its_rejections(tmp_path):
    outputs = layout.file_outputs(tmp_path, "x", laz=True)
    assert {k: p.relative_to(tmp_path).as_posix() for k, p in outputs.items()} == {
        "las": "las/x.laz", "copc": "copc/x.copc.laz", "mcap": "mcap/x.mcap"}
    (tmp_path / "rejected").mkdir()
    for name in ("x-000000000000.parquet", "x-000000005000.parquet", "x-tile-0000.parquet", "xy-000000000000.parquet"):
        (tmp_path / "rejected" / name).touch()
    assert [p.name for p in layout.rejected_files(tmp_path, "x")] == [
        "x.parquet", "x-000000000000.parquet", "x-000000005000.parquet"]


def test_the_patterns_match_the_names_they_stand_for():
    own = re.compile("x" + f"({layout.RANGE_SUFFIX}|{layout.TILE_SUFFIX}|{layout.BUCKET_SUFFIX})")
    assert own.fullmatch(layout.part_name("x", 12)) and own.fullmatch(layout.tile_name("x", 3))
    assert own.fullmatch(layout.bucket_name("x", 12345)) and layout.bucket_name("x", 7) == "x-bucket-0007"
    assert not own.fullmatch("x-400") and not own.fullmatch("x-tile-12")


def test_the_folders_a_run_owns():
    assert layout.OUTPUT_DIRS == ("echoes", "pulses", "rejected", "las", "mcap", "copc", "logs", "parts")
    assert (layout.MANIFEST, layout.RUN_JSON) == ("fwl-output.json", "run.json")
    assert layout.STAGED.as_posix() == "parts/compact/echoes" and layout.FINISHED.as_posix() == "parts/compact-finished"


def test_a_part_s_name_gives_back_its_range_s_first_point():
    assert layout.range_start(layout.part_name("flight-7", 1125) + ".parquet") == 1125
    assert layout.range_start(f"echoes/{layout.part_name('a-000000000001', 0)}.parquet") == 0
    assert layout.range_start(layout.tile_name("flight-7", 3) + ".parquet") is None
