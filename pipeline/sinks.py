"""Writing the outputs: Parquet part files, the per-file MCAP."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

POINTS_PER_CLOUD_MESSAGE = 200  # consecutive pulses per foxglove.PointCloud message


def write_part(table: pa.Table, directory: Path, name: str) -> Path:
    """One deterministic part file per range: reruns and retries overwrite, never duplicate."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{name}.parquet"
    tmp = path.with_suffix(".parquet.tmp")
    pq.write_table(table, tmp)
    tmp.replace(path)
    return path


def _point_cloud_message(cloud: dict[str, np.ndarray], rows: np.ndarray, origin: np.ndarray):
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp

    names = ("x", "y", "z", "amplitude", "fwhm", "echo_index")
    # float32 around an origin kept in the pose: projected coordinates need more than float32 alone
    values = np.stack([cloud["x"][rows] - origin[0], cloud["y"][rows] - origin[1], cloud["z"][rows] - origin[2],
                       cloud["amplitude"][rows], cloud["echo_width"][rows], cloud["return_number"][rows]], axis=1)
    ns = int(round(float(cloud["gps_time"][rows[0]]) * 1e9))
    return PointCloud(
        timestamp=Timestamp(seconds=ns // 10**9, nanos=ns % 10**9), frame_id="world",
        pose=Pose(position=Vector3(x=origin[0], y=origin[1], z=origin[2]), orientation=Quaternion(w=1.0)),
        point_stride=4 * len(names),
        fields=[PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32) for i, n in enumerate(names)],
        data=values.astype("<f4").tobytes()), ns


WAVEFORM_SCHEMA = {
    "type": "object",
    "properties": {"pulse_id": {"type": "integer"}, "gps_time": {"type": "number"},
                   "time_ps": {"type": "array"}, "raw": {"type": "array"}, "model": {"type": "array"},
                   "echoes": {"type": "array"}},
}


def _waveform_messages(views: list[dict[str, np.ndarray]]):
    """(gps_time, pulse_id, JSON) per pulse of the ranges' view arrays, in time order."""
    keys = [(float(v["gps_time"][i]), int(v["pulse_id"][i]), b, i) for b, v in enumerate(views)
            for i in range(v["pulse_id"].size)]
    from fwcore.filter import REJECT_REASONS
    for gps_time, pulse_id, b, i in sorted(keys):
        v = views[b]
        lo, hi = v["sample_offsets"][i], v["sample_offsets"][i + 1]
        e_lo, e_hi = v["echo_offsets"][i], v["echo_offsets"][i + 1]
        yield gps_time, json.dumps({
            "pulse_id": pulse_id, "gps_time": gps_time,
            "time_ps": (np.arange(hi - lo) * float(v["sample_spacing_ps"][i])).tolist(),
            "raw": v["raw"][lo:hi].tolist(), "model": np.round(v["model"][lo:hi], 3).tolist(),
            "echoes": [{"time_ps": float(t), "amplitude": float(a), "fwhm_ps": float(f), "kept": not r,
                        "reject_reason": REJECT_REASONS[r]}
                       for t, a, f, r in zip(v["echo_time_ps"][e_lo:e_hi], v["echo_amplitude"][e_lo:e_hi],
                                             v["echo_fwhm_ps"][e_lo:e_hi], v["echo_reject"][e_lo:e_hi])],
        }).encode()


def write_mcap(path: Path, cloud: dict[str, np.ndarray], views: list[dict[str, np.ndarray]]) -> Path:
    """Kept echoes as foxglove.PointCloud messages on /echoes (chunks of consecutive pulses, GPS time
    stamps) and each pulse's raw waveform, fitted model and echoes as JSON on /waveform."""
    from mcap.writer import Writer
    from mcap_protobuf.schema import register_schema
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="fwlidar")
        cloud_channel = writer.register_channel("/echoes", "protobuf", register_schema(writer, PointCloud))
        schema = writer.register_schema("fwlidar.Waveform", "jsonschema", json.dumps(WAVEFORM_SCHEMA).encode())
        wave_channel = writer.register_channel("/waveform", "json", schema)
        if cloud["x"].size:
            origin = np.floor([cloud["x"].min(), cloud["y"].min(), cloud["z"].min()])
            pulse_of_echo = cloud["pulse_id"]
            starts = np.flatnonzero(np.r_[True, pulse_of_echo[1:] != pulse_of_echo[:-1]])
            for chunk in range(0, starts.size, POINTS_PER_CLOUD_MESSAGE):
                lo = starts[chunk]
                hi = starts[chunk + POINTS_PER_CLOUD_MESSAGE] if chunk + POINTS_PER_CLOUD_MESSAGE < starts.size \
                    else pulse_of_echo.size
                message, ns = _point_cloud_message(cloud, np.arange(lo, hi), origin)
                writer.add_message(cloud_channel, log_time=ns, data=message.SerializeToString(), publish_time=ns)
        for gps_time, data in _waveform_messages(views):
            ns = int(round(gps_time * 1e9))
            writer.add_message(wave_channel, log_time=ns, data=data, publish_time=ns)
        writer.finish()
    return path
