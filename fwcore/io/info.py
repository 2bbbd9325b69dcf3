"""`fwl info`: what a user asks of a file first (like lasinfo / pulseinfo), from headers and indexes only."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import laspy
import numpy as np

from fwcore.io.crs import crs_name, las_crs_wkt
from fwcore.io.descriptors import ranges_text
from fwcore.io.las import OFFSET_MASK, PointRecords, packet_keys, open_waveform_file
from fwcore.io.ownership import pulse_ownership
from fwcore.io.pulsewaves import VARIES, LookupTable, PulseWavesFile, open_pulsewaves


def describe_las(path: str | Path, chunk_points: int = 1_000_000) -> dict:
    """Header, descriptors and their use, packet storage, CRS, bounds and GPS time range of a LAS/LAZ file.

    Reads the header, then one pass over two point fields (packet key, GPS time); never a sample.
    """
    path = Path(path)
    wf = open_waveform_file(path)
    with laspy.open(path) as reader:
        header = reader.header
    seen = {"gps": [np.inf, -np.inf], "offset": -1}

    def key_chunks(points):  # the pass also finds the GPS time range and the largest packet offset
        for at, rows in points.chunks(chunk_points):
            keys = packet_keys(rows)
            gps = np.asarray(rows["gps_time"])
            gps = gps[np.isfinite(gps)]
            if gps.size:
                seen["gps"] = [min(seen["gps"][0], gps.min()), max(seen["gps"][1], gps.max())]
            if (keys >= 0).any():
                seen["offset"] = max(seen["offset"], int((keys[keys >= 0] & OFFSET_MASK).max()))
            yield at, keys

    with PointRecords(wf) as points:  # one pulse per distinct packet, counted in bounded memory
        owned = pulse_ownership(key_chunks(points), wf.point_count, max(1, wf.point_count))
    t_min, t_max = (float(t) for t in seen["gps"]) if np.isfinite(seen["gps"][0]) else (None, None)
    per_descriptor = {i: int(c) for i, c in enumerate(owned.descriptor_pulses) if c}
    descriptors = [{"index": d.index, "bits": d.bits_per_sample, "samples": d.n_samples,
                    "spacing_ps": d.sample_spacing_ps, "gain": d.gain, "offset": d.offset,
                    "compression": d.compression, "pulses": int(per_descriptor.get(d.index, 0)),
                    "problem": d.problem} for d in sorted(wf.descriptors.values(), key=lambda d: d.index)]
    missing = sorted(set(per_descriptor) - set(wf.descriptors))
    wkt, source = las_crs_wkt(header)
    store = wf.packets
    if store.path == path:
        storage = f"internal, from byte {store.record_start}"
    else:
        storage = f"external {store.path.name} ({store.path.stat().st_size} bytes" + \
            (", LAStools-compressed)" if store.compressed else ", uncompressed)")
    return {
        "file": str(path),
        "format": "LAZ" if wf.compressed else "LAS",
        "version": wf.version,
        "point_format": wf.point_format,
        "system_identifier": header.system_identifier,
        "generating_software": header.generating_software,
        "points": wf.header_point_count,
        "points_present": wf.point_count,
        "pulses": int(owned.descriptor_pulses.sum()),
        "points_without_packet": int(wf.point_count - owned.descriptor_points.sum()),
        "descriptors": descriptors,
        "descriptors_missing": [{"index": int(i), "pulses": int(per_descriptor[i])} for i in missing],
        "packets": storage,
        "crs": {"name": crs_name(wkt), "source": source},
        "bounds": {"min": [float(v) for v in header.mins], "max": [float(v) for v in header.maxs]},
        "gps_time": {"min": t_min, "max": t_max,
                     "type": "adjusted standard GPS time" if header.global_encoding.gps_time_type
                     else "GPS week seconds"},
        "problems": list(wf.problems),
        "largest_packet_offset": seen["offset"] if seen["offset"] >= 0 else None,
    }


def describe_pulsewaves(path: str | Path) -> dict:
    """Header, descriptors (composition and samplings) and their use, lookup tables, CRS, bounds, times."""
    pw = open_pulsewaves(path)
    h = pw.header
    records = pw.records()
    used = dict(zip(*[a.tolist() for a in np.unique(np.asarray(records["descriptor"]), return_counts=True)])) \
        if records.size else {}
    descriptors = [{
        "index": d.index, "pulses": int(used.get(d.index, 0)), "problem": d.problem, "description": d.description,
        "sample_units_ns": d.sample_units_ns, "optical_center_to_anchor":
            "varies" if d.optical_center_to_anchor == VARIES - (1 << 32) or d.optical_center_to_anchor == VARIES
            else d.optical_center_to_anchor,
        "scanner": d.scanner_index,
        "samplings": [{"kind": s.kind, "channel": s.channel, "bits": s.bits_per_sample,
                       "samples": "variable" if s.bits_for_samples else s.number_of_samples,
                       "segments": "variable" if s.bits_for_segments else s.number_of_segments,
                       "sample_units_ns": s.sample_units_ns, "lookup_table": s.lookup_table,
                       "duration_bits": s.bits_for_duration} for s in d.samplings]}
        for d in sorted(pw.descriptors.values(), key=lambda d: d.index)]
    t = np.asarray([h.t_min, h.t_max], np.float64) * h.t_scale + h.t_offset
    return {
        "file": str(pw.path),
        "format": "PulseWaves",
        "version": h.version,
        "system_identifier": h.system_identifier,
        "generating_software": h.generating_software,
        "pulses": h.n_pulses,
        "pulses_present": pw.point_count,
        "descriptors": descriptors,
        "descriptors_missing": [{"index": int(i), "pulses": int(n)} for i, n in used.items()
                                if i not in pw.descriptors],
        "scanners": [dataclasses.asdict(s) for s in pw.scanners.values()],
        "lookup_tables": [describe_table(t_, pw) for t_ in pw.lookup_tables.values()],
        "packets": f"{pw.waves_path.name} ({pw.waves_path.stat().st_size} bytes, uncompressed)",
        "crs": {"name": crs_name(pw.crs_wkt), "source": pw.crs_source},
        "bounds": {"min": list(h.bounds_min), "max": list(h.bounds_max)},
        "gps_time": {"min": float(t[0]), "max": float(t[1]),
                     "type": "no time stamps (T = 0)" if h.t_min == h.t_max == 0 else
                     ("standard GPS time" if h.t_offset >= 1e8 else "GPS week seconds")},
        "problems": list(pw.problems),
    }


def describe_table(table: LookupTable, pw: PulseWavesFile) -> dict:
    """What a lookup table converts to (LookupTable.decibels, .power), its no-value codes and the samplings
    that use it."""
    valid = np.flatnonzero(~table.no_value)
    values = table.entries[valid]
    power = table.power()[valid]
    unit = "dB" if table.decibels else "as given"
    return {
        "index": table.index, "entries": int(table.entries.size), "description": table.description,
        "unit_of_measurement": table.unit,
        "converts": f"decibels (unit {table.unit}) to power, 10^(dB/10)" if table.decibels
        else f"linear (unit {table.unit}): values as given",
        "no_value_codes": ranges_text(np.flatnonzero(table.no_value).tolist()) or None,
        "value_codes": ranges_text(valid.tolist()) or None, "value_unit": unit,
        "range": [float(values.min()), float(values.max())] if valid.size else None,
        "power": [float(power.min()), float(power.max())] if valid.size else None,
        "used_by": [f"{s.kind} channel {s.channel} of descriptor {d.index}" for d in pw.descriptors.values()
                    for s in d.samplings if s.lookup_table == table.index],
    }


def _table_line(t: dict) -> str:
    line = f"  lookup table {t['index']}: {t['entries']} entries, {t['description']}: {t['converts']}"
    if t["no_value_codes"]:
        line += f"; codes {t['no_value_codes']} no value (below detection: power 0)"
    if t["range"]:
        line += (f"; codes {t['value_codes']} {t['range'][0]:.4g}..{t['range'][1]:.4g}"
                 + (f" dB (power {t['power'][0]:.4g}..{t['power'][1]:.4g})" if t["value_unit"] == "dB" else ""))
    return line + ("; used by " + ", ".join(t["used_by"]) if t["used_by"] else "; used by no sampling")


def _format_granule(info: dict) -> str:
    lines = [f"{info['file']}: {info['format']}, {info['shots']} shots, CRS {info['crs']}"]
    for name, beam in info.get("beams", {}).items():
        b = beam["bounds"]
        lines.append(f"  {name}: {beam['shots']} shots, {beam['samples']['min']}-{beam['samples']['max']} samples, "
                     f"{beam['stale']} stale" + (f"; lon {b[0]:.5f}..{b[2]:.5f}, lat {b[1]:.5f}..{b[3]:.5f}" if b else ""))
    if "samples" in info and not isinstance(info["samples"], dict):
        lines.append(f"  {info['samples']} samples a shot")
    if info.get("bounds"):
        b = info["bounds"]
        lines.append(f"  lon {b[0]:.5f}..{b[2]:.5f}, lat {b[1]:.5f}..{b[3]:.5f}")
    for p in info.get("problems", []):
        lines.append(f"  PROBLEM: {p}")
    return "\n".join(lines)


def format_info(info: dict) -> str:
    """The human-readable form of describe_file's dictionary."""
    if "waveforms" in info:  # a NEON-layout CSV: waveforms, no header
        return (f"{info['file']}: {info['format']}\n  waveforms: {info['waveforms']}, "
                f"{info['samples']['min']}-{info['samples']['max']} samples each (fwl decompose-csv reads it)")
    if info["format"] in ("GEDI L1B", "LVIS L1B"):  # HDF5 granules: shots (by beam), samples, CRS, bounds
        return _format_granule(info)
    lines = [f"{info['file']}: {info['format']} {info['version']}"
             + (f", point format {info['point_format']}" if "point_format" in info else "")]
    for key in ("system_identifier", "generating_software"):
        if info.get(key):
            lines.append(f"  {key.replace('_', ' ')}: {info[key]}")
    if "points" in info:
        lines.append(f"  points: {info['points']} in the header, {info['points_present']} present; "
                     f"pulses (distinct packets): {info['pulses']}")
    else:
        lines.append(f"  pulses: {info['pulses']} in the header, {info['pulses_present']} present")
    lines.append(f"  packets: {info['packets']}")
    for d in info["descriptors"]:
        if "samplings" in d and not d["pulses"]:
            continue  # listed below among the unused
        if "samplings" in d:
            lines.append(f"  descriptor {d['index']}: {d['pulses']} pulses; sample units {d['sample_units_ns']} ns, "
                         f"optical centre to anchor {d['optical_center_to_anchor']}"
                         + (f"; UNUSABLE: {d['problem']}" if d["problem"] else "")
                         + (f"; {d['description']}" if d.get("description") else ""))
            for s in d["samplings"]:
                lines.append(f"    {s['kind']} channel {s['channel']}: {s['bits']} bits, "
                             f"{s['samples']} samples, {s['segments']} segments, {s['sample_units_ns']} ns"
                             + (f", lookup table {s['lookup_table']}" if s["lookup_table"] else ""))
            if sum(s["kind"] == "returning" for s in d["samplings"]) > 1:
                lines.append("    one waveform a pulse: of its returning channels, the one without a saturated "
                             "sample whose peak is highest against its full scale")
        elif d["pulses"] or d["problem"] is None:
            lines.append(f"  descriptor {d['index']}: {d['pulses']} pulses; {d['bits']} bits, {d['samples']} samples "
                         f"at {d['spacing_ps']:g} ps, gain {d['gain']:g}, offset {d['offset']:g}, "
                         f"compression {d['compression']}" + (f"; UNUSABLE: {d['problem']}" if d["problem"] else ""))
    unused = [d["index"] for d in info["descriptors"] if not d["pulses"] and ("samplings" in d or d["problem"])]
    if unused:
        lines.append(f"  {len(unused)} more descriptors, used by no pulse: {unused[:12]}"
                     + (" ..." if len(unused) > 12 else ""))
    for d in info.get("descriptors_missing", []):
        lines.append(f"  descriptor {d['index']}: used by {d['pulses']} pulses but not defined")
    for t in info.get("lookup_tables", []):
        lines.append(_table_line(t))
    crs = info["crs"]
    lines.append(f"  CRS: {crs['name'] or 'none'} ({crs['source']})")
    b = info["bounds"]
    lines.append("  bounds: " + ", ".join(f"{a} {lo:.3f}..{hi:.3f}" for a, lo, hi in zip("xyz", b["min"], b["max"])))
    t = info["gps_time"]
    if t["min"] is not None:
        lines.append(f"  GPS time: {t['min']:.6f}..{t['max']:.6f} ({t['type']})")
    for p in info.get("problems", []):
        lines.append(f"  PROBLEM: {p}")
    return "\n".join(lines)
