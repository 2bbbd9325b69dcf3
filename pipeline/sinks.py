"""Writing the outputs in bounded memory: part files per range, then per-file outputs assembled by streaming.

Every range is written by the worker that decomposed it: Parquet parts under
echoes/ and pulses/, and a LAS part and an MCAP part under parts/. Assembling
a file's las/<stem>.las and mcap/<stem>.mcap reads its parts in range order,
one at a time, into laspy's chunked writer and MCAP's writer; no step ever
holds more than a range. Every file is written under a temporary name and
renamed, so a reader never sees half a file and a retry overwrites.
"""

from __future__ import annotations

import json
import os
from datetime import datetime, timezone
from pathlib import Path

import laspy
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

POINTS_PER_CLOUD_MESSAGE = 200  # consecutive pulses per foxglove.PointCloud message
LAS_CHUNK_POINTS = 500_000  # points per read while a part is copied into its file's point cloud

# GPS time -> UTC: the GPS epoch on the Unix clock, and the leap seconds GPS time has gained since then.
GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00:00Z
LEAP_SECONDS = tuple((int(datetime(*day, tzinfo=timezone.utc).timestamp()) - GPS_EPOCH_UNIX_S + n, n)
                     for n, day in enumerate(((1981, 7, 1), (1982, 7, 1), (1983, 7, 1), (1985, 7, 1), (1988, 1, 1),
                                              (1990, 1, 1), (1991, 1, 1), (1992, 7, 1), (1993, 7, 1), (1994, 7, 1),
                                              (1996, 1, 1), (1997, 7, 1), (1999, 1, 1), (2006, 1, 1), (2009, 1, 1),
                                              (2012, 7, 1), (2015, 7, 1), (2017, 1, 1)), start=1))
TIME_STAMP_UTC = "UTC nanoseconds since 1970 (from the file's adjusted standard GPS time)"
TIME_STAMP_WEEK = ("GPS seconds of the week, as nanoseconds (the file records no week: "
                   "viewers show these as the first week of 1970)")


def temporary_path(path: Path) -> Path:
    """Where `path` is written before it is renamed into place (its folder made): a reader never sees half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(path.name + ".tmp")


def write_part(table: pa.Table, directory: Path, name: str, **write_options) -> Path:
    """One deterministic part file per range: reruns and retries overwrite, never duplicate (`write_options`:
    pyarrow.parquet.write_table's)."""
    path = directory / f"{name}.parquet"
    tmp = temporary_path(path)
    pq.write_table(table, tmp, **write_options)
    tmp.replace(path)
    return path


def write_json(path: Path, value: dict) -> Path:
    tmp = temporary_path(path)
    tmp.write_text(json.dumps(value))
    tmp.replace(path)
    return path


# ---------------------------------------------------------------- time stamps

def stamp_ns(gps_time: float, adjusted_standard: bool) -> int:
    """An MCAP log time for a LAS gps_time: UTC ns for adjusted standard GPS time (GPS seconds - 1e9);
    week seconds as ns otherwise (the week is not in the file)."""
    if not adjusted_standard:
        return int(round(gps_time * 1e9))
    gps = gps_time + 1e9
    leap = 0
    for since, n in LEAP_SECONDS:
        if gps >= since:
            leap = n
    return int(round((gps + GPS_EPOCH_UNIX_S - leap) * 1e9))


# ---------------------------------------------------------------- LAS

class ExtraBytesRanges:
    """Each Extra Bytes dimension's lowest and highest value over all the points seen (NaN ignored), set on a
    header's Extra Bytes record: laspy's running statistics depend on how the points were split into parts."""

    def __init__(self, header):
        self.names = list(header.point_format.extra_dimension_names)
        self.low = {name: np.inf for name in self.names}
        self.high = {name: -np.inf for name in self.names}

    def add(self, points) -> None:
        for name in self.names:
            values = np.asarray(points[name])
            values = values[~np.isnan(values)] if values.dtype.kind == "f" else values
            if values.size:
                self.low[name] = min(self.low[name], float(values.min()))
                self.high[name] = max(self.high[name], float(values.max()))

    def set_on(self, vlrs) -> None:
        for struct in vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs if self.names else ():
            name = struct.name.rstrip(b"\0").decode()
            if name in self.low and struct.min_is_relevant() and struct.max_is_relevant():
                if np.isfinite(self.low[name]):
                    struct._raw_min()[:] = self.low[name]
                    struct._raw_max()[:] = self.high[name]
                elif struct._long_type() == np.float64:  # a column without a value (radiometry unavailable)
                    struct._raw_min()[:] = struct._raw_max()[:] = np.nan
                else:  # an integer column without a value (a file whose points were all rejected): no min/max
                    struct.options &= ~(struct.MIN_BIT_MASK | struct.MAX_BIT_MASK)


def assemble_las(parts: list[Path], path: Path, laz: bool = False) -> Path:
    """One point cloud from its range parts, in the order given, one chunk of one part at a time.

    The header (scales, offsets, CRS, Extra Bytes) is the first part's; laspy's writer recomputes the
    counts and bounds, so the file does not depend on how the points were split into parts.
    """
    with laspy.open(parts[0]) as first:
        header = first.header
    ranges = ExtraBytesRanges(header)
    tmp = temporary_path(path)
    with laspy.open(tmp, mode="w", header=header, do_compress=laz) as writer:
        for part in parts:
            with laspy.open(part) as reader:
                for chunk in reader.chunk_iterator(LAS_CHUNK_POINTS):
                    writer.write_points(chunk)
                    ranges.add(chunk)
        ranges.set_on(writer.header.vlrs)
    tmp.replace(path)
    return path


# ---------------------------------------------------------------- MCAP

def _point_cloud_message(cloud: dict[str, np.ndarray], rows: np.ndarray, ns: int):
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp

    names = ("x", "y", "z", "amplitude", "fwhm", "echo_index")
    # float32 around an origin kept in the pose: projected coordinates need more than float32 alone
    origin = np.floor([cloud["x"][rows].min(), cloud["y"][rows].min(), cloud["z"][rows].min()])
    values = np.stack([cloud["x"][rows] - origin[0], cloud["y"][rows] - origin[1], cloud["z"][rows] - origin[2],
                       cloud["amplitude"][rows], cloud["echo_width"][rows], cloud["return_number"][rows]], axis=1)
    return PointCloud(
        timestamp=Timestamp(seconds=ns // 10**9, nanos=ns % 10**9), frame_id="world",
        pose=Pose(position=Vector3(x=origin[0], y=origin[1], z=origin[2]), orientation=Quaternion(w=1.0)),
        point_stride=4 * len(names),
        fields=[PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32) for i, n in enumerate(names)],
        data=values.astype("<f4").tobytes())


_NUMBERS = {"type": "array", "items": {"type": "number"}}
WAVEFORM_SCHEMA = {
    "type": "object",
    "properties": {
        "pulse_id": {"type": "integer", "description": "the pulse's identity, as in the tables"},
        "gps_time": {"type": "number", "description": "the point records' gps_time, as in the file"},
        "time_ps": {**_NUMBERS, "description": "each sample's time after the first, ps"},
        "raw": {**_NUMBERS, "description": "the digitized samples"},
        "model": {**_NUMBERS, "description": "the fitted model at each sample"},
        "echoes": {"type": "array", "items": {
            "type": "object",
            "properties": {"time_ps": {"type": "number"}, "amplitude": {"type": "number"},
                           "fwhm_ps": {"type": "number"}, "kept": {"type": "boolean"},
                           "reject_reason": {"type": "string"}}}},
    },
}


def _waveform_message(v: dict[str, np.ndarray], i: int) -> bytes:
    from fwcore.engine.filter import REJECT_REASONS

    lo, hi = v["sample_offsets"][i], v["sample_offsets"][i + 1]
    e_lo, e_hi = v["echo_offsets"][i], v["echo_offsets"][i + 1]
    return json.dumps({
        "pulse_id": int(v["pulse_id"][i]), "gps_time": float(v["gps_time"][i]),
        "time_ps": (np.arange(hi - lo) * float(v["sample_spacing_ps"][i])).tolist(),
        "raw": v["raw"][lo:hi].tolist(), "model": np.round(v["model"][lo:hi], 3).tolist(),
        "echoes": [{"time_ps": float(t), "amplitude": float(a), "fwhm_ps": float(f), "kept": not r,
                    "reject_reason": REJECT_REASONS[r]}
                   for t, a, f, r in zip(v["echo_time_ps"][e_lo:e_hi], v["echo_amplitude"][e_lo:e_hi],
                                         v["echo_fwhm_ps"][e_lo:e_hi], v["echo_reject"][e_lo:e_hi])],
    }).encode()


CRS_METADATA = "crs"  # the MCAP metadata record (and /echoes channel metadata key) of the points' CRS


class _McapFile:
    """An MCAP writer with the /echoes and /waveform channels registered, and the points' CRS (OGC WKT) in a
    metadata record and the /echoes channel's metadata."""

    def __init__(self, f, adjusted_standard: bool, crs_wkt: str | None = None):
        from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
        from mcap.writer import Writer
        from mcap_protobuf.schema import register_schema

        self.writer = Writer(f)
        self.writer.start(profile="", library="fwlidar")
        meta = {"log_time": TIME_STAMP_UTC if adjusted_standard else TIME_STAMP_WEEK}
        crs = {CRS_METADATA: crs_wkt} if crs_wkt else {}
        if crs:
            self.writer.add_metadata(CRS_METADATA, {"wkt": crs_wkt})
        self.channels = {
            "/echoes": self.writer.register_channel("/echoes", "protobuf", register_schema(self.writer, PointCloud),
                                                    metadata={**meta, **crs}),
            "/waveform": self.writer.register_channel(
                "/waveform", "json",
                self.writer.register_schema("fwlidar.Waveform", "jsonschema", json.dumps(WAVEFORM_SCHEMA).encode()),
                metadata=meta),
        }

    def add(self, topic: str, ns: int, data: bytes) -> None:
        self.writer.add_message(self.channels[topic], log_time=ns, data=data, publish_time=ns)


def write_mcap(path: Path, cloud: dict[str, np.ndarray], views: dict[str, np.ndarray],
               adjusted_standard: bool, crs_wkt: str | None = None) -> Path:
    """One range's kept echoes as foxglove.PointCloud messages on /echoes (chunks of consecutive pulses)
    and each pulse's raw waveform, fitted model and echoes as JSON on /waveform, in pulse order; their CRS
    as _McapFile says."""
    tmp = temporary_path(path)
    with open(tmp, "wb") as f:
        out = _McapFile(f, adjusted_standard, crs_wkt)
        pulse_of_echo = cloud["pulse_id"]
        if pulse_of_echo.size:
            starts = np.flatnonzero(np.r_[True, pulse_of_echo[1:] != pulse_of_echo[:-1]])
            for chunk in range(0, starts.size, POINTS_PER_CLOUD_MESSAGE):
                lo = starts[chunk]
                hi = starts[chunk + POINTS_PER_CLOUD_MESSAGE] if chunk + POINTS_PER_CLOUD_MESSAGE < starts.size \
                    else pulse_of_echo.size
                ns = stamp_ns(float(cloud["gps_time"][lo]), adjusted_standard)
                out.add("/echoes", ns, _point_cloud_message(cloud, np.arange(lo, hi), ns).SerializeToString())
        for i in range(views["pulse_id"].size):
            out.add("/waveform", stamp_ns(float(views["gps_time"][i]), adjusted_standard), _waveform_message(views, i))
        out.writer.finish()
    tmp.replace(path)
    return path


def assemble_mcap(parts: list[Path], path: Path, adjusted_standard: bool) -> Path:
    """One MCAP from its range parts, in the order given, message by message; the CRS the first part says."""
    from mcap.reader import make_reader

    with open(parts[0], "rb") as p:
        crs = next((m.metadata.get("wkt") for m in make_reader(p).iter_metadata() if m.name == CRS_METADATA), None)
    tmp = temporary_path(path)
    with open(tmp, "wb") as f:
        out = _McapFile(f, adjusted_standard, crs)
        for part in parts:
            with open(part, "rb") as p:
                for _, channel, message in make_reader(p).iter_messages(log_time_order=False):
                    out.add(channel.topic, message.log_time, message.data)
        out.writer.finish()
    tmp.replace(path)
    return path


def remove_parts(paths: list[Path]) -> None:
    for p in paths:
        try:
            os.remove(p)
        except FileNotFoundError:
            pass
