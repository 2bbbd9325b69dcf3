"""Writing: the decomposed point cloud (LAS 1.4) and full-waveform files (for tests and the simulator)."""

from __future__ import annotations

import functools
import logging
import shutil
import struct
from pathlib import Path
from typing import Iterable

import laspy
import numpy as np

from fwcore.io.crs import las_crs_wkt
from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.packets import EVLR_HEADER_BYTES
from fwcore.io.records import PulseBatch, pulse_identity

LOG = logging.getLogger("fwl")

# Per-echo attributes stored as ASPRS Extra Bytes in the decomposed point cloud: (name, description with unit).
# Descriptions hold at most 32 characters (LAS 1.4 Extra Bytes record).
EXTRA_DIMENSIONS = (
    ("amplitude", "peak above background [DN]"),
    ("echo_width", "echo FWHM [ps]"),
    ("alpha", "alpha [1]; NaN: system model"),
    ("echo_energy", "area under echo [DN x ps]"),
    ("fit_error", "pulse sum |residual| (Eq.9) [DN]"),
    ("channel", "waveform channel (PulseWaves)"),
)
# Radiometry (fwcore.radiometry.equations), NaN where unavailable: (name, description when calibrated, when relative).
RADIOMETRY_DIMENSIONS = (
    ("range_m", "range to the scanner [m]", "range to the scanner [m]"),
    ("incidence_deg", "incidence angle [deg]", "incidence angle [deg]"),
    ("backscatter_cross_section_m2", "backscatter cross-section [m2]", "cross-section, relative (C=1)"),
    ("backscatter_coefficient", "backscatter coefficient [1]", "backscatter coef., relative"),
    ("reflectance", "diffuse reflectance [1]", "reflectance, relative (C=1)"),
)
RADIOMETRY_FLAG = ("radiometry", "0 none, 1 relative, 2 calibrated")
RADIOMETRY_FLAGS = {"unavailable": 0, "relative": 1, "calibrated": 2}


def point_cloud_template(template: str | Path) -> dict:
    """Scales, offsets, CRS (WKT) and system identifier of the input the cloud is made from (LAS or PulseWaves)."""
    template = Path(template)
    from fwcore.io.formats import GEDI_L1B, LVIS_L1B, format_of

    fmt = format_of(template)
    if fmt in (GEDI_L1B, LVIS_L1B):  # degrees to 1e-7 (1 cm), heights to the millimetre
        return {"scales": np.array([1e-7, 1e-7, 1e-3]), "offsets": np.zeros(3),
                "wkt": fmt.crs(template)[0], "system_identifier": fmt.name.split()[0], "geokeys": []}
    if template.suffix.lower() == ".pls":
        from fwcore.io.pulsewaves import open_pulsewaves

        pw = open_pulsewaves(template)
        return {"scales": pw.header.scales, "offsets": pw.header.offsets, "wkt": pw.crs_wkt,
                "system_identifier": pw.header.system_identifier, "geokeys": []}
    stat = template.stat()
    return dict(_las_template(str(template), stat.st_mtime_ns, stat.st_size))  # a copy: callers set "wkt"


@functools.lru_cache(maxsize=16)
def _las_template(template: str, mtime_ns: int, size: int) -> dict:
    # once per file and version of it, not each range: its header with the EVLRs (the CRS may be one) is
    # megabytes to read where LAS 1.4 keeps the packets in an EVLR
    with laspy.open(template) as reader:
        source = reader.header
    wkt, _ = las_crs_wkt(source)
    geokeys = tuple(v for v in source.vlrs if v.user_id.rstrip("\0") == "LASF_Projection"
                    and v.record_id in (34735, 34736, 34737))
    return {"scales": source.scales.copy(), "offsets": source.offsets.copy(), "wkt": wkt,
            "system_identifier": source.system_identifier, "geokeys": geokeys}


def write_point_cloud(path: str | Path, template: str | Path, echoes: dict[str, np.ndarray],
                      calibrated: bool = False, crs_wkt: str | None = None) -> Path:
    """LAS 1.4 point format 6 (7 with colour, 8 with NIR), one point per kept echo; .laz compresses.

    Scale, offset, the system identifier and the coordinate reference system come from `template` (the
    input file); the CRS is written as OGC WKT with the global encoding's WKT bit, as formats 6-10 require
    (converted from GeoTIFF keys where the input has those), or `crs_wkt` where given (the run's CRS,
    fwcore.io.formats.input_crs). Columns: fwcore.pulses.decomposed_echoes, and the
    radiometry's (fwcore.radiometry.equations.echo_radiometry) as Extra Bytes, described as calibrated or relative.
    """
    path = Path(path)
    source = point_cloud_template(template)
    if crs_wkt:
        source["wkt"] = crs_wkt
    point_format = 8 if "nir" in echoes else 7 if "rgb" in echoes else 6
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales = np.asarray(source["scales"], dtype=float)
    header.offsets = np.asarray(source["offsets"], dtype=float)
    header.system_identifier = (source["system_identifier"] or "")[:32]
    header.generating_software = "fwlidar"
    if source["wkt"]:
        header.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", source["wkt"].encode() + b"\0"))
        header.global_encoding.wkt = True
    elif source["geokeys"]:  # keys that name no EPSG code: keep them as they are rather than lose them
        header.vlrs.extend(source["geokeys"])
        LOG.warning("%s: the input %s's GeoTIFF keys name neither an EPSG code nor a unit, so no WKT can be written; "
                    "its keys are copied as they are", path.name, Path(template).name)
    else:
        LOG.warning("%s: the input %s names no coordinate reference system; %s is written without one",
                    path.name, Path(template).name, path.name)
    header.add_extra_dims([laspy.ExtraBytesParams(name, "f4", description=desc,
                                                  no_data=[np.nan] if name == "alpha" else None)  # --model system
                           for name, desc in EXTRA_DIMENSIONS]
                          + [laspy.ExtraBytesParams(name, "f4", description=cal if calibrated else rel,
                                                    no_data=[np.nan])  # NaN: unavailable, said in the header
                             for name, cal, rel in RADIOMETRY_DIMENSIONS]
                          + [laspy.ExtraBytesParams(RADIOMETRY_FLAG[0], "u1", description=RADIOMETRY_FLAG[1])])
    las = laspy.LasData(header)
    las.x, las.y, las.z = echoes["x"], echoes["y"], echoes["z"]
    las.gps_time = echoes["gps_time"]
    las.return_number = np.minimum(echoes["return_number"], 15).astype(np.uint8)
    las.number_of_returns = np.minimum(echoes["number_of_returns"], 15).astype(np.uint8)
    las.intensity = echoes["intensity"].astype(np.uint16)
    if "classification" in echoes:
        las.classification = np.asarray(echoes["classification"]).astype(np.uint8)
    las.scan_angle = np.round(np.asarray(echoes["scan_angle"]) / 0.006).astype(np.int16)
    las.scan_direction_flag = echoes["scan_direction_flag"].astype(np.uint8)
    las.edge_of_flight_line = echoes["edge_of_flight_line"].astype(np.uint8)
    las.point_source_id = echoes["point_source_id"].astype(np.uint16)
    las.user_data = echoes["user_data"].astype(np.uint8)
    for name, _ in EXTRA_DIMENSIONS:
        values = echoes[name] if name in echoes else np.zeros(len(echoes["x"]))
        las[name] = np.asarray(values, dtype=np.float32)
    n = len(echoes["x"])
    for name, _, _ in RADIOMETRY_DIMENSIONS:
        values = np.asarray(echoes[name] if name in echoes else np.full(n, np.nan), dtype=np.float32)
        las[name] = np.where(np.isnan(values), np.float32(np.nan), values)  # one NaN: the bytes do not depend on how
    flags = echoes.get(RADIOMETRY_FLAG[0], np.full(n, "unavailable"))
    flags = np.asarray(flags).astype(str)
    las[RADIOMETRY_FLAG[0]] = np.select([flags == k for k in RADIOMETRY_FLAGS], list(RADIOMETRY_FLAGS.values()),
                                        0).astype(np.uint8)
    if "rgb" in echoes:
        las.red, las.green, las.blue = echoes["rgb"].T
    if "nir" in echoes:
        las.nir = echoes["nir"]
    path.parent.mkdir(parents=True, exist_ok=True)
    las.write(path)
    return path


def _evlr_header(record_length: int, description: str) -> bytes:
    return struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, record_length, description.encode()[:32])


DEFAULT_SCALES, DEFAULT_OFFSETS = (0.001, 0.001, 0.001), (0.0, 0.0, 0.0)


def packet_byte_offsets(lengths: np.ndarray, bits: np.ndarray) -> np.ndarray:
    """Where write_waveform_las puts each pulse's packet (after the record header), in pulse order:
    the packet offsets the reader reports."""
    sizes = np.asarray(lengths, dtype=np.int64) * (np.asarray(bits, dtype=np.int64) // 8)
    return EVLR_HEADER_BYTES + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)


def pulse_ids_as_written(gps_time: np.ndarray, anchor: np.ndarray, scales=DEFAULT_SCALES,
                         offsets=DEFAULT_OFFSETS) -> np.ndarray:
    """The pulse ids the reader will give pulses written with these scales and offsets (anchors quantised as
    the file stores them)."""
    scales, offsets = np.asarray(scales, float), np.asarray(offsets, float)
    stored = np.round((np.asarray(anchor, float) - offsets) / scales)
    return pulse_identity(gps_time, stored * scales + offsets)


def write_waveform_las(path: str | Path, pulses: PulseBatch, layout: str = "las13-wdp",
                       bits: int | np.ndarray = 8, scales=DEFAULT_SCALES, offsets=DEFAULT_OFFSETS,
                       empty_descriptors: Iterable[int] = ()) -> Path:
    """A full-waveform file of these pulses: their system returns as points, their samples as packets.

    layout "las13-wdp": LAS 1.3, point format 4, packets in a .wdp beside it;
    "las14-wdp": LAS 1.4, point format 9, .wdp beside it; "las14-internal": LAS 1.4, point format 9,
    packets in the EVLR 65535. `bits` (8 or 16, per file or per pulse) picks each pulse's descriptor:
    one descriptor per distinct (bits, samples, spacing, gain, offset), numbered from 1 around the
    indices in `empty_descriptors`, which get descriptors of 0 samples (as RIEGL writes a hundred).
    """
    with WaveformLasWriter(path, layout, scales, offsets, empty_descriptors) as writer:
        writer.write(pulses, bits)
    return Path(path)


class WaveformLasWriter:
    """write_waveform_las batch by batch, holding one batch: the same bytes as one call on all the pulses.

    The header (and its descriptors) precedes the points, so the first batch decides the descriptors and
    later batches may only reuse its (bits, samples, spacing, gain, offset) kinds. Packets stream to the
    .wdp as batches come; packets inside the file follow all the points, so they wait in a scratch file
    beside it until close(). The header's counts and bounds are laspy's, updated batch by batch. If the
    writing fails, what was written is removed (a file without its end is not a flight).
    """

    def __init__(self, path: str | Path, layout: str = "las13-wdp", scales=DEFAULT_SCALES,
                 offsets=DEFAULT_OFFSETS, empty_descriptors: Iterable[int] = ()) -> None:
        if layout not in ("las13-wdp", "las14-wdp", "las14-internal"):
            raise ValueError(f"layout must be las13-wdp, las14-wdp or las14-internal, not {layout!r}")
        self.path = Path(path)
        self.layout = layout
        self.scales, self.offsets = np.asarray(scales), np.asarray(offsets)
        self.empty = sorted(set(int(i) for i in empty_descriptors))
        self.packets_path = (self.path.with_suffix(".wdp") if layout != "las14-internal"
                             else self.path.with_name(self.path.name + ".packets.partial"))
        self._table: dict[tuple, int] | None = None  # descriptor index of each kind, from the first batch
        self._points: laspy.LasWriter | None = None
        self._packets = None
        self._packet_bytes = 0

    def __enter__(self) -> "WaveformLasWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abandon()

    def write(self, pulses: PulseBatch, bits: int | np.ndarray = 8) -> None:
        """Append these pulses (bits per file or per pulse, as write_waveform_las)."""
        n = len(pulses)
        bits = np.broadcast_to(np.asarray(bits), (n,))
        if not np.isin(bits, (8, 16)).all():
            raise ValueError(f"{self.path.name}: bits per sample must be 8 or 16, not "
                             f"{sorted(set(bits.tolist()) - {8, 16})}")
        if np.any(np.diff(pulses.return_offsets) < 1):
            raise ValueError(f"{self.path.name}: every pulse needs at least one point (system return) to carry its "
                             "packet")
        lengths = np.diff(pulses.sample_offsets)
        kinds = list(zip(bits.tolist(), lengths.tolist(), pulses.sample_spacing_ps.tolist(),
                         pulses.digitizer_gain.tolist(), pulses.digitizer_offset.tolist()))
        if self._table is None:
            self._start(kinds)
        unknown = set(kinds) - self._table.keys()
        if unknown:
            raise ValueError(f"{self.path.name}: a later batch has packets of a kind the first batch did not "
                             f"(bits, samples, spacing, gain, offset) {sorted(unknown)[0]}: the descriptors "
                             f"are in the header, written with the first batch")
        packet_data = _packet_bytes(pulses, bits)
        sizes = lengths.astype(np.int64) * (bits.astype(np.int64) // 8)
        packet_offset = packet_byte_offsets(lengths, bits) + self._packet_bytes
        self._points.write_points(self._point_record(pulses, kinds, packet_offset, sizes).points)
        self._packets.write(packet_data)
        self._packet_bytes += len(packet_data)

    def close(self) -> Path:
        """Finish the file: header counts and bounds, the packets' record length, internal packets appended."""
        if self._table is None:
            raise ValueError(f"{self.path.name}: no pulses were written")
        self._points.close()
        self._packets.seek(0)
        self._packets.write(_evlr_header(self._packet_bytes, "fwlidar waveform packets"))
        self._packets.close()
        if self.layout == "las14-internal":
            with open(self.path, "r+b") as f, open(self.packets_path, "rb") as packets:
                start = f.seek(0, 2)
                f.write(_evlr_header(self._packet_bytes, "Waveform Data Packets"))
                packets.seek(EVLR_HEADER_BYTES)
                shutil.copyfileobj(packets, f, 16 << 20)
                # the header's start of the waveform packets, of the first EVLR and the number of EVLRs
                f.seek(227)
                f.write(struct.pack("<QQI", start, start, 1))
            self.packets_path.unlink()
        return self.path

    def _start(self, kinds: list[tuple]) -> None:
        free = (i for i in range(1, 256) if i not in self.empty)
        self._table = {kind: next(free) for kind in dict.fromkeys(kinds)}
        descriptors = [WaveformDescriptor(i, k[0], 0, k[1], k[2], k[3], k[4]) for k, i in self._table.items()]
        descriptors += [WaveformDescriptor(i, 16, 0, 0, 0.0, 0.0, 0.0) for i in self.empty]
        descriptors.sort(key=lambda d: d.index)
        version, point_format = ("1.3", 4) if self.layout == "las13-wdp" else ("1.4", 9)
        header = laspy.LasHeader(point_format=point_format, version=version)
        header.scales, header.offsets = self.scales, self.offsets
        for d in descriptors:
            header.vlrs.append(laspy.VLR("LASF_Spec", 99 + d.index, "Waveform Packet Descriptor",
                                         d.to_record_data()))
        if self.layout == "las14-internal":
            header.global_encoding.waveform_data_packets_internal = True
        else:
            header.global_encoding.waveform_data_packets_external = True
        self.header = header
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._points = laspy.open(self.path, mode="w", header=header,
                                  do_compress=self.path.suffix.lower() == ".laz")
        self._packets = open(self.packets_path, "w+b")
        self._packets.write(bytes(EVLR_HEADER_BYTES))  # its record length is known at close

    def _point_record(self, pulses: PulseBatch, kinds: list[tuple], packet_offset: np.ndarray,
                      sizes: np.ndarray) -> laspy.LasData:
        owner = np.repeat(np.arange(len(pulses)), np.diff(pulses.return_offsets))
        las = laspy.LasData(self.header)
        las.x, las.y, las.z = pulses.return_xyz.T
        las.gps_time = pulses.gps_time[owner]
        las.return_number = pulses.return_number
        # the file's own count where it has one: a clipped file's pulse may hold fewer returns than it had
        las.number_of_returns = (pulses.number_of_returns if pulses.number_of_returns is not None
                                 else np.diff(pulses.return_offsets)[owner]).astype(np.uint8)
        las.intensity = pulses.return_intensity
        if pulses.classification is not None:
            las.classification = pulses.classification[owner]
        if self.header.point_format.id == 4:
            las.scan_angle_rank = np.round(pulses.scan_angle[owner]).astype(np.int8)
        else:
            las.scan_angle = np.round(pulses.scan_angle[owner] / 0.006).astype(np.int16)
        las.scan_direction_flag = pulses.scan_direction_flag[owner]
        las.edge_of_flight_line = pulses.edge_of_flight_line[owner]
        las.point_source_id = pulses.point_source_id[owner]
        las.user_data = pulses.user_data[owner]
        las.wavepacket_index = np.array([self._table[k] for k in kinds], dtype=np.uint8)[owner]
        las.wavepacket_offset = packet_offset[owner].astype(np.uint64)
        las.wavepacket_size = sizes.astype(np.uint32)[owner]
        las.return_point_wave_location = pulses.return_location_ps.astype(np.float32)
        las.x_t, las.y_t, las.z_t = pulses.direction[owner].astype(np.float32).T
        return las

    def _abandon(self) -> None:
        if self._points is not None:
            self._points.dest.close()
        if self._packets is not None:
            self._packets.close()
        for path in (self.path, self.packets_path):
            path.unlink(missing_ok=True)


def _packet_bytes(pulses: PulseBatch, bits: np.ndarray) -> bytes:
    """The pulses' packets in pulse order: samples rounded and clipped to the bits' range."""
    if bits.size and (bits == bits[0]).all():  # one sample type: one conversion of all the samples
        top = (1 << int(bits[0])) - 1
        values = np.round(pulses.samples[pulses.sample_offsets[0]:pulses.sample_offsets[-1]])
        np.clip(values, 0, top, out=values)  # in place: a chunk of a flight is hundreds of MB of samples
        return values.astype("<u1" if bits[0] == 8 else "<u2").tobytes()
    blobs = []
    for i in range(len(pulses)):
        top = (1 << int(bits[i])) - 1
        blobs.append(np.clip(np.round(pulses.pulse_samples(i)), 0, top).astype(
            "<u1" if bits[i] == 8 else "<u2").tobytes())
    return b"".join(blobs)
