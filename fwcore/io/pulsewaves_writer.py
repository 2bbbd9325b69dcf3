"""Waveforms written as PulseWaves (.pls + .wvs), so tools that read PulseWaves (Sylva, PulseTools) see the same
waveforms our readers give: a GEDI or LVIS HDF5 file, or any PulseBatch, in the format's uncompressed form 0.

What is written, by the layout fwcore.io.pulsewaves reads (its module docstring has the draft's traps): one
pulse descriptor per distinct sample spacing, each with one returning sampling of one segment a pulse (16-bit
segment lengths, 8- or 16-bit unsigned samples, no lookup table); a pulse's anchor is its first sample's position
and its target 1000 sampling units along the beam, so the reader gives back each sample's position to the
coordinates' quantum. Not written: outgoing waveforms, the system's returns, a CRS record (the coordinates are the
batch's, in its CRS).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from fwcore.io.pulsewaves import PULSE_HEADER, PULSE_RECORD, VARIES, WAVES_HEADER_BYTES
from fwcore.io.records import PulseBatch
from fwcore.io.signatures import PULSE_SIGNATURE, WAVES_SIGNATURE

_COMPOSITION = struct.Struct("<IIiHHfII64s")  # 92 bytes
_SAMPLING = struct.Struct("<IIBBBBffBBHIHHfI64s")  # 104 bytes
T_SCALE = 1e-6  # GPS time in microseconds
MAX_DESCRIPTORS = 255


def vlr(user: str, record_id: int, payload: bytes, description: str = "") -> bytes:
    """A variable-length record: its 96-byte head, then the payload."""
    return struct.pack("<16sIIq64s", user.encode(), record_id, 0, len(payload), description.encode()) + payload


def returning_descriptor(spacing_ps: float, bits: int) -> bytes:
    """A composition of one returning sampling: units of 1 ns, each sample `spacing_ps` apart, one segment a pulse
    of up to 65,535 samples, no duration bits (every segment starts at the anchor)."""
    varies = VARIES - (1 << 32)  # the optical centre's offset "varies", in the signed field
    out = _COMPOSITION.pack(_COMPOSITION.size, 0, varies, 0, 1, 1.0, 0, 0, b"fwcore.io.pulsewaves_writer")
    return out + _SAMPLING.pack(_SAMPLING.size, 0, 2, 0, 0, 0, 1.0, 0.0, 0, 16, 1, 0, bits, 0, spacing_ps / 1000.0, 0,
                                b"returning waveform")


def _quantised(values: np.ndarray, scale: float) -> tuple[float, np.ndarray]:
    """(offset, int32 codes) of values at `scale`, about the values' midpoint so int32 holds them."""
    finite = values[np.isfinite(values)]
    offset = float(np.round((finite.min() + finite.max()) / 2 / scale) * scale) if finite.size else 0.0
    codes = np.round((values - offset) / scale)
    if not np.all(np.abs(codes) < 2**31 - 1):
        raise ValueError(f"coordinates span {np.ptp(finite):.6g}: more than int32 holds at the scale {scale}")
    return offset, codes.astype(np.int32)


def write_pulsewaves(path: str | Path, pulses: PulseBatch, bits: int = 16, round_samples: bool = False,
                     system: str = "", coordinate_scales: tuple[float, float, float] | None = None) -> Path:
    """`pulses` as `path` (.pls) and its .wvs beside it. Samples must be whole numbers in [0, 2**bits) unless
    `round_samples` (then rounded: GEDI's float DN, said by the caller); coordinates are quantised at
    `coordinate_scales` (default 1e-7 for x and y under 360 in magnitude, degrees, else 1e-3; 1e-3 for z)."""
    path = Path(path)
    if bits not in (8, 16):
        raise ValueError(f"{bits}-bit samples: PulseWaves' returning samples are 8 or 16 bits here")
    n = len(pulses)
    if n == 0:
        raise ValueError(f"{path}: no pulses to write")
    samples = np.round(pulses.samples) if round_samples else pulses.samples
    if not (np.all(samples == np.round(samples)) and samples.min() >= 0 and samples.max() < 2**bits):
        raise ValueError(f"{path}: samples {samples.min()}..{samples.max()} are not whole {bits}-bit values "
                         "(round_samples rounds them)")
    lengths = np.diff(pulses.sample_offsets)
    if lengths.max() > 65535:
        raise ValueError(f"{path}: a waveform of {lengths.max()} samples; one segment holds at most 65,535")
    spacings, descriptor = np.unique(pulses.sample_spacing_ps, return_inverse=True)
    if spacings.size > MAX_DESCRIPTORS:
        raise ValueError(f"{path}: {spacings.size} sample spacings; PulseWaves holds {MAX_DESCRIPTORS} descriptors")

    # the first sample's position, and the beam per 1 ns sampling unit (fwcore.io.records.PulseBatch's geometry)
    first = pulses.anchor + pulses.anchor_location_ps[:, None] * pulses.direction
    target = first - 1000.0 * 1000.0 * pulses.direction
    both = np.vstack([first, target])
    scales = coordinate_scales or tuple(1e-7 if axis < 2 and np.nanmax(np.abs(both[:, axis])) < 360 else 1e-3
                                        for axis in range(3))
    offsets, codes = zip(*(_quantised(both[:, axis], scales[axis]) for axis in range(3)))
    codes = np.stack(codes, axis=1)

    dtype = np.uint8 if bits == 8 else np.dtype("<u2")
    waves = bytearray(WAVES_SIGNATURE.ljust(WAVES_HEADER_BYTES, b"\0"))  # compression 0: uncompressed
    wave_offsets = np.empty(n, np.int64)
    for i in range(n):  # one segment: its sample count, then the samples
        wave_offsets[i] = len(waves)
        waves += struct.pack("<H", lengths[i])
        waves += samples[pulses.sample_offsets[i]:pulses.sample_offsets[i + 1]].astype(dtype).tobytes()
    path.with_suffix(".wvs").write_bytes(bytes(waves))

    vlrs = b"".join(vlr("PulseWaves_Spec", 200001 + d, returning_descriptor(s, bits), f"{s:g} ps a sample")
                    for d, s in enumerate(spacings))
    records = np.zeros(n, PULSE_RECORD)
    records["T"] = np.round(pulses.gps_time / T_SCALE)
    records["offset"] = wave_offsets
    records["anchor"], records["target"] = codes[:n], codes[n:]
    records["last_returning"] = np.minimum(lengths - 1, 32767)
    records["descriptor"] = descriptor + 1
    lo, hi = np.nanmin(both, axis=0), np.nanmax(both, axis=0)
    header = PULSE_HEADER.pack(PULSE_SIGNATURE, 0, 0, 0, 0, 0, bytes(8), system.encode()[:63],
                               b"fwcore.io.pulsewaves_writer", 1, 2026, 0, 3, PULSE_HEADER.size,
                               PULSE_HEADER.size + len(vlrs), n, 0, 0, PULSE_RECORD.itemsize, 0, 0, spacings.size, 0,
                               T_SCALE, 0.0, int(records["T"].min()), int(records["T"].max()),
                               *scales, *offsets, lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])
    path.write_bytes(header + vlrs + records.tobytes())
    return path
