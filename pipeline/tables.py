"""Arrow tables of decomposition results (what the command line and sinks write)."""

from __future__ import annotations

import functools
import json

import numpy as np
import pyarrow as pa

from fwcore.config import DecompositionConfig
from fwcore.records import MESSAGES, STATUS_REASONS, BatchDecomposition
from fwcore.filter import REJECT_REASONS

CONFIG_METADATA_KEY = b"fwlidar.config"
GEO_METADATA_KEY = b"geo"  # GeoParquet 1.1: https://geoparquet.org/releases/v1.1.0/
GEOMETRY_COLUMN = "geometry"
_WKB_POINT_Z = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8")])


def _with_config(table: pa.Table, config: DecompositionConfig, extra: dict[bytes, bytes] | None = None) -> pa.Table:
    return table.replace_schema_metadata({CONFIG_METADATA_KEY: json.dumps(config.to_dict()).encode(), **(extra or {})})


@functools.lru_cache(maxsize=64)
def file_crs_projjson(path: str) -> str | None:
    """The input's coordinate reference system as PROJJSON (fwcore.io.crs_wkt, LAS or PulseWaves, read with
    pyproj), or None."""
    import pyproj

    from fwcore.io import crs_wkt

    try:
        wkt = crs_wkt(path)
        return pyproj.CRS.from_wkt(wkt).to_json() if wkt else None
    except Exception:  # noqa: BLE001  unreadable or unknown CRS records: the CRS is unknown, not invented
        return None


def wkb_points(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> pa.Array:
    """ISO WKB Point Z per row (little-endian, type 1001); null where a coordinate is not finite."""
    n = len(x)
    records = np.empty(n, dtype=_WKB_POINT_Z)
    records["order"], records["type"] = 1, 1001
    records["x"], records["y"], records["z"] = x, y, z
    offsets = np.arange(n + 1, dtype=np.int32) * _WKB_POINT_Z.itemsize
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    validity = None if finite.all() else pa.py_buffer(np.packbits(finite, bitorder="little"))
    return pa.Array.from_buffers(pa.binary(), n, [validity, pa.py_buffer(offsets), pa.py_buffer(records.tobytes())],
                                 null_count=int(n - finite.sum()))


def geo_metadata(x: np.ndarray, y: np.ndarray, z: np.ndarray, crs_projjson: str | None) -> dict[bytes, bytes]:
    """GeoParquet 1.1 file metadata for the point geometry column; crs null means unknown (not CRS84)."""
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    column = {"encoding": "WKB", "geometry_types": ["Point Z"],
              "crs": json.loads(crs_projjson) if crs_projjson else None}
    if finite.any():
        column["bbox"] = [float(v) for v in (x[finite].min(), y[finite].min(), z[finite].min(),
                                             x[finite].max(), y[finite].max(), z[finite].max())]
    meta = {"version": "1.1.0", "primary_column": GEOMETRY_COLUMN, "columns": {GEOMETRY_COLUMN: column}}
    return {GEO_METADATA_KEY: json.dumps(meta).encode()}


def echo_table(waveform_id: np.ndarray, result: BatchDecomposition, config: DecompositionConfig) -> pa.Table:
    """One row per echo, spurious ones included; times and widths in samples, amplitudes in digitizer units."""
    counts = np.diff(result.echo_offsets)
    owner = result.echo_waveform
    echo_index = np.arange(owner.size) - result.echo_offsets[owner]
    reasons = np.array(REJECT_REASONS, dtype=object)[result.reject]
    table = pa.table({
        "waveform_id": pa.array(waveform_id[owner], pa.int64()),
        "echo_index": pa.array(echo_index, pa.int32()),
        "echo_count": pa.array(counts[owner], pa.int32()),
        "amplitude": result.amplitude,
        "time": result.position,
        "sigma": result.sigma,
        "alpha": result.alpha,
        "fwhm": result.fwhm,
        "energy": result.energy,
        "background": result.background[owner],
        "kept": pa.array(result.reject == 0),
        "reject_reason": pa.array(reasons.tolist(), pa.string()),
        "fit_error": result.fit_error[owner],
        "fit_error_raw": result.fit_error_raw[owner],
        "rmse": result.rmse[owner],
        "r2": result.r2[owner],
        "optimizer": pa.array([config.optimizer.value] * owner.size, pa.string()),
        "model": pa.array([config.model.value] * owner.size, pa.string()),
    })
    return _with_config(table, config)


def waveform_table(waveform_id: np.ndarray, result: BatchDecomposition, config: DecompositionConfig,
                   n_samples: np.ndarray) -> pa.Table:
    """One row per waveform, whether or not it was decomposed: none is dropped."""
    counts = np.diff(result.echo_offsets)
    owner = result.echo_waveform
    kept = np.bincount(owner[result.reject == 0], minlength=len(result))
    table = pa.table({
        "waveform_id": pa.array(waveform_id, pa.int64()),
        "status": pa.array([STATUS_REASONS[s] for s in result.status], pa.string()),
        "n_samples": pa.array(n_samples, pa.int32()),
        "noise_sigma": result.noise_sigma,
        "background": result.background,
        "fit_error": result.fit_error,
        "fit_error_raw": result.fit_error_raw,
        "rmse": result.rmse,
        "r2": result.r2,
        "n_echoes_initial": pa.array(result.n_echoes_initial, pa.int32()),
        "n_echoes_dropped": pa.array(result.n_echoes_dropped, pa.int32()),
        "n_echoes_added": pa.array(result.n_echoes_added, pa.int32()),
        "n_echoes": pa.array(counts, pa.int32()),
        "n_echoes_kept": pa.array(kept, pa.int32()),
        "model_evaluations": pa.array(result.nfev, pa.int64()),
        "nit": pa.array(result.nit, pa.int32()),
        "message": pa.array([MESSAGES[m] for m in result.message], pa.string()),
        "optimizer": pa.array([config.optimizer.value] * len(result), pa.string()),
        "model": pa.array([config.model.value] * len(result), pa.string()),
    })
    return _with_config(table, config)


def _strings(value: str, n: int) -> pa.Array:
    return pa.array([value] * n, pa.string())


RADIOMETRY_COLUMNS = ("range_m", "incidence_deg", "backscatter_cross_section_m2", "backscatter_coefficient",
                      "reflectance")


def _radiometry_columns(radiometry: dict[str, np.ndarray] | None, n: int) -> dict[str, pa.Array]:
    """fwcore.radiometry.echo_radiometry's columns, NaN as null; all null (and 'unavailable') without them."""
    if radiometry is None:
        radiometry = {**{c: np.full(n, np.nan) for c in RADIOMETRY_COLUMNS}, "radiometry": np.full(n, "unavailable")}
    columns = {c: pa.array(radiometry[c], pa.float64(), from_pandas=True) for c in RADIOMETRY_COLUMNS}
    columns["radiometry"] = pa.array(np.asarray(radiometry["radiometry"], dtype=object).tolist(), pa.string())
    return columns


def pulse_tables(source_file: str, pulses, result: BatchDecomposition, config: DecompositionConfig,
                 xyz: np.ndarray, ok: np.ndarray, radiometry: dict[str, np.ndarray] | None = None
                 ) -> tuple[pa.Table, pa.Table]:
    """Echo rows (kept and spurious, geolocated, with their radiometry) and pulse rows of the decomposed pulses
    `ok`."""
    from fwcore.model import sigma_to_time_unit

    counts = np.diff(result.echo_offsets)
    owner = result.echo_waveform
    echo_index = np.arange(owner.size) - result.echo_offsets[owner]
    spacing = pulses.sample_spacing_ps[owner]
    gain = pulses.digitizer_gain[owner]
    echoes = pa.table({
        "source_file": _strings(source_file, owner.size),
        "pulse_id": pa.array(pulses.pulse_id[owner], pa.int64()),
        "channel": pa.array(pulses.channels()[owner], pa.int16()),
        "segment": pa.array(pulses.segments()[owner], pa.int16()),
        "gps_time": pulses.gps_time[owner],
        "echo_index": pa.array(echo_index, pa.int32()),
        "echo_count": pa.array(counts[owner], pa.int32()),
        "time_ps": result.position * spacing,
        "amplitude": result.amplitude,
        "amplitude_volts": result.amplitude * gain,
        "sigma_ps": sigma_to_time_unit(result.sigma, result.alpha, spacing),
        "alpha": result.alpha,
        "fwhm_ps": result.fwhm * spacing,
        "energy": result.energy * spacing,
        "background": result.background[owner],
        **_radiometry_columns(radiometry, owner.size),
        "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
        GEOMETRY_COLUMN: wkb_points(xyz[:, 0], xyz[:, 1], xyz[:, 2]),
        "kept": pa.array(result.reject == 0),
        "reject_reason": pa.array(np.array(REJECT_REASONS, dtype=object)[result.reject].tolist(), pa.string()),
        "fit_error": result.fit_error[owner],
        "fit_error_raw": result.fit_error_raw[owner],
        "rmse": result.rmse[owner],
        "r2": result.r2[owner],
        "optimizer": _strings(config.optimizer.value, owner.size),
        "model": _strings(config.model.value, owner.size),
    })
    kept = np.bincount(owner[result.reject == 0], minlength=len(result))
    sel = np.flatnonzero(ok)
    table = pa.table({
        "source_file": _strings(source_file, sel.size),
        "pulse_id": pa.array(pulses.pulse_id[sel], pa.int64()),
        "channel": pa.array(pulses.channels()[sel], pa.int16()),
        "segment": pa.array(pulses.segments()[sel], pa.int16()),
        "packet_offset": pa.array(pulses.packet_offset[sel], pa.int64()),
        "gps_time": pulses.gps_time[sel],
        "n_samples": pa.array(np.diff(pulses.sample_offsets)[sel], pa.int32()),
        "sample_spacing_ps": pulses.sample_spacing_ps[sel],
        "noise_sigma": result.noise_sigma[sel],
        "background": result.background[sel],
        "background_volts": pulses.digitizer_offset[sel] + pulses.digitizer_gain[sel] * result.background[sel],
        "fit_error": result.fit_error[sel],
        "fit_error_raw": result.fit_error_raw[sel],
        "rmse": result.rmse[sel],
        "r2": result.r2[sel],
        "n_echoes_initial": pa.array(result.n_echoes_initial[sel], pa.int32()),
        "n_echoes_dropped": pa.array(result.n_echoes_dropped[sel], pa.int32()),
        "n_echoes_added": pa.array(result.n_echoes_added[sel], pa.int32()),
        "n_echoes": pa.array(counts[sel], pa.int32()),
        "n_echoes_kept": pa.array(kept[sel], pa.int32()),
        "model_evaluations": pa.array(result.nfev[sel], pa.int64()),
        "nit": pa.array(result.nit[sel], pa.int32()),
        "message": pa.array([MESSAGES[m] for m in result.message[sel]], pa.string()),
        "n_system_returns": pa.array(np.diff(pulses.return_offsets)[sel], pa.int32()),
        "system_pulse_fwhm_ps": np.full(sel.size, config.pulse_fwhm_ps()),
        "shape_tolerance": np.full(sel.size, config.shape_tolerance or 0.0),
        "optimizer": _strings(config.optimizer.value, sel.size),
        "model": _strings(config.model.value, sel.size),
    })
    geo = geo_metadata(xyz[:, 0], xyz[:, 1], xyz[:, 2], file_crs_projjson(str(pulses.source_file)))
    return _with_config(echoes, config, geo), _with_config(table, config)


REJECTED_SCHEMA = pa.schema([("source_file", pa.string()), ("pulse_id", pa.int64()), ("stage", pa.string()),
                             ("reason", pa.string())])


def rejected_table(rows) -> pa.Table:
    """Rejections (pipeline.records.Rejection) as rejected/'s rows."""
    return pa.table({c: [getattr(r, c) for r in rows] for c in REJECTED_SCHEMA.names}, schema=REJECTED_SCHEMA)


def empty_rejected_table() -> pa.Table:
    """rejected/ of an input without rejections: the schema and no rows, so that queries over rejected/ work."""
    return REJECTED_SCHEMA.empty_table()
