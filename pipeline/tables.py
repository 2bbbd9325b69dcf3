"""Arrow tables of decomposition results (what the command line and sinks write), each from one column
specification: a column's name, type, unit and meaning are written once (COLUMNS), the tables list their
columns by name (TABLES), and every written field carries its unit and meaning in its Parquet metadata. The
columns of the engine's per-waveform record take its fields by name (RECORD_COLUMNS).
"""

from __future__ import annotations

import dataclasses
import functools
import json

import numpy as np
import pyarrow as pa

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import SystemPulse
from fwcore.io.crs import crs_projjson
from fwcore.engine.records import WAVEFORM_CODES, WAVEFORM_FIELDS, BatchDecomposition
from fwcore.engine.filter import REJECT_REASONS
from fwcore.metrics.pulses import top_heights

CONFIG_METADATA_KEY = b"fwlidar.config"
PULSE_METADATA_KEY = b"fwlidar.pulse"  # the file's system pulse the rows were decomposed with
GEO_METADATA_KEY = b"geo"  # GeoParquet 1.1: https://geoparquet.org/releases/v1.1.0/
GEOMETRY_COLUMN = "geometry"
BBOX_COLUMN = "bbox"  # GeoParquet 1.1's bbox covering of the geometry: its row group statistics prune box queries
BBOX_FIELDS = ("xmin", "ymin", "xmax", "ymax")
BBOX_TYPE = pa.struct([(f, pa.float64()) for f in BBOX_FIELDS])
_WKB_POINT_Z = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8"), ("z", "<f8")])


def _with_config(table: pa.Table, config: DecompositionConfig, pulse: SystemPulse,
                 extra: dict[bytes, bytes] | None = None) -> pa.Table:
    """The table with the method it was decomposed with (its model the file's) and the file's pulse."""
    return table.replace_schema_metadata({**_method_metadata(config, pulse), **(extra or {})})


@functools.lru_cache(maxsize=16)
def _method_metadata(config: DecompositionConfig, pulse: SystemPulse) -> dict[bytes, bytes]:
    # once per file, not twice a range: the pulse's response as JSON cost ~1 ms a table
    method = config.replace(model=pulse.echo_model(config.model))
    return {CONFIG_METADATA_KEY: json.dumps(method.to_dict()).encode(),
            PULSE_METADATA_KEY: json.dumps(pulse.to_dict()).encode()}


@functools.lru_cache(maxsize=64)
def file_crs_projjson(path: str) -> str | None:
    """The input's coordinate reference system as PROJJSON (fwcore.io.crs_wkt, LAS or PulseWaves, read with
    pyproj), or None."""
    from fwcore.io import crs_wkt

    try:
        return crs_projjson(crs_wkt(path))
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


def bbox_points(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> pa.Array:
    """Each point's bbox covering (xmin = xmax = x, ymin = ymax = y); null where the geometry is null."""
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return pa.StructArray.from_arrays([pa.array(v) for v in (x, y, x, y)], fields=list(BBOX_TYPE),
                                      mask=pa.array(~finite))


def geo_metadata(x: np.ndarray, y: np.ndarray, z: np.ndarray, crs_projjson: str | None,
                 covering: bool = True) -> dict[bytes, bytes]:
    """GeoParquet 1.1 file metadata for the point geometry column; crs null means unknown (not CRS84);
    `covering` declares the table's bbox column (the echo table has one, the pulse table not)."""
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    column = {"encoding": "WKB", "geometry_types": ["Point Z"],
              "crs": json.loads(crs_projjson) if crs_projjson else None}
    if finite.any():
        column["bbox"] = [float(v) for v in (x[finite].min(), y[finite].min(), z[finite].min(),
                                             x[finite].max(), y[finite].max(), z[finite].max())]
    if covering:
        column["covering"] = {"bbox": {f: [BBOX_COLUMN, f] for f in BBOX_FIELDS}}
    meta = {"version": "1.1.0", "primary_column": GEOMETRY_COLUMN, "columns": {GEOMETRY_COLUMN: column}}
    return {GEO_METADATA_KEY: json.dumps(meta).encode()}


@dataclasses.dataclass(frozen=True)
class Column:
    """One output column: name, Arrow type, unit ("" for a name, a count or a flag) and meaning."""

    name: str
    type: pa.DataType
    unit: str
    meaning: str

    @property
    def field(self) -> pa.Field:
        return pa.field(self.name, self.type, metadata={b"unit": self.unit.encode(), b"description": self.meaning.encode()})


F64, I64, I32, I16, STR, BOOL = pa.float64(), pa.int64(), pa.int32(), pa.int16(), pa.string(), pa.bool_()
COLUMNS = {c.name: c for c in (
    Column("source_file", STR, "", "the input's file name"),
    Column("pulse_id", I64, "", "the pulse's identity: a hash of its GPS time and anchor, the same in every encoding "
                                "of the file"),
    Column("waveform_id", I64, "", "the waveform's id in the CSV input"),
    Column("channel", I16, "", "the PulseWaves sampling channel (LAS: 0)"),
    Column("segment", I16, "", "returning segments joined after the first in the waveform (PulseWaves; LAS: 0)"),
    Column("packet_offset", I64, "byte", "where the pulse's samples are: LAS packet offset, PulseWaves offset to waves"),
    Column("gps_time", F64, "s", "the pulse's GPS time as the input stores it (week seconds or adjusted standard)"),
    Column("echo_index", I32, "", "the echo's number in its waveform, in time order from 0, spurious ones included"),
    Column("echo_count", I32, "", "echoes fitted to the waveform, spurious ones included"),
    Column("time_ps", F64, "ps", "the echo's centre, from the packet's first sample"),
    Column("time", F64, "sample", "the echo's centre, from the waveform's first sample"),
    Column("amplitude", F64, "DN", "the echo's peak above the background, in digitizer counts"),
    Column("amplitude_volts", F64, "V", "amplitude times the descriptor's digitizer gain"),
    Column("sigma_chauve", F64, "ps^(alpha^2/2)", "Chauve's sigma: the echo is A exp(-|t - u|^(alpha^2) / (2 sigma^2)) "
                                                  "with t in ps; its unit depends on alpha; null under --model "
                                                  "system (echoes of the measured response)"),
    Column("sigma", F64, "sample^(alpha^2/2)", "Chauve's sigma with t in samples; under --model system the sigma "
                                               "(samples) of the Gaussian of the echo's FWHM"),
    Column("alpha", F64, "1", "the generalized Gaussian's shape: sqrt(2) a Gaussian, more a flatter top; null under "
                              "--model system"),
    Column("fwhm_ps", F64, "ps", "the echo's full width at half maximum"),
    Column("pulse_width_ps", F64, "ps", "the echo's full width at half maximum measured on the waveform (the samples "
                                        "less the background and the other echoes), as RIEGL's 'Pulse width': "
                                        "unlike fwhm_ps, never held at the system response's width; null where "
                                        "the echo has no half-maximum crossing in its record"),
    Column("fwhm", F64, "sample", "the echo's full width at half maximum"),
    Column("energy", F64, "DN ps", "the area under the echo"),
    Column("background", F64, "DN", "the waveform's background level"),
    Column("background_volts", F64, "V", "the background through the descriptor's gain and offset"),
    Column("range_m", F64, "m", "the echo's range to the scanner (null: no trajectory or scanner position)"),
    Column("incidence_deg", F64, "deg", "the angle between the beam and a plane through neighbouring kept echoes "
                                        "(null: no plane)"),
    Column("backscatter_cross_section_m2", F64, "m2", "sigma = C_cal R^4 E; relative (C_cal = 1) unless calibrated"),
    Column("backscatter_coefficient", F64, "1", "gamma = 4 sigma / (pi R^2 beta^2); relative unless calibrated"),
    Column("reflectance", F64, "1", "rho = gamma / (4 cos alpha), alpha 0 without a plane; relative unless calibrated"),
    Column("radiometry", STR, "", "calibrated | relative | unavailable: what the radiometric columns are"),
    Column("reflectance_basis", STR, "", "incidence | apparent: no plane | apparent: untrusted plane | null: no "
                                         "range, no energy or no beam divergence: what the reflectance is, or why none"),
    Column("x", F64, "CRS unit", "the echo's position in the input's CRS (at time_ps plus the file's range offset)"),
    Column("y", F64, "CRS unit", "as x"),
    Column("z", F64, "CRS unit", "as x"),
    Column(GEOMETRY_COLUMN, pa.binary(), "", "x, y, z as a WKB Point Z (GeoParquet 1.1)"),
    Column(BBOX_COLUMN, BBOX_TYPE, "CRS unit", "the geometry's bounding box (xmin = xmax = x, ymin = ymax = y), "
                                               "GeoParquet 1.1's covering: box queries read it"),
    Column("kept", BOOL, "", "false for a spurious echo"),
    Column("classification", pa.uint8(), "", "ASPRS class: 2 ground, 6 building, 3/4/5 low/medium/high vegetation, "
                                            "7 low noise, 1 unclassified (fwl classify; null before it)"),
    Column("height", F64, "m", "the echo's height above the terrain (fwl classify's; null before it)"),
    Column("reject_reason", STR, "", "why a spurious echo was set aside ('' when kept): weak, too_close, out_of_range, "
           "too_narrow, too_wide (the filter), under_ground (fwcore.plausibility)"),
    Column("status", STR, "", "'' when decomposed, else why not"),
    Column("n_samples", I32, "", "samples in the waveform"),
    Column("sample_spacing_ps", F64, "ps", "time between two samples"),
    Column("noise_sigma", F64, "DN", "the waveform's noise level"),
    Column("fit_error", F64, "DN", "the method's objective (Eq. 9): the sum of absolute residuals |model - denoised "
                                   "sample| over the waveform's valid samples"),
    Column("fit_error_raw", F64, "DN", "the sum of absolute residuals |model - raw sample| over the valid samples"),
    Column("rmse", F64, "DN", "root mean square residual against the raw (valid) samples"),
    Column("r2", F64, "1", "coefficient of determination against the raw (valid) samples"),
    Column("n_echoes_initial", I32, "", "echoes of the initial estimate"),
    Column("n_echoes_dropped", I32, "", "initial echoes the model-order selection dropped, or set aside unfitted beside one strong echo (strong_echo_fit)"),
    Column("n_echoes_added", I32, "", "echoes the model-order selection added"),
    Column("n_echoes", I32, "", "echoes fitted"),
    Column("n_echoes_kept", I32, "", "echoes kept"),
    Column("model_evaluations", I64, "", "evaluations of the model"),
    Column("nit", I32, "", "the optimizer's generations or iterations"),
    Column("message", STR, "", "how the optimizer ended"),
    Column("n_system_returns", I32, "", "the returns the input's system recorded for the pulse (LAS points)"),
    Column("system_pulse_fwhm_ps", F64, "ps", "the file's system pulse width the run used"),
    Column("shape_tolerance", F64, "1", "the model's relative shape error on the file's pulse"),
    Column("optimizer", STR, "", "the optimizer"),
    Column("model", STR, "", "the echo model"),
    Column("ground_z", F64, "CRS unit", "the ground's height: the waveform's lowest mode (GEDI L2A's elev_lowestmode; "
                                        "a small footprint's last kept echo unless --pulse-metrics full; null: see "
                                        "metrics_reason)"),
    Column("rh", pa.list_(pa.float32()), "m", "RH0..RH100: the height above the ground below which 0..100 % of "
                                                   "the waveform's energy lies (GEDI L2A), truncated to cm"),
    Column("rv", F64, "DN sample", "the canopy's energy: the waveform above the ground return, above the ground (L2B; "
                                   "a small footprint's: its kept echoes' above the ground echo)"),
    Column("rg", F64, "DN sample", "the ground's energy: the fitted ground return's area (L2B; a small footprint's: "
                                   "its ground echo's)"),
    Column("cover", F64, "1", "canopy cover: cos(zenith) (1 - Pgap), Pgap = 1 - rv / (rv + 1.5 rg) (GEDI L2B)"),
    Column("pai", F64, "m2/m2", "plant area index: -ln(Pgap) cos(zenith) / (0.5 x 1) (GEDI L2B)"),
    Column("pavd_z", pa.list_(pa.float32()), "m2/m3", "plant area volume density in 5 m bins from the ground up "
                                                      "(0-5, 5-10, ... m; GEDI L2B)"),
    Column("metrics_reason", STR, "", "'' when the forest metrics were measured, else why they are null"),
    Column("agbd", F64, "Mg/ha", "aboveground biomass density: GEDI L4A's model of the shot's stratum on its RH "
                                 "(fwcore.metrics.biomass; null: see agbd_reason)"),
    Column("agbd_se", F64, "Mg/ha", "agbd's standard error as L4A gives it (the model's coefficient covariance and "
                                    "residual error)"),
    Column("agbd_stratum", STR, "", "the L4A prediction stratum (plant functional type _ region, e.g. ENT_NAm) whose "
                                    "model gave agbd: from the L2A granule's land cover, else --stratum"),
    Column("agbd_reason", STR, "", "'' when agbd was predicted, else why it is null"),
    Column("agbd_algorithm", pa.int8(), "", "GEDI: the L2A algorithm whose RH gave agbd, as L4A chooses it (not "
                                            "always selected_algorithm; L4A's algorithm 10 is measured as 5: "
                                            "fwcore.metrics.l4a_algorithm; null: no agbd, or not GEDI)"),
    Column("selected_algorithm", pa.int8(), "", "GEDI: the L2A algorithm whose ground and RH are ground_z and rh (L2A's "
                                                "selected_algorithm where its granule lies beside the L1B; null: "
                                                "not GEDI)"),
    Column("mode_z", pa.list_(pa.float32()), "CRS unit", "the height of every mode the ground was chosen from, top to "
                                                         "bottom (GEDI: the selected algorithm's zcross modes; those "
                                                         "below ground_z were passed over; null: none measured)"),
    *(Column(f"ground_z_a{a}", F64, "CRS unit", f"GEDI L2A algorithm {a}'s ground (elev_lowestmode_a{a}); with "
                                                f"--l2a-algorithms all") for a in range(1, 7)),
    *(Column(f"rh_a{a}", pa.list_(pa.float32()), "m", f"GEDI L2A algorithm {a}'s RH0..RH100 (rh_a{a}); with "
                                                      f"--l2a-algorithms all") for a in range(1, 7)),
    Column("lfid", I64, "", "LVIS's file id (LFID) of the shot, to join LVIS's products (null: not LVIS)"),
    Column("shot_number", I64, "", "the mission's shot number (LVIS's SHOTNUMBER, GEDI's shot_number), to join its "
                                   "products (null: the file numbers no shots)"),
    Column("top_z", F64, "CRS unit", "the highest detected return: where the signal starts (LVIS's ZH, GEDI L2A's "
                                     "elev_highestreturn; null: see metrics_reason)"),
    Column("stale_return_flag", pa.int8(), "", "GEDI L1B's stale return flag (null: not recorded)"),
    Column("degrade_flag", pa.int8(), "", "GEDI L1B's degraded pointing or positioning flag (null: not recorded)"),
    Column("stage", STR, "", "the stage that rejected it: open | read | decompose | geolocate | write"),
    Column("reason", STR, "", "why"),
)}
CSV_ENERGY = Column("energy", F64, "DN sample", "the area under the echo")  # decompose-csv's tables are in samples
# pulses/ is GeoParquet too: a point per pulse where the file anchors its beam
PULSE_GEOMETRY = Column(GEOMETRY_COLUMN, pa.binary(), "", "the pulse's anchor as a WKB Point Z in the run's CRS "
                                                          "(GeoParquet 1.1): where the file places its beam (LAS: the "
                                                          "point its waveform is anchored to; PulseWaves: its anchor)")
_FIT = ("fit_error", "fit_error_raw", "rmse", "r2")
_COUNTS = ("n_echoes_initial", "n_echoes_dropped", "n_echoes_added", "n_echoes", "n_echoes_kept", "model_evaluations",
           "nit", "message")
_METHOD = ("optimizer", "model")
_FOREST = ("ground_z", "rh", "rv", "rg", "cover", "pai", "pavd_z", "metrics_reason")
_BIOMASS = ("agbd", "agbd_se", "agbd_stratum", "agbd_reason")
_L4A = ("agbd_algorithm",)  # which algorithm's RH L4A predicts from
_GEDI = ("selected_algorithm", "mode_z")
# written only with --l2a-algorithms all: appended after the table's own columns
EVERY_ALGORITHM = (*(f"ground_z_a{a}" for a in range(1, 7)), *(f"rh_a{a}" for a in range(1, 7)))
_SHOT = ("lfid", "shot_number", "top_z")  # the mission's shot ids and the signal's start: join its products
# Each table's columns, in order: the outputs of fwl run (echoes/, pulses/, rejected/) and of fwl decompose-csv.
TABLES = {
    "echoes": ("source_file", "pulse_id", "channel", "segment", "gps_time", "echo_index", "echo_count", "time_ps",
               "amplitude", "amplitude_volts", "sigma_chauve", "alpha", "fwhm_ps", "pulse_width_ps", "energy",
               "background",
               "range_m", "incidence_deg", "backscatter_cross_section_m2", "backscatter_coefficient", "reflectance",
               "radiometry", "reflectance_basis", "x", "y", "z", GEOMETRY_COLUMN, BBOX_COLUMN, "kept", "reject_reason", *_FIT, *_METHOD,
               "classification", "height"),
    "pulses": ("source_file", "pulse_id", "channel", "segment", "packet_offset", "gps_time", PULSE_GEOMETRY, "n_samples",
               "sample_spacing_ps", "noise_sigma", "background", "background_volts", *_FIT, *_COUNTS,
               "n_system_returns", "system_pulse_fwhm_ps", "shape_tolerance", *_METHOD, *_FOREST, *_SHOT, *_GEDI, *_BIOMASS, *_L4A,
               "stale_return_flag",
               "degrade_flag"),
    "rejected": ("source_file", "pulse_id", "stage", "reason"),
    "csv echoes": ("waveform_id", "echo_index", "echo_count", "amplitude", "time", "sigma", "alpha", "fwhm", CSV_ENERGY,
                   "background", "kept", "reject_reason", *_FIT, *_METHOD),
    "csv waveforms": ("waveform_id", "status", "n_samples", "noise_sigma", "background", *_FIT, *_COUNTS, *_METHOD),
}
_RENAMED = {"nfev": "model_evaluations"}  # record fields whose column name says more
# The columns that are fields of the engine's per-waveform record (fwcore.engine.records.WAVEFORM_RESULT), by column name:
# the tables take their values from the record by this map, and a test checks that their columns cover it.
RECORD_COLUMNS = {_RENAMED.get(f, f): f for f in WAVEFORM_FIELDS}


@functools.cache
def table_schema(table: str) -> pa.Schema:
    """A table's Arrow schema, each field with its unit and meaning."""
    return pa.schema([table_column(c).field for c in TABLES[table]])


def table_column(column: str | Column) -> Column:
    """A table's column: by name from COLUMNS, or its own where its unit differs (CSV_ENERGY)."""
    return COLUMNS[column] if isinstance(column, str) else column


def _table(table: str, values: dict) -> pa.Table:
    """A table from its columns' values (every column of its specification, no other)."""
    schema = table_schema(table)
    if set(values) != set(schema.names):
        raise ValueError(f"{table}: values for {sorted(set(values) ^ set(schema.names))} do not match its columns")
    return pa.table([v if isinstance(v, pa.Array) and v.type == f.type else pa.array(v, f.type)
                     for f, v in ((f, values[f.name]) for f in schema)], schema=schema)


def echo_table(waveform_id: np.ndarray, result: BatchDecomposition, config: DecompositionConfig,
               pulse: SystemPulse) -> pa.Table:
    """One row per echo, spurious ones included; times and widths in samples, amplitudes in digitizer units."""
    owner = result.echo_waveform
    table = _table("csv echoes", {
        "waveform_id": waveform_id[owner], "echo_index": np.arange(owner.size) - result.echo_offsets[owner],
        "echo_count": np.diff(result.echo_offsets)[owner], "amplitude": result.amplitude, "time": result.position,
        "sigma": result.sigma, "alpha": _null_where_nan(result.alpha), "fwhm": result.fwhm, "energy": result.energy,
        **_record_columns("csv echoes", result, owner), **_kept(result), **_method(config, pulse, owner.size)})
    return _with_config(table, config, pulse)


def waveform_table(waveform_id: np.ndarray, result: BatchDecomposition, config: DecompositionConfig,
                   pulse: SystemPulse, n_samples: np.ndarray) -> pa.Table:
    """One row per waveform, whether or not it was decomposed: none is dropped."""
    every = np.arange(len(result))
    table = _table("csv waveforms", {
        "waveform_id": waveform_id, "n_samples": n_samples, **_record_columns("csv waveforms", result, every),
        **_echo_counts(result, every), **_method(config, pulse, len(result))})
    return _with_config(table, config, pulse)


def _record_columns(table: str, result: BatchDecomposition, rows: np.ndarray) -> dict:
    """The table's columns of the per-waveform record (RECORD_COLUMNS) at rows, codes as their strings."""
    columns = {}
    for column in table_schema(table).names:
        field = RECORD_COLUMNS.get(column)
        if field in WAVEFORM_CODES:
            columns[column] = _coded_strings(WAVEFORM_CODES[field], result.per_waveform[field][rows])
        elif field is not None:
            columns[column] = result.per_waveform[field][rows]
    return columns


def _echo_counts(result: BatchDecomposition, rows: np.ndarray) -> dict:
    kept = np.bincount(result.echo_waveform[result.reject == 0], minlength=len(result))
    return {"n_echoes": np.diff(result.echo_offsets)[rows], "n_echoes_kept": kept[rows]}


def _kept(result: BatchDecomposition) -> dict:
    return {"kept": result.reject == 0,
            "reject_reason": _coded_strings(REJECT_REASONS, result.reject)}


def _method(config: DecompositionConfig, pulse: SystemPulse, n: int) -> dict:
    return {"optimizer": _strings(config.optimizer.value, n),
            "model": _strings(pulse.echo_model(config.model).value, n)}


def _null_where_nan(values: np.ndarray) -> pa.Array:
    """A float column whose NaN means 'does not apply' (a tabulated echo has no shape factor): null, so that no
    NaN reaches an output."""
    return pa.array(values, pa.float64(), from_pandas=True)


def _strings(value: str, n: int) -> pa.Array:
    return pa.repeat(pa.scalar(value, pa.string()), n)


def _coded_strings(names, codes: np.ndarray) -> pa.Array:
    """Each row's name by its code (a string column), taken in Arrow: no Python string a row."""
    return pa.array(names, pa.string()).take(pa.array(np.asarray(codes)))


RADIOMETRY_COLUMNS = ("range_m", "incidence_deg", "backscatter_cross_section_m2", "backscatter_coefficient",
                      "reflectance")


def _radiometry_columns(radiometry: dict[str, np.ndarray] | None, n: int) -> dict:
    """fwcore.radiometry.equations.echo_radiometry's columns, NaN as null; all null (and 'unavailable') without them."""
    if radiometry is None:
        radiometry = {**{c: np.full(n, np.nan) for c in RADIOMETRY_COLUMNS}, "radiometry": np.full(n, "unavailable"),
                      "reflectance_basis": np.full(n, "null: no range")}
    # NaN is null here: unavailable, not a number gone wrong
    return {**{c: _null_where_nan(radiometry[c]) for c in RADIOMETRY_COLUMNS},
            **{c: pa.array(np.asarray(radiometry[c]), pa.string()) for c in ("radiometry", "reflectance_basis")}}


def _float_lists(values: np.ndarray, column: str) -> pa.Array:
    """Per row a list of the row's values (float32), null where the row measured nothing (all NaN). A plain list,
    not a fixed-size one: Parquet reads a fixed-size list's null rows back as empty lists."""
    values = values.astype(np.float32)
    n, width = values.shape
    measured = np.isfinite(values).any(axis=1)
    return pa.ListArray.from_arrays(pa.array(np.arange(n + 1) * width, pa.int32()), pa.array(values.ravel()),
                                    type=COLUMNS[column].type, mask=None if measured.all() else pa.array(~measured))


def _forest_columns(metrics, rows: np.ndarray) -> dict:
    """fwcore.metrics.waveform.WaveformMetrics at rows, NaN as null; all null without them."""
    n = rows.size
    if metrics is None:
        return {**{c: pa.nulls(n, COLUMNS[c].type) for c in _FOREST if c != "metrics_reason"},
                "metrics_reason": _strings("not measured", n)}
    return {**{c: _null_where_nan(getattr(metrics, c)[rows]) for c in ("ground_z", "rv", "rg", "cover", "pai")},
            "rh": _float_lists(metrics.rh[rows], "rh"), "pavd_z": _float_lists(metrics.pavd_z[rows], "pavd_z"),
            "metrics_reason": pa.array(metrics.reason, pa.string()).take(pa.array(rows))}


def _biomass_columns(biomass, rows: np.ndarray) -> dict:
    """fwcore.metrics.biomass.ShotBiomass at rows, NaN as null; all null (with the reason) without it."""
    if biomass is None:
        return {"agbd": pa.nulls(rows.size, F64), "agbd_se": pa.nulls(rows.size, F64),
                "agbd_stratum": _strings("", rows.size), "agbd_reason": _strings("not predicted", rows.size),
                "agbd_algorithm": pa.nulls(rows.size, pa.int8())}
    return {"agbd": _null_where_nan(biomass.agbd[rows]), "agbd_se": _null_where_nan(biomass.agbd_se[rows]),
            "agbd_stratum": biomass.stratum[rows].tolist(), "agbd_reason": biomass.reason[rows].tolist(),
            "agbd_algorithm": _l4a_algorithm(biomass, rows)}


def _l4a_algorithm(biomass, rows: np.ndarray) -> pa.Array:
    """The algorithm whose RH gave each shot's agbd; null where none did (no agbd, or not GEDI)."""
    if biomass is None or biomass.algorithm is None:
        return pa.nulls(rows.size, pa.int8())
    algorithm = biomass.algorithm[rows]
    return pa.array(algorithm, pa.int8(), mask=(algorithm == 0) | ~np.isfinite(biomass.agbd[rows]))
def _gedi_columns(metrics, algorithms: np.ndarray | None, rows: np.ndarray) -> dict:
    """The selected L2A algorithm (GEDI; null for other sensors) and every mode's height (wherever the forest
    metrics were measured)."""
    return {"selected_algorithm": _flag(algorithms, rows),
            "mode_z": (pa.nulls(rows.size, COLUMNS["mode_z"].type) if metrics is None
                       else _ragged_lists(metrics.mode_z[rows], "mode_z"))}


def _ragged_lists(values: np.ndarray, column: str) -> pa.Array:
    """Per row its finite values as a list (float32): NaN padding dropped; null where it has none."""
    finite = np.isfinite(values)
    counts = finite.sum(axis=1)
    return pa.ListArray.from_arrays(pa.array(np.r_[0, np.cumsum(counts)], pa.int32()),
                                    pa.array(values[finite].astype(np.float32)), type=COLUMNS[column].type,
                                    mask=pa.array(counts == 0))


def with_every_algorithm(table: pa.Table, every: dict | None, rows: np.ndarray) -> pa.Table:
    """The pulses table with every L2A algorithm's ground and RH appended (--l2a-algorithms all)."""
    if not every:
        return table
    for a in range(1, 7):
        metrics = every.get(a)
        ground = _null_where_nan(metrics.ground_z[rows]) if metrics else pa.nulls(rows.size, F64)
        rh = _float_lists(metrics.rh[rows], f"rh_a{a}") if metrics else pa.nulls(rows.size, COLUMNS[f"rh_a{a}"].type)
        table = table.append_column(COLUMNS[f"ground_z_a{a}"].field, ground)
        table = table.append_column(COLUMNS[f"rh_a{a}"].field, rh)
    return table


def _shot_columns(pulses, metrics, rows: np.ndarray) -> dict:
    """The mission's shot ids (null where the file numbers none) and the signal start's height (null where the
    metrics were not measured)."""
    ids = {c: pa.nulls(rows.size, pa.int64()) if getattr(pulses, c) is None else pa.array(getattr(pulses, c)[rows],
                                                                                          pa.int64())
           for c in ("lfid", "shot_number")}
    top = np.full(rows.size, np.nan) if metrics is None else top_heights(pulses, metrics)[rows]
    return {**ids, "top_z": _null_where_nan(top)}


def _flag(values: np.ndarray | None, rows: np.ndarray) -> pa.Array:
    return pa.nulls(rows.size, pa.int8()) if values is None else pa.array(values[rows], pa.int8())


def pulse_tables(source_file: str, pulses, result: BatchDecomposition, config: DecompositionConfig,
                 pulse: SystemPulse, xyz: np.ndarray, ok: np.ndarray, radiometry: dict[str, np.ndarray] | None = None,
                 crs_wkt: str | None = None, metrics=None, algorithms: np.ndarray | None = None,
                 every: dict | None = None, biomass=None, model: np.ndarray | None = None) -> tuple[pa.Table, pa.Table]:
    """Echo rows (kept and spurious, geolocated, with their radiometry) and pulse rows of the decomposed pulses
    `ok`, with their forest metrics (fwcore.metrics) and biomass (fwcore.metrics.biomass) where given; the geometry's CRS is `crs_wkt` (the run's,
    fwcore.io.formats.input_crs), else the input file's; GEDI: each shot's L2A `algorithms` and, with
    --l2a-algorithms all, `every` algorithm's metrics. `model`: the fitted model at every sample where the caller
    has it (fwcore.engine.records.fitted_model; the echoes' widths are measured against it)."""
    from fwcore.engine.model import sigma_to_time_unit
    from fwcore.engine.waveform_width import waveform_widths

    owner = result.echo_waveform
    spacing = pulses.sample_spacing_ps[owner]
    echoes = _table("echoes", {
        "source_file": _strings(source_file, owner.size), "pulse_id": pulses.pulse_id[owner],
        "channel": pulses.channels()[owner], "segment": pulses.segments()[owner], "gps_time": pulses.gps_time[owner],
        "echo_index": np.arange(owner.size) - result.echo_offsets[owner],
        "echo_count": np.diff(result.echo_offsets)[owner], "time_ps": result.position * spacing,
        "amplitude": result.amplitude, "amplitude_volts": result.amplitude * pulses.digitizer_gain[owner],
        "sigma_chauve": _null_where_nan(sigma_to_time_unit(result.sigma, result.alpha, spacing)),
        "alpha": _null_where_nan(result.alpha),
        "fwhm_ps": result.fwhm * spacing,
        "pulse_width_ps": _null_where_nan(
            waveform_widths(pulses.samples, pulses.sample_offsets, result, model) * spacing),
        "energy": result.energy * spacing, **_record_columns("echoes", result, owner), **_radiometry_columns(radiometry, owner.size),
        "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], GEOMETRY_COLUMN: wkb_points(xyz[:, 0], xyz[:, 1], xyz[:, 2]),
        BBOX_COLUMN: bbox_points(xyz[:, 0], xyz[:, 1], xyz[:, 2]),
        **_kept(result), **_method(config, pulse, owner.size),
        "classification": pa.nulls(owner.size, pa.uint8()), "height": pa.nulls(owner.size, F64)})  # fwl classify's
    sel = np.flatnonzero(ok)
    table = _table("pulses", {
        "source_file": _strings(source_file, sel.size), "pulse_id": pulses.pulse_id[sel],
        "channel": pulses.channels()[sel], "segment": pulses.segments()[sel],
        "packet_offset": pulses.packet_offset[sel], "gps_time": pulses.gps_time[sel],
        GEOMETRY_COLUMN: wkb_points(*pulses.anchor[sel].T),
        "n_samples": np.diff(pulses.sample_offsets)[sel], "sample_spacing_ps": pulses.sample_spacing_ps[sel],
        "background_volts": pulses.digitizer_offset[sel] + pulses.digitizer_gain[sel] * result.background[sel],
        **_record_columns("pulses", result, sel), **_echo_counts(result, sel),
        "n_system_returns": np.diff(pulses.return_offsets)[sel],
        "system_pulse_fwhm_ps": np.full(sel.size, pulse.fwhm_ps),
        "shape_tolerance": np.full(sel.size, pulse.shape_tolerance), **_method(config, pulse, sel.size),
        **_forest_columns(metrics, sel), **_shot_columns(pulses, metrics, sel),
        **_gedi_columns(metrics, algorithms, sel), **_biomass_columns(biomass, sel), "stale_return_flag": _flag(pulses.stale_return_flag, sel),
        "degrade_flag": _flag(pulses.degrade_flag, sel)})
    projjson = crs_projjson(crs_wkt) if crs_wkt else file_crs_projjson(str(pulses.source_file))
    geo = geo_metadata(xyz[:, 0], xyz[:, 1], xyz[:, 2], projjson)
    anchors = geo_metadata(*pulses.anchor[sel].T, projjson, covering=False)
    table = with_every_algorithm(table, every, sel)
    return _with_config(echoes, config, pulse, geo), _with_config(table, config, pulse, anchors)


REJECTED_SCHEMA = table_schema("rejected")


def rejected_table(rows) -> pa.Table:
    """Rejections (pipeline.records.Rejection) as rejected/'s rows."""
    return pa.table({c: [getattr(r, c) for r in rows] for c in REJECTED_SCHEMA.names}, schema=REJECTED_SCHEMA)


def empty_rejected_table() -> pa.Table:
    """rejected/ of an input without rejections: the schema and no rows, so that queries over rejected/ work."""
    return REJECTED_SCHEMA.empty_table()
