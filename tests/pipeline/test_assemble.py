"""A file's outputs assembled from its ranges' parts: the parts the ranges' job left, found in order, copied
whole into the file, then removed."""

from pathlib import Path

import apache_beam as beam
import laspy
from apache_beam.testing.test_pipeline import TestPipeline

from fwcore.engine.config import DecompositionConfig
from pipeline.assemble import assemble_file, written_parts
from pipeline.outputs import InputNames
from pipeline.plan import plan_inputs
from pipeline.stages import RangeSettings
from pipeline.transforms import RangeStages


def test_the_files_second_job_finds_the_written_ranges_parts_in_order(tmp_path, leica_dir):
    """The ranges' job ends at the parts; written_parts lists them from parts/ for the files' job (assemble_file)."""
    config = DecompositionConfig(generations=3)
    path = str(leica_dir / "leica_a.las")
    tasks, _ = plan_inputs([path], InputNames.of([path]), config, 400)
    out = str(tmp_path / "out")
    settings = RangeSettings(out, config, frozenset({"parquet", "las"}))
    with TestPipeline() as p:  # the middle range is not written: it must not be looked for
        p | beam.Create([tasks[2], tasks[0]]) | beam.ParDo(RangeStages(settings))
    files = written_parts(out, tasks, frozenset({"parquet", "las"}))
    assert [(stem, [(r.range_start, Path(r.las).name, r.mcap) for r in parts]) for stem, parts in files] == \
        [("leica_a", [(0, "leica_a-000000000000.las", ""), (800, "leica_a-000000000800.las", "")])]
    points = [laspy.read(r.las).header.point_count for r in files[0][1]]
    assert assemble_file(files[0], out, False) == "leica_a"
    assembled = laspy.read(tmp_path / "out" / "las" / "leica_a.las")
    assert points[0] > 0 and assembled.header.point_count == sum(points)
    assert not list((tmp_path / "out" / "parts").glob("*.las"))  # the parts are removed once in the file
