"""Writing the outputs in bounded memory: part files per range, then per-file outputs assembled by streaming.

Every range is written by the worker that decomposed it: Parquet parts under
echoes/ and pulses/, and a LAS part and an MCAP part under parts/. Assembling
a file's las/<stem>.las and mcap/<stem>.mcap reads its parts in range order,
one at a time, into laspy's chunked writer and MCAP's writer; no step ever
holds more than a range. Every file is written under a temporary name and
renamed, so a reader never sees half a file and a retry overwrites.
"""

from __future__ import annotations

import contextlib
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


def dictionary_columns(schema: pa.Schema) -> list[str]:
    """The Parquet columns whose values repeat, dictionary-encoded: strings, integers (a pulse's id on each of its
    echoes) and list values (RH truncated to cm). Not the plain floats, nor WKB, all but unique: pyarrow would build
    their dictionaries and drop them, 40% of writing an echo part (docs/benchmarks.md, issue 60, third pass)."""
    found = []
    for field in schema:
        if pa.types.is_string(field.type) or pa.types.is_integer(field.type):
            found.append(field.name)
        elif pa.types.is_list(field.type):
            found.append(f"{field.name}.list.element")  # the leaf's path (pyarrow's compliant nested type)
    return found


def write_part(table: pa.Table, directory: Path, name: str, **write_options) -> Path:
    """One deterministic part file per range: reruns and retries overwrite, never duplicate (`write_options`:
    pyarrow.parquet.write_table's; by default a dictionary for the dictionary_columns only)."""
    path = directory / f"{name}.parquet"
    tmp = temporary_path(path)
    pq.write_table(table, tmp, **{"use_dictionary": dictionary_columns(table.schema), **write_options})
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


# /waveform: one protobuf message per batch of consecutive pulses (as /echoes), every array a packed repeated
# field of fixed width, so that a batch is its arrays' bytes; any protobuf reader decodes it with the schema
# the file holds (a FileDescriptorSet). Offsets are into the message's own arrays, from 0.
WAVEFORMS_MESSAGE = "fwlidar.Waveforms"
WAVEFORM_FIELDS = (  # (name, protobuf type, numpy dtype, what it holds)
    ("pulse_id", "sfixed64", "<i8", "each pulse's identity, as in the tables"),
    ("gps_time", "double", "<f8", "each pulse's gps_time, as in the file"),
    ("sample_spacing_ps", "double", "<f8", "each pulse's time between two samples, ps"),
    ("sample_offsets", "fixed32", "<u4", "pulse i's samples are raw[sample_offsets[i]:sample_offsets[i + 1]]"),
    ("raw", "float", "<f4", "the digitized samples"),
    ("model", "float", "<f4", "the fitted model at each sample (0 where the pulse was not decomposed)"),
    ("echo_offsets", "fixed32", "<u4", "pulse i's echoes are echo_*[echo_offsets[i]:echo_offsets[i + 1]]"),
    ("echo_time_ps", "double", "<f8", "each echo's centre after the pulse's first sample, ps"),
    ("echo_amplitude", "double", "<f8", "each echo's amplitude, DN"),
    ("echo_fwhm_ps", "double", "<f8", "each echo's FWHM, ps"),
    ("echo_reject", "fixed32", "<u4", "0 kept; else the code of why it was set aside, into reject_reasons"),
)
REJECT_REASONS_FIELD = len(WAVEFORM_FIELDS) + 1  # repeated string: the reasons, by code


def waveforms_schema() -> bytes:
    """The /waveform schema: fwlidar.Waveforms as a serialized FileDescriptorSet."""
    from google.protobuf import descriptor_pb2

    field = descriptor_pb2.FieldDescriptorProto
    message = descriptor_pb2.DescriptorProto(name="Waveforms")
    for number, (name, kind, _, _) in enumerate(WAVEFORM_FIELDS, start=1):
        message.field.add(name=name, number=number, label=field.LABEL_REPEATED,
                          type=getattr(field, f"TYPE_{kind.upper()}"))
    message.field.add(name="reject_reasons", number=REJECT_REASONS_FIELD, label=field.LABEL_REPEATED,
                      type=field.TYPE_STRING)
    proto = descriptor_pb2.FileDescriptorProto(name="fwlidar/Waveforms.proto", package="fwlidar", syntax="proto3",
                                               message_type=[message])
    return descriptor_pb2.FileDescriptorSet(file=[proto]).SerializeToString()


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _length_delimited(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def _waveforms_message(v: dict[str, np.ndarray], lo: int, hi: int) -> bytes:
    """Pulses lo..hi-1 of a range's views as one fwlidar.Waveforms message."""
    from fwcore.engine.filter import REJECT_REASONS

    s_lo, s_hi, e_lo, e_hi = v["sample_offsets"][lo], v["sample_offsets"][hi], v["echo_offsets"][lo], v["echo_offsets"][hi]
    arrays = {"pulse_id": v["pulse_id"][lo:hi], "gps_time": v["gps_time"][lo:hi],
              "sample_spacing_ps": v["sample_spacing_ps"][lo:hi],
              "sample_offsets": v["sample_offsets"][lo:hi + 1] - s_lo, "raw": v["raw"][s_lo:s_hi],
              "model": v["model"][s_lo:s_hi], "echo_offsets": v["echo_offsets"][lo:hi + 1] - e_lo,
              **{f"echo_{k}": v[f"echo_{k}"][e_lo:e_hi] for k in ("time_ps", "amplitude", "fwhm_ps", "reject")}}
    parts = [_length_delimited(number, np.ascontiguousarray(arrays[name], dtype=dtype).tobytes())
             for number, (name, _, dtype, _) in enumerate(WAVEFORM_FIELDS, start=1) if arrays[name].size]
    parts += [_length_delimited(REJECT_REASONS_FIELD, reason.encode()) for reason in REJECT_REASONS]
    return b"".join(parts)


def decode_waveforms(data: bytes) -> dict[str, np.ndarray | list[str]]:
    """A /waveform message's arrays by name (and reject_reasons), read with protobuf from the schema."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for proto in descriptor_pb2.FileDescriptorSet.FromString(waveforms_schema()).file:
        pool.Add(proto)
    message = message_factory.GetMessageClass(pool.FindMessageTypeByName(WAVEFORMS_MESSAGE)).FromString(data)
    found = {name: np.array(getattr(message, name), dtype=dtype) for name, _, dtype, _ in WAVEFORM_FIELDS}
    return {**found, "reject_reasons": list(message.reject_reasons)}


CRS_METADATA = "crs"  # the MCAP metadata record (and /echoes channel metadata key) of the points' CRS


class _McapFile:
    """An MCAP writer with the /echoes and /waveform channels registered, and the points' CRS (OGC WKT) in a
    metadata record and the /echoes channel's metadata."""

    def __init__(self, f, adjusted_standard: bool, crs_wkt: str | None = None, compression: str = "zstd"):
        from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
        from mcap.writer import CompressionType, Writer
        from mcap_protobuf.schema import register_schema

        self.writer = Writer(f, compression=CompressionType[compression.upper()])
        self.writer.start(profile="", library="fwlidar")
        meta = {"log_time": TIME_STAMP_UTC if adjusted_standard else TIME_STAMP_WEEK}
        crs = {CRS_METADATA: crs_wkt} if crs_wkt else {}
        if crs:
            self.writer.add_metadata(CRS_METADATA, {"wkt": crs_wkt})
        self.channels = {
            "/echoes": self.writer.register_channel("/echoes", "protobuf", register_schema(self.writer, PointCloud),
                                                    metadata={**meta, **crs}),
            "/waveform": self.writer.register_channel(
                "/waveform", "protobuf", self.writer.register_schema(WAVEFORMS_MESSAGE, "protobuf", waveforms_schema()),
                metadata=meta),
        }

    def add(self, topic: str, ns: int, data: bytes) -> None:
        self.writer.add_message(self.channels[topic], log_time=ns, data=data, publish_time=ns)


def _batches(starts: np.ndarray, total: int, size: int = POINTS_PER_CLOUD_MESSAGE):
    """(lo, hi) of each run of `size` consecutive groups whose first rows are `starts`, the last ending at total."""
    for chunk in range(0, starts.size, size):
        yield starts[chunk], starts[chunk + size] if chunk + size < starts.size else total


def write_mcap(path: Path, cloud: dict[str, np.ndarray], views: dict[str, np.ndarray],
               adjusted_standard: bool, crs_wkt: str | None = None) -> Path:
    """One range's kept echoes as foxglove.PointCloud messages on /echoes and its pulses' raw waveforms, fitted
    models and echoes as fwlidar.Waveforms messages on /waveform, each message a batch of consecutive pulses,
    in pulse order; their CRS as _McapFile says. In LZ4, not zstd: a part is read once, by assemble_mcap, which
    compresses the file's chunks with zstd; LZ4 compresses 4x and decompresses 4x faster, in 1.4x the bytes
    (docs/benchmarks.md, issue 60, third pass), and keeps parts/ within 0.4 of the raw messages' size."""
    tmp = temporary_path(path)
    with open(tmp, "wb") as f:
        out = _McapFile(f, adjusted_standard, crs_wkt, compression="lz4")
        pulse_of_echo = cloud["pulse_id"]
        if pulse_of_echo.size:
            starts = np.flatnonzero(np.r_[True, pulse_of_echo[1:] != pulse_of_echo[:-1]])
            for lo, hi in _batches(starts, pulse_of_echo.size):
                ns = stamp_ns(float(cloud["gps_time"][lo]), adjusted_standard)
                out.add("/echoes", ns, _point_cloud_message(cloud, np.arange(lo, hi), ns).SerializeToString())
        n = views["pulse_id"].size
        for lo, hi in _batches(np.arange(n), n):
            out.add("/waveform", stamp_ns(float(views["gps_time"][lo]), adjusted_standard),
                    _waveforms_message(views, lo, hi))
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
        for topic, log_time, data in _read_ahead(_part_messages(parts)):
            out.add(topic, log_time, data)
        out.writer.finish()
    tmp.replace(path)
    return path


def _part_messages(parts: list[Path]):
    """(topic, log time, data) of every message of the parts, in the order given, each part in its own order."""
    from mcap.reader import make_reader

    for part in parts:
        with open(part, "rb") as p:
            for _, channel, message in make_reader(p).iter_messages(log_time_order=False):
                yield channel.topic, message.log_time, message.data


def _read_ahead(items, depth: int = 32):
    """The items of `items` in order, made by a thread of their own up to `depth` ahead: the parts' reading
    (Python) runs while the writer compresses a chunk (zstd, without the GIL). An error there is raised here.
    A range's messages are batches of pulses (28 a range of the RIEGL line, 170 KB on average): 32 are ~5 MiB."""
    import queue
    import threading

    made: queue.Queue = queue.Queue(depth)
    end, failed, stop = object(), [], threading.Event()

    def produce():
        try:
            for item in items:
                if stop.is_set():  # the reader below stopped (its writer failed)
                    return
                made.put(item)
        except BaseException as err:  # noqa: BLE001  handed to the reader below
            failed.append(err)
        finally:
            made.put(end)

    thread = threading.Thread(target=produce, name="mcap-parts", daemon=True)
    thread.start()
    try:
        while (item := made.get()) is not end:
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # room for its last put
            with contextlib.suppress(queue.Empty):
                made.get(timeout=0.05)
        thread.join()
    if failed:
        raise failed[0]


def remove_parts(paths: list[Path]) -> None:
    for p in paths:
        try:
            os.remove(p)
        except FileNotFoundError:
            pass
