"""DuckDB queries over a run's Parquet tables: only what one view needs ever leaves the files.

The map and the 3D view ask for the echoes inside a box, at most `limit` of
them: a deterministic sample (by a hash of pulse and echo) that gets denser
as the box shrinks, so a run of millions of echoes stays responsive.
"""

from __future__ import annotations

import functools
import json
import threading
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.parquet as pq

from pipeline.layout import ECHOES, PULSES, REJECTED, RUN_JSON
from pipeline.view.frame import Frame, of_crs

# the page's colour choices -> echo table columns
COLOUR_COLUMNS = {"height": "z", "amplitude": "amplitude", "width": "fwhm_ps", "fit_error": "fit_error",
                  "reflectance": "reflectance", "range": "range_m"}
COLOUR_UNITS = {"height": "m", "amplitude": "DN", "width": "ns", "fit_error": "", "reflectance": "", "range": "m"}
HISTOGRAM_BINS = 40
COLOUR_SQL = {"width": "fwhm_ps / 1000.0"}  # the width in ns, as the pulse view shows times

_local = threading.local()
_database = duckdb.connect()
_database_lock = threading.Lock()


def _connection() -> duckdb.DuckDBPyConnection:
    """One cursor per server thread on one shared in-memory database (a cursor is cheap; a database is not)."""
    if not hasattr(_local, "con"):
        with _database_lock:
            _local.con = _database.cursor()
    return _local.con


def _table(run: Path, name: str, filename: bool = False) -> str | None:
    """The run's part files of one table as a DuckDB table expression (with each row's file, if asked)."""
    files = sorted((run / name).glob("*.parquet"))
    if not files:
        return None
    quoted = ", ".join("'" + str(f).replace("'", "''") + "'" for f in files)
    return f"read_parquet([{quoted}], union_by_name=true{', filename=true' if filename else ''})"


def _query(sql: str, params: list | None = None) -> dict[str, np.ndarray]:
    return _connection().execute(sql, params or []).fetchnumpy()


def _crs_of(run: Path):
    """The pyproj CRS of the run's echo table (its GeoParquet metadata), None when the input named none."""
    files = sorted((run / ECHOES).glob("*.parquet"))
    if not files:
        return None
    meta = pq.read_schema(files[0]).metadata or {}
    geo = json.loads(meta.get(b"geo", b"{}") or b"{}")
    crs = (geo.get("columns", {}).get(geo.get("primary_column", "geometry"), {}) or {}).get("crs")
    if not crs:
        return None
    import pyproj
    try:
        return pyproj.CRS.from_json_dict(crs)
    except pyproj.exceptions.CRSError:
        return None


def frame(run: Path) -> Frame:
    return _frame(run, (run / RUN_JSON).stat().st_mtime_ns if (run / RUN_JSON).exists() else 0)


@functools.lru_cache(maxsize=64)
def _frame(run: Path, _mtime: int) -> Frame:
    crs = _crs_of(run)
    local = crs is not None and (crs.is_geocentric or crs.is_geographic)  # a frame about the run's centre
    return of_crs(crs, _raw_bounds(run) if local else None)


def _raw_bounds(run: Path) -> dict | None:
    echoes = _table(run, ECHOES)
    if echoes is None:
        return None
    r = _connection().execute(f"SELECT min(x), max(x), min(y), max(y), min(z), max(z), count(*) "
                              f"FROM {echoes}").fetchone()
    return {"x": [r[0], r[1]], "y": [r[2], r[3]], "z": [r[4], r[5]], "echoes": int(r[6])} if r[6] else None


def bounds(run: Path) -> dict[str, list[float]] | None:
    """The echoes' extent in the map's frame."""
    echoes = _table(run, ECHOES)
    if echoes is None:
        return None
    fx, fy, fz = frame(run).sql()
    r = _connection().execute(f"SELECT min({fx}), max({fx}), min({fy}), max({fy}), min({fz}), max({fz}), count(*) "
                              f"FROM {echoes} WHERE x IS NOT NULL").fetchone()
    if not r[6]:
        return None
    return {"x": [r[0], r[1]], "y": [r[2], r[3]], "z": [r[4], r[5]], "echoes": int(r[6])}


def source_files(run: Path) -> list[str]:
    pulses = _table(run, PULSES)
    if pulses is None:
        return []
    return [r[0] for r in _connection().execute(f"SELECT DISTINCT source_file FROM {pulses} ORDER BY 1").fetchall()]


def colours(run: Path) -> dict[str, str | None]:
    """Each colour mode: None where the run's echoes have the column with values, else why not."""
    return _colours(run, (run / RUN_JSON).stat().st_mtime_ns if (run / RUN_JSON).exists() else 0)


@functools.lru_cache(maxsize=64)
def _colours(run: Path, _mtime: int) -> dict[str, str | None]:
    echoes = _table(run, ECHOES)
    if echoes is None:
        return {c: "the run has no echoes" for c in COLOUR_COLUMNS}
    columns = {r[0] for r in _connection().execute(f"DESCRIBE SELECT * FROM {echoes}").fetchall()}
    out = {}
    for colour, column in COLOUR_COLUMNS.items():
        if column not in columns:
            out[colour] = f"the run's echo table has no {column} column"
            continue
        n = _connection().execute(f"SELECT count(*) FROM {echoes} "
                                  f"WHERE isfinite(CAST({column} AS DOUBLE))").fetchone()[0]
        why = " (the run computed no radiometry for its inputs)" if colour in ("reflectance", "range") else ""
        out[colour] = None if n else f"the run has no {column} values{why}"
    return out


def _floats(values) -> np.ndarray:
    """A query's column as floats, NULL as NaN (DuckDB gives masked or object arrays where there are NULLs)."""
    if isinstance(values, np.ma.MaskedArray):
        return np.ma.filled(values.astype(float), np.nan)
    if values.dtype == object:
        return np.array([np.nan if v is None else float(v) for v in values], dtype=float)
    return values.astype(float)


def colour_range(values: np.ndarray) -> dict:
    """The colour scale: the 2nd to 98th percentile of the finite values, and how many lie outside it."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return {"cmin": None, "cmax": None, "below": 0, "above": 0}
    lo, hi = (float(v) for v in np.percentile(finite, [2, 98]))
    return {"cmin": lo, "cmax": hi, "below": int((finite < lo).sum()), "above": int((finite > hi).sum())}


def echoes_in_box(run: Path, colour: str, box: tuple[float, float, float, float] | None, limit: int,
                  kept_only: bool = False) -> dict:
    """Up to `limit` echoes inside box (xmin, xmax, ymin, ymax of the map's frame), their colour value, kept
    flag and pulse."""
    if colour not in COLOUR_COLUMNS:
        raise ValueError(f"colour must be one of {', '.join(COLOUR_COLUMNS)}, not {colour!r}")
    return _echoes_in_box(run, colour, box, limit, kept_only)


def _echoes_in_box(run: Path, colour: str, box, limit: int, kept_only: bool) -> dict:
    echoes = _table(run, ECHOES)
    files = source_files(run)
    unavailable = colours(run)[colour]
    view = frame(run)
    if echoes is None:
        return {"total": 0, "files": files, "x": [], "y": [], "z": [], "value": [], "kept": [], "file": [],
                "pulse_id": [], "frame": view.describe(), "unavailable": unavailable, **colour_range(np.zeros(0))}
    fx, fy, fz = view.sql()
    where, params = ["x IS NOT NULL AND y IS NOT NULL AND z IS NOT NULL"], []
    if box is not None:
        where.append(f"{fx} BETWEEN ? AND ? AND {fy} BETWEEN ? AND ?")
        params += list(box)
    if kept_only:
        where.append("kept")
    condition = " AND ".join(where)
    value = "NULL" if unavailable else COLOUR_SQL.get(colour, COLOUR_COLUMNS[colour])
    total = _connection().execute(f"SELECT count(*) FROM {echoes} WHERE {condition}", params).fetchone()[0]
    rows = _query(f"SELECT {fx} AS x, {fy} AS y, {fz} AS z, CAST({value} AS DOUBLE) AS value, kept, source_file, "
                  f"pulse_id FROM {echoes} WHERE {condition} "
                  f"ORDER BY hash(source_file, pulse_id, echo_index) LIMIT ?", params + [int(limit)])
    index = {name: i for i, name in enumerate(files)}
    values = _floats(rows["value"])
    # millimetres and float32 colour values: what a screen shows, in half the bytes
    return {"total": int(total), "files": files, "frame": view.describe(), "unavailable": unavailable,
            "unit": COLOUR_UNITS[colour], **colour_range(values),
            **{c: np.round(_floats(rows[c]), 3) for c in ("x", "y", "z")},
            "value": values.astype(np.float32).astype(float), "kept": rows["kept"],
            "file": np.array([index[s] for s in rows["source_file"]], dtype=np.int32),
            "pulse_id": rows["pulse_id"].astype(str)}  # ids as their digits: beyond 2^53 a page's number rounds


def pulse_echoes(run: Path, source_file: str, pulse_id: int) -> list[dict]:
    """The echo table's rows of one pulse, in echo order."""
    echoes = _table(run, ECHOES)
    if echoes is None:
        return []
    cur = _connection().execute(f"SELECT * FROM {echoes} WHERE source_file = ? AND pulse_id = ? "
                                f"ORDER BY echo_index", [source_file, int(pulse_id)])
    names = [d[0] for d in cur.description]
    # the GeoParquet geometry (WKB bytes) and its bbox covering repeat x, y, z
    return [{k: v for k, v in zip(names, row) if k not in ("geometry", "bbox")} for row in cur.fetchall()]


def pulse_row(run: Path, source_file: str, pulse_id: int) -> tuple[dict, str] | None:
    """The pulse table's row of one pulse and the part file that holds it."""
    pulses = _table(run, PULSES, filename=True)
    if pulses is None:
        return None
    cur = _connection().execute(f"SELECT * FROM {pulses} WHERE source_file = ? AND pulse_id = ? LIMIT 1",
                                [source_file, int(pulse_id)])
    row = cur.fetchone()
    if row is None:
        return None
    values = dict(zip([d[0] for d in cur.description], row))
    values.pop("geometry", None)  # the anchor as WKB bytes: no JSON (the viewer reads the anchor from the file)
    return values, values.pop("filename")


def first_pulse(run: Path) -> tuple[str, int] | None:
    """The pulse with the most echoes (the first such in file order): a telling one to show first."""
    pulses = _table(run, PULSES)
    if pulses is None:
        return None
    row = _connection().execute(f"SELECT source_file, pulse_id FROM {pulses} "
                                f"ORDER BY n_echoes DESC, source_file, gps_time LIMIT 1").fetchone()
    return (row[0], int(row[1])) if row else None


def rejected(run: Path, limit: int = 500) -> dict:
    """The rejected pulses (first `limit`) and how many of each reason."""
    table = _table(run, REJECTED)
    if table is None:
        return {"total": 0, "reasons": [], "rows": []}
    con = _connection()
    total = con.execute(f"SELECT count(*) FROM {table}").fetchone()[0]
    # reasons name byte offsets and sizes: grouped with the numbers as N, one row per kind of failure
    reasons = con.execute(f"SELECT stage, regexp_replace(reason, '[0-9]+', 'N', 'g') AS kind, count(*) AS n "
                          f"FROM {table} GROUP BY 1, 2 ORDER BY n DESC, 1, 2").fetchall()
    rows = con.execute(f"SELECT source_file, pulse_id, stage, reason FROM {table} "
                       f"ORDER BY source_file, pulse_id LIMIT ?", [limit]).fetchall()
    return {"total": int(total),
            "reasons": [{"stage": s, "reason": r, "count": int(n)} for s, r, n in reasons],
            "rows": [{"source_file": f, "pulse_id": int(p), "stage": s, "reason": r} for f, p, s, r in rows]}


def _histogram(values: np.ndarray, integer: bool = False) -> dict:
    values = values[np.isfinite(values)] if values.size else values
    if values.size == 0:
        return {"edges": [], "counts": []}
    if integer:
        edges = np.arange(values.min(), values.max() + 2) - 0.5
    else:
        edges = np.histogram_bin_edges(values, HISTOGRAM_BINS)
    counts, edges = np.histogram(values, edges)
    return {"edges": edges, "counts": counts}


def distributions(run: Path) -> dict:
    """Echoes per pulse (all and kept), fit error per pulse, amplitude per echo (kept and spurious)."""
    pulses, echoes = _table(run, PULSES), _table(run, ECHOES)
    out = {}
    if pulses is not None:
        p = _query(f"SELECT n_echoes, n_echoes_kept, fit_error FROM {pulses}")
        out["echoes_per_pulse"] = _histogram(p["n_echoes"].astype(float), integer=True)
        out["kept_echoes_per_pulse"] = _histogram(p["n_echoes_kept"].astype(float), integer=True)
        out["fit_error"] = _histogram(p["fit_error"].astype(float))
    if echoes is not None:
        e = _query(f"SELECT amplitude, kept FROM {echoes}")
        amplitude, kept = e["amplitude"].astype(float), e["kept"].astype(bool)
        finite = np.isfinite(amplitude)
        if finite.any():  # one set of bins for both, so the bars compare
            edges = np.histogram_bin_edges(amplitude[finite], HISTOGRAM_BINS)
            for name, sel in (("amplitude_kept", kept), ("amplitude_spurious", ~kept)):
                counts, _ = np.histogram(amplitude[sel & finite], edges)
                out[name] = {"edges": edges, "counts": counts}
    return out


PULSE_ORDERS = {"kept": "n_echoes_kept DESC, n_echoes ASC", "echoes": "n_echoes DESC",
                "spurious": "n_echoes - n_echoes_kept DESC", "fit_error": "r2 ASC NULLS LAST"}


def pulse_list(run: Path, order: str, limit: int) -> list[dict]:
    """The pulses worth a look first: most kept echoes, most echoes, most spurious, or the worst fits (lowest R²)."""
    if order not in PULSE_ORDERS:
        raise ValueError(f"order must be one of {', '.join(PULSE_ORDERS)}, not {order!r}")
    pulses = _table(run, PULSES)
    if pulses is None:
        return []
    cur = _connection().execute(f"SELECT source_file, pulse_id, n_echoes, n_echoes_kept, fit_error, r2 FROM {pulses} "
                                f"ORDER BY {PULSE_ORDERS[order]}, source_file, gps_time LIMIT ?", [int(limit)])
    names = [d[0] for d in cur.description]
    return [dict(zip(names, row)) for row in cur.fetchall()]


def gps_time_range(run: Path, source_file: str) -> tuple[float, float] | None:
    pulses = _table(run, PULSES)
    if pulses is None:
        return None
    lo, hi = _connection().execute(f"SELECT min(gps_time), max(gps_time) FROM {pulses} WHERE source_file = ?",
                                   [source_file]).fetchone()
    return None if lo is None else (float(lo), float(hi))
