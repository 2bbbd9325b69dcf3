"""A file's outputs assembled from its ranges' parts: the files' job, after the ranges' job.

    written_parts(output, tasks, formats)   each input's RangeParts, as the files under parts/ show them
    assemble_file(item, output, laz)        one input's parts -> las/<stem>.las (.laz), copc/<stem>.copc.laz,
                                            mcap/<stem>.mcap, streamed in range order; the parts removed

The writers are pipeline.sinks' (LAS, MCAP) and pipeline.copc's; the names pipeline.layout's.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.copc import assemble_copc, has_point_cloud_parts
from pipeline.layout import LAS, MCAP, COPC, file_outputs, part_paths
from pipeline.records import RangePart, ReadTask
from pipeline.sinks import assemble_las, assemble_mcap, remove_parts


def written_parts(output: str | Path, tasks: list[ReadTask],
                  formats: frozenset[str]) -> list[tuple[str, list[RangePart]]]:
    """After the ranges' job, each input's RangeParts as the files under parts/ show them (a range is written
    whole or not at all, and a range's stale parts are removed before it is redone), in plan order."""
    files: dict[str, list[RangePart]] = {}
    for task in tasks:
        paths = part_paths(output, task)
        las = str(paths[LAS]) if has_point_cloud_parts(formats) and paths[LAS].exists() else ""
        mcap = str(paths[MCAP]) if "mcap" in formats and paths[MCAP].exists() else ""
        if las or mcap:
            files.setdefault(task.source.stem, []).append(RangePart(
                task.source.stem, task.source.path, task.start, las, mcap, task.source.adjusted_standard_gps_time))
    return list(files.items())


def assemble_file(item: tuple[str, list[RangePart]], output: str | Path, laz: bool,
                  formats: frozenset[str] = frozenset(("las", "mcap"))) -> str:
    """One input's RangeParts -> las/<stem>.las (or .laz), copc/<stem>.copc.laz and mcap/<stem>.mcap, streamed
    from the parts in range order; the parts are removed once in the files."""
    stem, ranges = item
    ranges = sorted(ranges, key=lambda r: r.range_start)
    las = [Path(r.las) for r in ranges if r.las]
    mcap = [Path(r.mcap) for r in ranges if r.mcap]
    paths = file_outputs(output, stem, laz)
    if las and "las" in formats:
        assemble_las(las, paths[LAS], laz)
    if las and "copc" in formats:
        assemble_copc(las, paths[COPC])
    if mcap:
        assemble_mcap(mcap, paths[MCAP], ranges[0].adjusted_standard_gps_time)
    remove_parts(las + mcap)
    return stem
