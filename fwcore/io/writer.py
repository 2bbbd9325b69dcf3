"""Writing: the decomposed point cloud (LAS 1.4) and full-waveform files (for tests and the simulator)."""

from __future__ import annotations

import struct
from pathlib import Path

import laspy
from laspy.vlrs.vlrlist import VLRList
import numpy as np

from fwcore.records import BatchDecomposition
from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.geolocate import echo_positions
from fwcore.io.packets import EVLR_HEADER_BYTES
from fwcore.io.records import PulseBatch
from fwcore.model import sigma_to_time_unit

# Per-echo attributes stored as ASPRS Extra Bytes in the decomposed point cloud.
EXTRA_DIMENSIONS = (
    ("amplitude", "echo amplitude above background"),
    ("echo_width", "echo FWHM (ps)"),
    ("sigma", "generalized Gaussian sigma (ps)"),
    ("alpha", "generalized Gaussian shape"),
    ("echo_energy", "area under the echo (DN ps)"),
    ("fit_error", "pulse fit error (Eq. 9)"),
)
_CRS_RECORDS = {("LASF_Projection", 34735), ("LASF_Projection", 34736), ("LASF_Projection", 34737),
                ("LASF_Projection", 2112)}


def decomposed_echoes(pulses: PulseBatch, result: BatchDecomposition,
                      positions: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Columns of the kept echoes, geolocated, with return numbers recomputed in time order.

    `positions` are those of every echo (fwcore.io.geolocate.echo_positions), when the caller has them.
    """
    kept = result.reject == 0
    owner = result.echo_waveform[kept]
    spacing = pulses.sample_spacing_ps[owner]
    xyz = (echo_positions(pulses, result) if positions is None else positions)[kept]
    # echoes are sorted by position within a pulse, so a running count is the return number
    n_kept = np.bincount(owner, minlength=len(result))
    first = np.concatenate([[0], np.cumsum(n_kept)[:-1]])
    return_number = np.arange(owner.size) - first[owner] + 1
    amplitude = result.amplitude[kept]
    columns = {
        "pulse_id": pulses.pulse_id[owner],
        "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
        "gps_time": pulses.gps_time[owner],
        "return_number": return_number,
        "number_of_returns": n_kept[owner],
        # 8-bit digitizers scaled to the 16-bit intensity range
        "intensity": np.clip(np.round(amplitude * 2.0 ** (16 - pulses.bits_per_sample[owner])), 0, 65535),
        "scan_angle": pulses.scan_angle[owner],
        "scan_direction_flag": pulses.scan_direction_flag[owner],
        "edge_of_flight_line": pulses.edge_of_flight_line[owner],
        "point_source_id": pulses.point_source_id[owner],
        "user_data": pulses.user_data[owner],
        "amplitude": amplitude,
        "echo_width": result.fwhm[kept] * spacing,
        "sigma": sigma_to_time_unit(result.sigma[kept], result.alpha[kept], spacing),
        "alpha": result.alpha[kept],
        "echo_energy": result.energy[kept] * spacing,
        "fit_error": result.fit_error[owner],
    }
    if pulses.rgb is not None:
        columns["rgb"] = pulses.rgb[owner]
    if pulses.nir is not None:
        columns["nir"] = pulses.nir[owner]
    return columns


def write_point_cloud(path: str | Path, template: str | Path, echoes: dict[str, np.ndarray]) -> Path:
    """LAS 1.4 point format 6 (7 with colour, 8 with NIR), one point per kept echo; .laz compresses.

    Scale, offset and the coordinate reference system VLRs come from `template` (the input file).
    """
    path = Path(path)
    with laspy.open(template) as reader:
        source = reader.header
    point_format = 8 if "nir" in echoes else 7 if "rgb" in echoes else 6
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales = source.scales
    header.offsets = source.offsets
    for vlr in source.vlrs:
        if (vlr.user_id.rstrip("\0"), vlr.record_id) in _CRS_RECORDS:
            header.vlrs.append(vlr)
    header.global_encoding.wkt = any(v.record_id == 2112 for v in header.vlrs)
    header.add_extra_dims([laspy.ExtraBytesParams(name, "f4", description=desc) for name, desc in EXTRA_DIMENSIONS])
    las = laspy.LasData(header)
    las.x, las.y, las.z = echoes["x"], echoes["y"], echoes["z"]
    las.gps_time = echoes["gps_time"]
    las.return_number = np.minimum(echoes["return_number"], 15).astype(np.uint8)
    las.number_of_returns = np.minimum(echoes["number_of_returns"], 15).astype(np.uint8)
    las.intensity = echoes["intensity"].astype(np.uint16)
    las.scan_angle = np.round(np.asarray(echoes["scan_angle"]) / 0.006).astype(np.int16)
    las.scan_direction_flag = echoes["scan_direction_flag"].astype(np.uint8)
    las.edge_of_flight_line = echoes["edge_of_flight_line"].astype(np.uint8)
    las.point_source_id = echoes["point_source_id"].astype(np.uint16)
    las.user_data = echoes["user_data"].astype(np.uint8)
    for name, _ in EXTRA_DIMENSIONS:
        las[name] = np.asarray(echoes[name], dtype=np.float32)
    if "rgb" in echoes:
        las.red, las.green, las.blue = echoes["rgb"].T
    if "nir" in echoes:
        las.nir = echoes["nir"]
    path.parent.mkdir(parents=True, exist_ok=True)
    las.write(path)
    return path


def _evlr_header(record_length: int, description: str) -> bytes:
    return struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, record_length, description.encode()[:32])


def packet_byte_offsets(lengths: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """Where write_waveform_las puts each pulse's packet (after the record header), in pulse order:
    the byte offsets the reader reports as pulse ids."""
    sizes = np.asarray(lengths, dtype=np.int64) * (np.asarray(bits, dtype=np.int64) // 8)
    return EVLR_HEADER_BYTES + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)


def write_waveform_las(path: str | Path, pulses: PulseBatch, layout: str = "las13-wdp",
                       bits: int | np.ndarray = 8, scales=(0.001, 0.001, 0.001), offsets=(0.0, 0.0, 0.0)) -> Path:
    """A full-waveform file of these pulses: their system returns as points, their samples as packets.

    layout "las13-wdp": LAS 1.3, point format 4, packets in a .wdp beside it;
    "las14-internal": LAS 1.4, point format 9, packets in the EVLR 65535.
    `bits` (8 or 16, per file or per pulse) picks each pulse's descriptor:
    one descriptor per distinct (bits, samples, spacing, gain, offset).
    """
    if layout not in ("las13-wdp", "las14-internal"):
        raise ValueError(f"layout must be las13-wdp or las14-internal, not {layout!r}")
    path = Path(path)
    n = len(pulses)
    bits = np.broadcast_to(np.asarray(bits), (n,))
    if not np.isin(bits, (8, 16)).all():
        raise ValueError("bits per sample must be 8 or 16")
    if np.any(np.diff(pulses.return_offsets) < 1):
        raise ValueError("every pulse needs at least one point (system return) to carry its packet")
    lengths = np.diff(pulses.sample_offsets)
    kinds = list(zip(bits.tolist(), lengths.tolist(), pulses.sample_spacing_ps.tolist(),
                     pulses.digitizer_gain.tolist(), pulses.digitizer_offset.tolist()))
    table = {kind: i + 1 for i, kind in enumerate(dict.fromkeys(kinds))}
    descriptors = [WaveformDescriptor(i, k[0], 0, k[1], k[2], k[3], k[4]) for k, i in table.items()]
    # packets, in pulse order, after the record header
    blobs, packet_offset = [], packet_byte_offsets(lengths, bits)
    for i in range(n):
        dtype = "<u1" if bits[i] == 8 else "<u2"
        top = (1 << int(bits[i])) - 1
        blobs.append(np.clip(np.round(pulses.pulse_samples(i)), 0, top).astype(dtype).tobytes())
    packet_data = b"".join(blobs)
    record = _evlr_header(len(packet_data), "fwlidar waveform packets") + packet_data

    version, point_format = ("1.3", 4) if layout == "las13-wdp" else ("1.4", 9)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets = np.asarray(scales), np.asarray(offsets)
    for d in descriptors:
        header.vlrs.append(laspy.VLR("LASF_Spec", 99 + d.index, "Waveform Packet Descriptor", d.to_record_data()))
    owner = np.repeat(np.arange(n), np.diff(pulses.return_offsets))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pulses.return_xyz.T
    las.gps_time = pulses.gps_time[owner]
    las.return_number = pulses.return_number
    las.number_of_returns = np.diff(pulses.return_offsets)[owner].astype(np.uint8)
    las.intensity = pulses.return_intensity
    if point_format == 4:
        las.scan_angle_rank = np.round(pulses.scan_angle[owner]).astype(np.int8)
    else:
        las.scan_angle = np.round(pulses.scan_angle[owner] / 0.006).astype(np.int16)
    las.scan_direction_flag = pulses.scan_direction_flag[owner]
    las.edge_of_flight_line = pulses.edge_of_flight_line[owner]
    las.point_source_id = pulses.point_source_id[owner]
    las.user_data = pulses.user_data[owner]
    las.wavepacket_index = np.array([table[k] for k in kinds], dtype=np.uint8)[owner]
    las.wavepacket_offset = packet_offset[owner].astype(np.uint64)
    las.wavepacket_size = np.array([len(b) for b in blobs], dtype=np.uint32)[owner]
    las.return_point_wave_location = pulses.return_location_ps.astype(np.float32)
    las.x_t, las.y_t, las.z_t = pulses.direction[owner].astype(np.float32).T
    path.parent.mkdir(parents=True, exist_ok=True)
    if layout == "las13-wdp":
        las.header.global_encoding.waveform_data_packets_external = True
        las.write(path)
        path.with_suffix(".wdp").write_bytes(record)
    else:
        las.header.global_encoding.waveform_data_packets_internal = True
        las.evlrs = VLRList([laspy.VLR("LASF_Spec", 65535, "Waveform Data Packets", packet_data)])
        las.write(path)
        with laspy.open(path) as reader:
            start = reader.header.start_of_first_evlr
        with open(path, "r+b") as f:
            f.seek(227)  # start_of_waveform_data_packet_record in the LAS 1.3/1.4 header
            f.write(struct.pack("<Q", start))
    return path
