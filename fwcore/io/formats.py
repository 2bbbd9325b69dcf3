"""The reading entry points, dispatching on the file's format: LAS/LAZ or PulseWaves.

    plan_point_ranges(path)  -> [PointRange]   every pulse in exactly one range
    read_pulses(range)       -> PulseBatch     the same record whatever the format
    describe_file(path)      -> dict           `fwl info`: headers and indexes only
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fwcore.io.records import PointRange, PulseBatch

PULSEWAVES_SIGNATURE = b"PulseWavesPulse"


def is_pulsewaves(path: str | Path) -> bool:
    """A .pls file, or any file that starts with the PulseWaves signature."""
    path = Path(path)
    if path.suffix.lower() == ".pls":
        return True
    try:
        with open(path, "rb") as f:
            return f.read(len(PULSEWAVES_SIGNATURE)) == PULSEWAVES_SIGNATURE
    except OSError:
        return False


# What a file is, by its first bytes (or name): a command given the wrong kind says which kind it got.
KINDS = ((b"LASF", "a LAS/LAZ file"), (PULSEWAVES_SIGNATURE, "a PulseWaves pulse file (.pls)"),
         (b"PulseWavesWaves", "a PulseWaves waves file (.wvs: the samples of the .pls beside it)"),
         (b"waveform_id,n_samples", "a NEON-layout waveform CSV"))
PACKET_SUFFIXES = {".wdp": "a LAS waveform packet file (.wdp: the samples of the .las beside it)",
                   ".wdz": "a LASzip waveform packet file (.wdz: the samples of the .laz beside it)"}


def file_kind(path: str | Path) -> str:
    """What a file is, in words ("a LAS/LAZ file", "a NEON-layout waveform CSV", ...; "an unknown kind of file")."""
    path = Path(path)
    if path.suffix.lower() in PACKET_SUFFIXES:
        return PACKET_SUFFIXES[path.suffix.lower()]
    try:
        with open(path, "rb") as f:
            head = f.read(64)
    except OSError:
        return "an unreadable file"
    for signature, kind in KINDS:
        if head.startswith(signature):
            return kind
    if not head:
        return "an empty file"
    try:
        if b"\0" in head:  # binary: a damaged header of some format, not text
            return "an unknown kind of file"
        head.decode("utf-8")
        return "a text file" + (" (CSV)" if b"," in head else "")
    except UnicodeDecodeError:
        return "an unknown kind of file"


def wrong_kind(path: str | Path, wanted: str) -> str:
    """ "PATH is a NEON-layout waveform CSV, not WANTED" with the command that reads it, where one does."""
    kind = file_kind(path)
    reader = {"a LAS/LAZ file": "fwl run reads it", "a PulseWaves pulse file (.pls)": "fwl run reads it",
              "a NEON-layout waveform CSV": "fwl decompose-csv reads it"}.get(kind)
    if kind.startswith(("a PulseWaves waves", "a LAS waveform", "a LASzip waveform")):
        reader = "give the file beside it"
    return f"{path} is {kind}, not {wanted}" + (f" ({reader})" if reader else "")


LAS_GLOBAL_ENCODING_AT = 6  # uint16 in the public header block; bit 2 (value 4): waveform packets external
LAS_EXTERNAL_PACKETS = 4


def packet_file(path: str | Path) -> Path | None:
    """The file beside `path` that holds its samples, if one is there: a LAS file's .wdp/.wdz, a PulseWaves
    file's .wvs (found as their readers find them)."""
    from fwcore.io.packets import external_packet_file
    from fwcore.io.pulsewaves import waves_file
    try:
        return waves_file(Path(path)) if is_pulsewaves(path) else external_packet_file(Path(path))
    except FileNotFoundError:
        return None


def needs_packet_file(path: str | Path) -> bool:
    """Whether the samples of `path` live in a file beside it: always for PulseWaves; for LAS, as the header's
    global encoding says (read from its bytes, so a file still being copied answers too)."""
    if is_pulsewaves(path):
        return True
    try:
        with open(path, "rb") as f:
            head = f.read(LAS_GLOBAL_ENCODING_AT + 2)
    except OSError:
        return False
    if len(head) < LAS_GLOBAL_ENCODING_AT + 2 or head[:4] != b"LASF":
        return False  # not LAS (yet): whoever opens it says what is wrong
    return bool(int.from_bytes(head[LAS_GLOBAL_ENCODING_AT:], "little") & LAS_EXTERNAL_PACKETS)


def open_input(path: str | Path):
    """The opened header of either format (WaveformFile or PulseWavesFile); errors name the file."""
    if is_pulsewaves(path):
        from fwcore.io.pulsewaves import open_pulsewaves
        return open_pulsewaves(path)
    from fwcore.io.reader import open_waveform_file
    return open_waveform_file(path)


@dataclasses.dataclass(frozen=True)
class InputSummary:
    """What a run needs to know of a file before reading it."""

    records: int  # point records (LAS) or pulse records (PulseWaves) present
    adjusted_standard_gps_time: bool  # LAS global encoding bit: GPS time - 1e9 s; otherwise week seconds or absolute


def input_summary(path: str | Path) -> InputSummary:
    """Record count and GPS time type of either format, from its header."""
    opened = open_input(path)
    if is_pulsewaves(path):
        return InputSummary(opened.point_count, False)
    import laspy
    with laspy.open(path) as reader:
        adjusted = int(reader.header.global_encoding.gps_time_type) == 1
    return InputSummary(opened.point_count, adjusted)


def crs_wkt(path: str | Path) -> str | None:
    """The file's coordinate reference system as OGC WKT (LAS: WKT record or GeoTIFF keys; PulseWaves: keys,
    or Earth-centred by magnitude), None when it names none."""
    if is_pulsewaves(path):
        from fwcore.io.pulsewaves import open_pulsewaves
        return open_pulsewaves(path).crs_wkt
    import laspy

    from fwcore.io.crs import las_crs_wkt
    with laspy.open(path) as reader:
        return las_crs_wkt(reader.header)[0]


def plan_point_ranges(path: str | Path, points_per_range: int = 10_000) -> list[PointRange]:
    """Ranges of a file's records (LAS points, PulseWaves pulses), each pulse in exactly one."""
    if is_pulsewaves(path):
        from fwcore.io.pulsewaves import plan_pulse_ranges
        return plan_pulse_ranges(path, points_per_range)
    from fwcore.io.reader import plan_point_ranges as plan_las
    return plan_las(path, points_per_range)


def read_pulses(point_range: PointRange | str | Path, wf=None) -> PulseBatch:
    """The pulses of a range (or of a whole file, given its path)."""
    path = point_range.path if isinstance(point_range, PointRange) else point_range
    if is_pulsewaves(path):
        from fwcore.io.pulsewaves import read_pulsewaves
        return read_pulsewaves(point_range, wf)
    from fwcore.io.reader import read_pulses as read_las
    return read_las(point_range, wf)


def describe_file(path: str | Path) -> dict:
    """What `fwl info` prints: format, counts, descriptors and their use, packets, CRS, bounds, times."""
    if is_pulsewaves(path):
        from fwcore.io.pulsewaves import describe_pulsewaves
        return describe_pulsewaves(path)
    from fwcore.io.info import describe_las
    return describe_las(path)
