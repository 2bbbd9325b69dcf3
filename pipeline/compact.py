"""`fwl compact RUN_DIR`: a finished run's echo parts (one a range, in flight order) rewritten as spatial tiles for
analysts: per input, runs of its echoes along the Hilbert curve over the square on its extent, each tile in
Hilbert order and in row groups with statistics (pipeline.geoparquet), so that a box query reads a few row groups
of a few files.

    stage   per input: its parts -> buckets (parts/compact/<stem>-bucket-NNNN.parquet, one per tile, in one pass
            over the parts) -> each bucket sorted into its tile under parts/compact/echoes/; the input's mark
            parts/compact/<stem>.json, written last, lists the parts it read and the tiles it wrote
    swap    once every input is marked: echoes/ -> parts/compact/replaced/, parts/compact/echoes/ -> echoes/
            (two renames), the replaced parts removed, run.json's file list updated, the staging removed

Memory is bounded by a part and a tile (--tile-rows). A killed compaction is rerun: an input with its mark is not
staged again, the swap goes on from where it stopped; until the first rename echoes/ is the run's own, after the
second it is the tiles, so no reader ever sees a row twice or misses one. Tiles are named after their input
(<stem>-tile-NNNN.parquet), so `fwl run --resume`, `fwl watch` and `fwl view` treat them as the input's.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fwcore.spatial import NO_POSITION, finite_bounds, hilbert_key, square_bounds
from pipeline.geoparquet import spatially_sorted, write_echo_part
from pipeline.layout import (BUCKET_SUFFIX, COMPACT, ECHOES, FINISHED, PARTS, RANGE_SUFFIX, REPLACED, STAGED,
                             TILE_SUFFIX, bucket_name, tile_name)
from pipeline.outputs import earlier_run_files, list_outputs, read_manifest, read_run, write_run_json
from pipeline.sinks import remove_parts, write_json
from pipeline.tables import GEO_METADATA_KEY, geo_metadata

TILE_ROWS = 1_000_000  # echoes per tile: files of some 170 MB (the benchmark's 422,133 echoes take 73 MB)
# echoes per row group of a tile: its row groups follow one curve over the whole input, so larger ones still prune
# (a centre box of 1% of the 200,000-pulse flight's area: 5.8% of the bytes), and the footer every query parses
# (836 KB at 2,048, some 20 ms in DuckDB) is 4x smaller (bench/bench_query.py)
TILE_ROW_GROUP_ROWS = 8192
TILE_ORDER = 8  # tiles are runs of cells of a 256 x 256 Hilbert grid over the input's extent


def echo_files(echoes: Path, stem: str) -> list[Path]:
    """An input's echo files in echoes/: its range parts (<stem>-<12 digits>) or its tiles (<stem>-tile-NNNN)."""
    own = re.compile(re.escape(stem) + rf"({RANGE_SUFFIX}|{TILE_SUFFIX})\.parquet")
    return sorted(p for p in echoes.glob("*.parquet") if own.fullmatch(p.name)) if echoes.is_dir() else []


def _extent(sources: list[Path]) -> tuple[float, float, float, float] | None:
    """The input's extent from its parts' GeoParquet bbox (footers only); read from x and y where one has none."""
    boxes = []
    for path in sources:
        meta = pq.read_schema(path).metadata or {}
        try:
            bbox = json.loads(meta[GEO_METADATA_KEY])["columns"]["geometry"].get("bbox")
        except (KeyError, ValueError):
            bbox = None
        if bbox is None and pq.ParquetFile(path).metadata.num_rows:
            t = pq.read_table(path, columns=["x", "y"])
            found = finite_bounds(*(t.column(c).to_numpy(zero_copy_only=False) for c in ("x", "y")))
            bbox = None if found is None else [found[0], found[1], 0.0, found[2], found[3], 0.0]
        if bbox is not None:
            boxes.append((bbox[0], bbox[1], bbox[3], bbox[4]))
    if not boxes:
        return None
    b = np.array(boxes)
    return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())


def _cells(table: pa.Table, extent) -> np.ndarray:
    """Each row's cell of the tiling grid; rows without a position in one cell after all others."""
    x, y = (table.column(c).to_numpy(zero_copy_only=False).astype(np.float64) for c in ("x", "y"))
    if extent is None:
        return np.full(len(x), 4 ** TILE_ORDER, dtype=np.int64)
    key = hilbert_key(x, y, extent, TILE_ORDER)
    return np.where(key == NO_POSITION, 4 ** TILE_ORDER, key).astype(np.int64)


def tiles_of_cells(counts: np.ndarray, tile_rows: int) -> np.ndarray:
    """Each cell's tile: consecutive cells along the curve, at most `tile_rows` echoes a tile (a fuller cell is a
    tile of its own)."""
    tile_of = np.zeros(counts.size, dtype=np.int64)
    tile, held = 0, 0
    for cell, n in enumerate(counts):
        if n and held and held + n > tile_rows:
            tile, held = tile + 1, 0
        tile_of[cell] = tile
        held += int(n)
    return tile_of


def _buckets(folder: Path, stem: str, sources: list[Path], tile_of: np.ndarray, extent, schema: pa.Schema
             ) -> dict[int, Path]:
    """One pass over the parts: each row into its tile's bucket file."""
    writers: dict[int, pq.ParquetWriter] = {}
    paths: dict[int, Path] = {}
    try:
        for source in sources:
            table = pq.read_table(source)
            if not table.num_rows:
                continue
            table = _conform(table, schema, source)
            tiles = tile_of[_cells(table, extent)]
            order = np.argsort(tiles, kind="stable")
            bounds = np.flatnonzero(np.r_[True, np.diff(tiles[order]) != 0, True])
            for lo, hi in zip(bounds[:-1], bounds[1:]):
                tile = int(tiles[order[lo]])
                if tile not in writers:
                    paths[tile] = folder / COMPACT / f"{bucket_name(stem, tile)}.parquet"
                    writers[tile] = pq.ParquetWriter(paths[tile], schema)
                writers[tile].write_table(table.take(pa.array(order[lo:hi])))
    finally:
        for writer in writers.values():
            writer.close()
    return paths


def _conform(table: pa.Table, schema: pa.Schema, source: Path) -> pa.Table:
    if table.schema.equals(schema, check_metadata=False):
        return table.replace_schema_metadata(schema.metadata)
    raise ValueError(f"{source}: its columns differ from the input's other echo parts; it cannot join their tiles")


def _tile(bucket: Path, extent, staged: Path, name: str, metadata: dict, crs: str | None,
          row_group_rows: int) -> int:
    """A bucket -> its tile: in Hilbert order over the input's extent, with its own GeoParquet bbox."""
    table = spatially_sorted(pq.read_table(bucket), extent)
    x, y, z = (table.column(c).to_numpy(zero_copy_only=False).astype(np.float64) for c in ("x", "y", "z"))
    table = table.replace_schema_metadata({**metadata, **geo_metadata(x, y, z, crs)})
    write_echo_part(table, staged, name, row_group_rows, sort=False)
    bucket.unlink()
    return table.num_rows


def _crs_of(metadata: dict) -> str | None:
    try:
        crs = json.loads(metadata[GEO_METADATA_KEY])["columns"]["geometry"].get("crs")
    except (KeyError, ValueError):
        return None
    return json.dumps(crs) if crs is not None else None


def _rows(paths: list[Path]) -> int:
    return sum(pq.ParquetFile(p).metadata.num_rows for p in paths)


def stage_input(folder: Path, stem: str, tile_rows: int, row_group_rows: int) -> dict:
    """One input's tiles under parts/compact/echoes/, then its mark; what an earlier attempt left goes first."""
    compact, staged = folder / COMPACT, folder / STAGED
    stale = re.compile(re.escape(stem) + rf"({BUCKET_SUFFIX}|{TILE_SUFFIX})\.parquet(\.tmp)?")
    remove_parts([p for d in (compact, staged) for p in sorted(d.glob("*")) if stale.fullmatch(p.name)])
    sources = echo_files(folder / ECHOES, stem)
    extent = square_bounds(found) if (found := _extent(sources)) else None
    counts = np.zeros(4 ** TILE_ORDER + 1, dtype=np.int64)
    for source in sources:  # the tiles' sizes, from the positions alone
        if pq.ParquetFile(source).metadata.num_rows:
            counts += np.bincount(_cells(pq.read_table(source, columns=["x", "y"]), extent), minlength=counts.size)
    tiles: list[str] = []
    if sources and counts.sum():
        schema = pq.read_schema(sources[0])
        metadata = {k: v for k, v in (schema.metadata or {}).items() if k != GEO_METADATA_KEY}
        buckets = _buckets(folder, stem, sources, tiles_of_cells(counts, tile_rows), extent, schema)
        for index, tile in enumerate(sorted(buckets)):  # tiles numbered along the curve, without gaps
            tiles.append(tile_name(stem, index))
            _tile(buckets[tile], extent, staged, tiles[-1], metadata, _crs_of(schema.metadata or {}),
                  row_group_rows)
    rows = _rows(sources)
    if _rows([staged / f"{t}.parquet" for t in tiles]) != rows:  # never a row lost or doubled
        raise RuntimeError(f"{folder}: the tiles of {stem} do not hold its parts' {rows} echoes; nothing replaced")
    mark = {"sources": {p.name: p.stat().st_size for p in sources}, "tiles": tiles, "rows": rows}
    write_json(compact / f"{stem}.json", mark)
    return mark


def _marks(folder: Path, stems: list[str]) -> dict[str, dict]:
    """The inputs' marks that still hold: after the first rename all do; before it, each part they read must be
    in echoes/ at its size (a part changed since, and the input is staged again)."""
    marks = {}
    swapped = (folder / REPLACED).exists() or not (folder / STAGED).exists()
    for stem in stems:
        try:
            mark = json.loads((folder / COMPACT / f"{stem}.json").read_text())
            sizes = mark["sources"].items()
            if swapped or all((folder / ECHOES / name).stat().st_size == size for name, size in sizes):
                marks[stem] = mark
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return marks


def swap(folder: Path, marks: dict[str, dict]) -> None:
    """The staged tiles become echoes/ by two renames; the replaced parts go. Goes on from any point it was
    killed at."""
    echoes, staged, replaced = folder / ECHOES, folder / STAGED, folder / REPLACED
    if staged.is_dir():
        if not replaced.exists():
            read = {name for mark in marks.values() for name in mark["sources"]}
            left = sorted(p.name for p in echoes.iterdir() if p.name not in read) if echoes.is_dir() else []
            if left:  # rows the tiles do not hold: never dropped
                raise ValueError(f"{echoes}: holds {', '.join(left[:5])}, which no input's tiles were made from; "
                                 f"nothing replaced")
            if echoes.is_dir():
                echoes.rename(replaced)
        elif echoes.exists():
            raise ValueError(f"{folder}: both {echoes} and {replaced} exist: an earlier fwl compact was disturbed; "
                             f"look at them, keep one, and rerun")
        staged.rename(echoes)
    if replaced.exists():
        shutil.rmtree(replaced)


def _finish(folder: Path, tile_rows: int, marks: dict[str, dict]) -> dict:
    """run.json's file list as it now is, and what was compacted; then the staging goes."""
    summary = read_run(folder)
    compact = (folder / COMPACT).as_posix()
    summary["files"] = [f for f in list_outputs(folder) if not (folder / f).as_posix().startswith(compact + "/")]
    summary["compacted"] = {"tile_rows": tile_rows, "tiles": sum(len(m["tiles"]) for m in marks.values()),
                            "echoes": sum(m["rows"] for m in marks.values())}
    write_run_json(folder, summary)
    (folder / COMPACT).rename(folder / FINISHED)  # at once: a kill here leaves no half of the marks
    shutil.rmtree(folder / FINISHED)
    if (folder / PARTS).is_dir() and not any((folder / PARTS).iterdir()):
        (folder / PARTS).rmdir()
    return summary["compacted"]


def compact_run(folder: str | Path, tile_rows: int = TILE_ROWS, row_group_rows: int = TILE_ROW_GROUP_ROWS,
                say: Callable[[str], None] = lambda line: None) -> dict:
    """A finished run's echo parts -> spatial tiles in echoes/ (the module's steps); a rerun after a kill goes on
    from where it stopped. Refuses a folder that is not a finished run (IncompleteRunError, OutputFolderError),
    or one whose echoes/ holds what no input wrote. Returns run.json's "compacted": tiles and echoes."""
    if not isinstance(tile_rows, int) or tile_rows < 1:
        raise ValueError(f"--tile-rows must be a whole number >= 1, not {tile_rows}")
    if not isinstance(row_group_rows, int) or row_group_rows < 1:
        raise ValueError(f"--row-group-rows must be a whole number >= 1, not {row_group_rows}")
    folder = Path(folder).resolve()
    read_run(folder)  # a finished run, or IncompleteRunError naming why not
    earlier_run_files(folder)  # nothing in it that a run did not write
    stems = [e["stem"] for e in read_manifest(folder)["inputs"]]
    shutil.rmtree(folder / FINISHED, ignore_errors=True)
    if not (folder / ECHOES).is_dir() and not (folder / COMPACT).is_dir():
        raise ValueError(f"{folder}: has no echoes/ to compact (run with --formats including parquet)")
    marks = _marks(folder, stems)
    for stem in stems:
        if stem not in marks:
            (folder / STAGED).mkdir(parents=True, exist_ok=True)
            marks[stem] = stage_input(folder, stem, tile_rows, row_group_rows)
            say(f"fwl compact: {stem}: {len(marks[stem]['sources'])} files -> {len(marks[stem]['tiles'])} tiles, "
                f"{marks[stem]['rows']:,} echoes")
    swap(folder, marks)
    return _finish(folder, tile_rows, marks)
