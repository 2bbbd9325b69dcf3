"""Lookup tables as RIEGL writes them, on PulseWaves files this test writes from the specification.

RiPROCESS 1.6.5 (PulseWaves 0.3) writes two tables (records 300001 and 300002, "amplitude conversion table
for low channel" / "... for high channel", unit_of_measurement 1, float32, 256 entries) holding decibels:
codes 0-3 are -2e37 (no value: below detection), codes 4-255 rise from -5.44 to 19.73 dB (low channel) and
from -1.46 to 39.71 dB (high channel). Its pulses carry the low-power channel 1 and, where that saturates,
the high-power channel 0 over the same window.
"""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np
import pytest

from fwcore.engine.config import DecompositionConfig, Model
from fwcore.engine.decompose import decompose_batch
from fwcore.io import describe_file, plan_point_ranges, read_pulses
from fwcore.io.geolocate import geolocate
from fwcore.io.info import format_info
from fwcore.io.pulsewaves import open_pulsewaves
from fwcore.instrument.pulse import nominal_pulse
from fwcore.instrument.width import recorded_pulse_fwhm_ps
from fwcore.pulses import pulse_waveforms

SENTINEL = -2e37
LOW_DB = np.r_[[SENTINEL] * 4, np.linspace(-5.44, 19.73, 252)].astype(np.float32)
HIGH_DB = np.r_[[SENTINEL] * 4, np.linspace(-1.46, 39.71, 252)].astype(np.float32)
SCALE = 0.001  # coordinates in mm
DURATION_SCALE = 0.001  # durations stored in ps
ANCHOR = np.array([1000.0, 2000.0, 1500.0])
STEP_M = 0.149896229  # one ns along the beam


# ---------------------------------------------------------------- a PulseWaves writer, from the specification

@dataclasses.dataclass
class Sampling:
    kind: int  # 1 outgoing, 2 returning
    channel: int
    table: int = 0
    bits_duration: int = 32
    bits_segments: int = 8
    description: str = ""


@dataclasses.dataclass
class Table:
    unit: int
    description: str
    entries: np.ndarray
    with_compression: bool = True  # the 84-byte table head; False: the reference library's 80 bytes


def _vlr(user: str, record_id: int, payload: bytes, description: str = "") -> bytes:
    return struct.pack("<16sIIq64s", user.encode(), record_id, 0, len(payload), description.encode()) + payload


def _descriptor(samplings: list[Sampling]) -> bytes:
    # composition record (size 92): size, reserved, optical centre to anchor, extra wave bytes, samplings,
    # sample units, compression, scanner index, description
    out = struct.pack("<IIiHHfII64s", 92, 0, 0, 0, len(samplings), 1.0, 0, 0, b"RIEGL-like test descriptor")
    for s in samplings:  # sampling records (size 104)
        out += struct.pack("<IIBBBBffBBHIHHfI64s", 104, 0, s.kind, s.channel, 0, s.bits_duration,
                           DURATION_SCALE if s.bits_duration else 1.0, 0.0, s.bits_segments, 8,
                           0 if s.bits_segments else 1, 0, 8, s.table, 1.0, 0, s.description.encode())
    return out


def _table(t: Table) -> bytes:
    head = struct.pack("<III64s", 76, 0, 1, b"lookup table record")
    size = 84 if t.with_compression else 80
    body = struct.pack("<IIIHBB", size, 0, t.entries.size, t.unit, 8, 0)
    body += (struct.pack("<I", 0) if t.with_compression else b"") + struct.pack("<64s", t.description.encode())
    return head + body + np.asarray(t.entries, "<f4").tobytes()


def _waves(samplings: list[Sampling], segments: list[list[tuple[float, np.ndarray]]]) -> bytes:
    out = b""
    for s, segs in zip(samplings, segments):
        if s.bits_segments:
            out += struct.pack("<B", len(segs))
        for duration_ns, codes in segs:
            if s.bits_duration:
                out += struct.pack("<i", int(round(duration_ns / DURATION_SCALE)))
            out += struct.pack("<B", len(codes)) + np.asarray(codes, np.uint8).tobytes()
    return out


def write_pulsewaves(path: Path, samplings: list[Sampling], tables: dict[int, Table],
                     pulses: list[list[list[tuple[float, np.ndarray]]]]) -> Path:
    """A .pls + .wvs pair: one descriptor (index 1), the tables, and per pulse its segments per sampling
    (duration from the anchor in ns, codes); every pulse fired straight down from ANCHOR, 1 ms apart."""
    waves, offsets = b"PulseWavesWaves\0" + struct.pack("<I", 0) + bytes(40), []
    for segments in pulses:
        offsets.append(len(waves))
        waves += _waves(samplings, segments)
    path.with_suffix(".wvs").write_bytes(waves)
    vlrs = _vlr("PulseWaves_Spec", 200001, _descriptor(samplings))
    vlrs += b"".join(_vlr("PulseWaves_Spec", 300000 + i, _table(t), t.description) for i, t in tables.items())
    anchor = np.round(ANCHOR / SCALE).astype(np.int32)
    target = np.round((ANCHOR + [0.0, 0.0, -1000 * STEP_M]) / SCALE).astype(np.int32)
    records = b"".join(struct.pack("<qq3i3ihhBBBB", 1_000_000 * k, o, *anchor, *target, 0, 0, 1, 0, 0, 0)
                       for k, o in enumerate(offsets))
    lo, hi = ANCHOR - [1, 1, 400], ANCHOR + 1
    header = struct.pack("<16sIIIHH8s64s64sHHBBHqqIIIIqIiddqq3d3d6d", b"PulseWavesPulse\0", 0, 0, 0, 0, 0, bytes(8),
                         b"RIEGL-like test file", b"tests/fwcore/io/test_pulsewaves_tables.py", 1, 2026, 0, 3,
                         352, 352 + len(vlrs), len(pulses), 0, 0, 48, 0, 0, 1 + len(tables), -1, 1e-6, 0.0,
                         0, 1_000_000 * max(len(pulses) - 1, 0), SCALE, SCALE, SCALE, 0.0, 0.0, 0.0,
                         lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])
    assert len(header) == 352
    terminator = _vlr("PulseWaves_Spec", 0xFFFFFFFF, b"")  # an AVLR of no payload: its footer only
    path.write_bytes(header + vlrs + records + terminator)
    return path


# ---------------------------------------------------------------- a RIEGL-like flight

RIEGL = [Sampling(1, 3, bits_duration=0, bits_segments=0, description="1 reference segment(s)"),
         Sampling(2, 1, table=1, description="lowpower segment(s)"),
         Sampling(2, 0, table=2, description="highpower segment(s)")]
RIEGL_TABLES = {1: Table(1, "amplitude conversion table for low channel", LOW_DB),
                2: Table(1, "amplitude conversion table for high channel", HIGH_DB)}
FWHM_NS = 4.0
START_NS = 990.0  # every returning window starts here, 60 samples


def _power(t_ns: np.ndarray, echoes: list[tuple[float, float]], rng: np.random.Generator) -> np.ndarray:
    sigma = FWHM_NS / 2.3548
    p = 0.35 + 0.1 * rng.standard_normal(t_ns.size)  # the background, around the detection threshold
    for at, power in echoes:
        p += power * np.exp(-0.5 * ((t_ns - at) / sigma) ** 2)
    return p


def encode(power: np.ndarray, table: np.ndarray) -> np.ndarray:
    """The code whose level is closest below the power's (dB), 2 below the table's lowest, 255 above its top."""
    level = 10 * np.log10(np.maximum(power, 1e-12))
    codes = np.searchsorted(table[4:].astype(np.float64), level, side="right") + 3
    return np.where(level < table[4], 2, np.clip(codes, 4, 255)).astype(np.uint8)


def _outgoing() -> np.ndarray:
    k = np.arange(40)
    return np.round(200 * np.exp(-0.5 * ((k - 15) / (FWHM_NS / 2.3548)) ** 2)).astype(np.uint8)


def _pulse(echoes: list[tuple[float, float]], rng, windows=((START_NS, 60),)) -> list:
    low, high = [], []
    for start, n in windows:
        p = _power(start + np.arange(n), echoes, rng)
        low.append((start, encode(p, LOW_DB)))
        high.append((start, encode(p, HIGH_DB)))
    saturated = any((codes == 255).any() for _, codes in low)
    return [[(0.0, _outgoing())], low, high if saturated else []]


FLIGHT = [  # per pulse its echoes: (time ns, power); the low channel saturates above 10^1.973 = 94
    [(1010.0, 30.0)],
    [(1010.0, 8.0), (1025.0, 20.0)],
    [(1012.0, 400.0)],  # saturates the low channel: the high one is recorded too
    [(1008.0, 2000.0), (1030.0, 150.0)],  # saturates; the weaker echo (7.5%: the filter keeps it) on the high channel
    [(1015.0, 60.0)],
]


@pytest.fixture(scope="module")
def riegl_like(tmp_path_factory) -> Path:
    rng = np.random.default_rng(38)
    pulses = [_pulse(echoes, rng) for echoes in FLIGHT]
    # a pulse whose low channel recorded two segments 100 ns apart, the gap unrecorded
    pulses.append(_pulse([(1005.0, 25.0), (1110.0, 12.0)], rng, windows=((990.0, 30), (1095.0, 30))))
    return write_pulsewaves(tmp_path_factory.mktemp("riegl") / "riegl_like.pls", RIEGL, RIEGL_TABLES, pulses)


def test_tables_are_read_as_decibels_with_no_value_below_detection(riegl_like):
    pw = open_pulsewaves(riegl_like)
    low, high = pw.lookup_tables[1], pw.lookup_tables[2]
    assert (low.unit, low.data_type, low.entries.size) == (1, 8, 256)
    assert low.description == "amplitude conversion table for low channel"
    assert high.description == "amplitude conversion table for high channel"
    assert low.decibels and high.decibels
    assert low.no_value.tolist() == [True] * 4 + [False] * 252
    power = low.power()
    assert power[:4].tolist() == [0.0] * 4  # below detection: no power, never -2e37
    assert power[4] == pytest.approx(10 ** -0.544, rel=1e-5) and power[255] == pytest.approx(10 ** 1.973, rel=1e-5)
    assert np.all(np.diff(power) >= 0) and high.power()[255] == pytest.approx(10 ** 3.971, rel=1e-5)
    assert low.saturation_code(8) == high.saturation_code(8) == 255


def test_one_waveform_a_pulse_in_power_from_the_channel_that_does_not_saturate(riegl_like):
    batch = read_pulses(riegl_like)
    assert len(batch) == len(FLIGHT) + 1 == np.unique(batch.pulse_id).size and not batch.rejected
    saturates = [max(p for _, p in echoes) + 0.6 > 10 ** 1.973 for echoes in FLIGHT]
    assert batch.channel[:len(FLIGHT)].tolist() == [0 if s else 1 for s in saturates]
    assert saturates.count(True) == 2
    assert np.isfinite(batch.samples).all() and batch.samples.min() >= 0.0
    assert batch.samples.max() < 10 ** 3.971 * 1.0001  # no 2.8e37: every sample is a power the table holds
    pw = open_pulsewaves(riegl_like)
    for row, echoes in enumerate(FLIGHT):
        y = batch.pulse_samples(row)
        table = pw.lookup_tables[2 if saturates[row] else 1]
        assert y.size == 60 and set(np.unique(y)) <= set(table.power())  # every sample a level's power
        assert (y == 0.0).any()  # codes 0-3 (below detection): zero power
        # the peak power as recorded, within the table's step (0.1-0.17 dB) and the background's noise
        assert y.max() == pytest.approx(max(p for _, p in echoes) + 0.35, rel=0.15), (row, y.max())


def test_segments_of_one_channel_join_into_one_waveform_at_their_times(riegl_like):
    batch = read_pulses(riegl_like)
    row = len(FLIGHT)
    y = batch.pulse_samples(row)
    assert batch.channel[row] == 1 and batch.segment[row] == 1  # one segment joined after the first
    assert y.size == 135  # 990..1019 and 1095..1124 ns on one grid
    gap = y[30:105]
    assert (gap == y.min()).all() and y.min() == 0.0  # unrecorded: below detection, the waveform's floor
    # each echo's peak sample lies where its time puts it along the beam
    t_ps = np.array([np.argmax(y[:30]), 105 + np.argmax(y[105:])]) * batch.sample_spacing_ps[row]
    xyz = geolocate(batch.anchor[[row, row]], batch.anchor_location_ps[[row, row]], batch.direction[[row, row]],
                    t_ps)
    np.testing.assert_allclose(ANCHOR[2] - xyz[:, 2], np.array([1005.0, 1110.0]) * STEP_M, atol=0.5 * STEP_M)


def test_the_engine_finds_every_echo_at_its_time(riegl_like):
    batch = read_pulses(riegl_like)
    config = DecompositionConfig(model=Model.GAUSSIAN)
    pulse = nominal_pulse(recorded_pulse_fwhm_ps(batch)[0])
    result = decompose_batch(pulse_waveforms(batch, seed=38), config, pulse, threads=1)
    kept = result.reject == 0
    for row, echoes in enumerate(FLIGHT):
        mine = kept & (result.echo_waveform == row)
        found = START_NS + result.position[mine] * batch.sample_spacing_ps[row] / 1000.0
        truth = np.array([t for t, _ in echoes])
        assert found.size == truth.size, (row, found, truth)
        np.testing.assert_allclose(np.sort(found), truth, atol=0.5)
        assert np.all(result.amplitude[mine] < 1.5 * max(p for _, p in echoes) + 1)


def test_info_says_what_each_table_converts_to(riegl_like):
    info = describe_file(riegl_like)
    low, high = info["lookup_tables"]
    assert low["converts"] == "decibels (unit 1) to power, 10^(dB/10)"
    assert low["no_value_codes"] == "0-3" and low["range"] == pytest.approx([-5.44, 19.73], abs=1e-3)
    assert high["range"] == pytest.approx([-1.46, 39.71], abs=1e-3)
    text = format_info(info)
    assert ("lookup table 1: 256 entries, amplitude conversion table for low channel: decibels (unit 1) to "
            "power, 10^(dB/10); codes 0-3 no value (below detection: power 0); codes 4-255 -5.44..19.73 dB"
            ) in text
    assert "used by returning channel 1 of descriptor 1" in text


def test_a_linear_table_is_applied_as_it_is_and_its_no_value_entries_are_zero(tmp_path):
    volts = np.r_[np.float32(np.nan), np.linspace(0.0, 2.55, 255)].astype(np.float32)
    samplings = [Sampling(2, 0, table=1, bits_duration=32, bits_segments=0)]
    codes = np.array([0, 1, 2, 100, 255], np.uint8)
    path = write_pulsewaves(tmp_path / "volts.pls", samplings,
                            {1: Table(0, "volts", volts, with_compression=False)}, [[[(1000.0, codes)]]])
    pw = open_pulsewaves(path)
    assert pw.lookup_tables[1].description == "volts" and not pw.lookup_tables[1].decibels
    batch = read_pulses(path)
    np.testing.assert_allclose(batch.samples, [0.0, 0.0, volts[2], volts[100], volts[255]])
    assert "linear (unit 0): values as given" in format_info(describe_file(path))


def test_a_range_of_a_file_with_tables_reads_its_planned_pulses(riegl_like):
    ranges = plan_point_ranges(riegl_like, 4)
    assert sum(r.n_pulses for r in ranges) == len(FLIGHT) + 1
    assert sum(len(read_pulses(r)) for r in ranges) == len(FLIGHT) + 1


def test_segments_off_one_sample_grid_reject_their_pulse_with_the_reason(tmp_path):
    rng = np.random.default_rng(5)
    good = _pulse([(1005.0, 25.0)], rng)
    off = _pulse([(1005.0, 25.0), (1110.0, 12.0)], rng, windows=((990.0, 30), (1095.5, 30)))  # half a sample off
    path = write_pulsewaves(tmp_path / "off.pls", RIEGL, RIEGL_TABLES, [good, off])
    batch = read_pulses(path)
    assert len(batch) == 1 and len(batch.rejected) == 1
    pulse_id, reason = batch.rejected[0]
    assert pulse_id >= 0 and pulse_id != batch.pulse_id[0]
    assert reason == ("off.pls: its 2 returning segments do not join into one waveform: they start 0, 105.5 "
                      "samples after the first, off one sample grid")
