"""The formats read, as a table: one entry per format (LAS/LAZ, PulseWaves, GEDI L1B, LVIS L1B, NEON CSV) with what
it can do, and the entry points that look a file's format up in it instead of branching on it.

    format_of(path)          -> Format         by the file's first bytes (and name)
    kind_of(path)            -> Kind           what any file is (its Format, if one reads it), for messages
    plan_point_ranges(path)  -> [PointRange]   every pulse in exactly one range
    read_pulses(range)       -> PulseBatch     the same record whatever the format
    input_summary(path)      -> InputSummary   what a run needs before reading
    input_crs(path, given)   -> InputCrs       the CRS every output writes: --crs, else the format's (Format.crs)
    describe_file(path)      -> dict           `fwl info`: headers and indexes only

The readers (las.py, neon.py, ...) do not import this table: given a file of another kind, they raise a
ForeignFileError (fwcore.io.errors), which the table's entries raise again saying what the file is instead.
"""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path
from typing import Any, Callable

from fwcore.io.crs import GIVEN, crs_name, las_crs_wkt, parse_crs
from fwcore.io.errors import ForeignFileError, WaveformFileError
from fwcore.io.records import PointRange, PulseBatch
from fwcore.io.signatures import HDF5_SIGNATURE, LAS_SIGNATURE, NEON_CSV_HEADER, PULSE_SIGNATURE, WAVES_SIGNATURE


@dataclasses.dataclass(frozen=True)
class Kind:
    """What a file is, from its first bytes (or its name): the format that reads it (None: no format fwl reads),
    and in words, for messages only ("a LAS/LAZ file", "a NEON-layout waveform CSV", ...)."""

    words: str
    format: "Format | None" = None
    text: bool = False  # text: a CSV of another layout, a note
    beside: bool = False  # the samples of the file beside it, which is the one to give


UNREADABLE, EMPTY = Kind("an unreadable file"), Kind("an empty file")
TEXT, CSV_TEXT = Kind("a text file", text=True), Kind("a text file (CSV)", text=True)
FOREIGN_BINARY = Kind("a binary file of no format fwl reads")
FOREIGN_HDF5 = Kind("an HDF5 file of no layout fwl reads (GEDI L2A and L2B granules hold no waveforms: give the "
                    "L1B)")
WAVES_FILE = Kind("a PulseWaves waves file (.wvs: the samples of the .pls beside it)", beside=True)
WDP_FILE = Kind("a LAS waveform packet file (.wdp: the samples of the .las beside it)", beside=True)
WDZ_FILE = Kind("a LASzip waveform packet file (.wdz: the samples of the .laz beside it)", beside=True)
SAMPLE_SUFFIXES = {".wdp": WDP_FILE, ".wdz": WDZ_FILE}
_CONTROL = bytes(set(range(32)) - {9, 10, 12, 13})  # bytes no text holds (tab, newlines, form feed do)


def _is_text(head: bytes) -> bool:
    """UTF-8 without control bytes; a character cut at the end of `head` is still text."""
    if any(b in _CONTROL for b in head):
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        return err.reason == "unexpected end of data" and err.start >= len(head) - 3
    return True


def kind_of(path: str | Path) -> Kind:
    """What a file is, from one read of its first 64 bytes (a packet file by its name)."""
    path = Path(path)
    if path.suffix.lower() in SAMPLE_SUFFIXES:
        return SAMPLE_SUFFIXES[path.suffix.lower()]
    try:
        with open(path, "rb") as f:
            head = f.read(64)
    except OSError:
        return UNREADABLE
    head = head.removeprefix(b"\xef\xbb\xbf")  # a CSV saved with a byte-order mark
    for fmt in FORMATS:
        if head.startswith(fmt.signature) and (fmt.sniff is None or fmt.sniff(path)):
            return Kind(fmt.kind, fmt)
    if head.startswith(HDF5_SIGNATURE):
        return FOREIGN_HDF5
    if head.startswith(WAVES_SIGNATURE):
        return WAVES_FILE
    if not head:
        return EMPTY
    if head[2:11] == b"LASF_Spec":  # a .wdp's: the header of the record that holds its packets
        return WDP_FILE
    return (CSV_TEXT if b"," in head else TEXT) if _is_text(head) else FOREIGN_BINARY


def wrong_kind(path: str | Path, wanted: str) -> str:
    """ "PATH is a NEON-layout waveform CSV, not WANTED" with the command that reads it, where one does."""
    kind = kind_of(path)
    reader = f"{kind.format.reads_with} reads it" if kind.format else "give the file beside it" if kind.beside else None
    return f"{path} is {kind.words}, not {wanted}" + (f" ({reader})" if reader else "")


LAS_GLOBAL_ENCODING_AT = 6  # uint16 in the public header block; bit 2 (value 4): waveform packets external
LAS_EXTERNAL_PACKETS = 4


def packet_file(path: str | Path) -> Path | None:
    """The file beside `path` that holds its samples, if one is there: a LAS file's .wdp/.wdz, a PulseWaves
    file's .wvs (found as their readers find them)."""
    beside = format_of(path).samples_beside
    try:
        return beside(Path(path)) if beside else None
    except FileNotFoundError:
        return None


def needs_packet_file(path: str | Path) -> bool:
    """Whether the samples of `path` live in a file beside it: always for PulseWaves; for LAS, as the header's
    global encoding says (read from its bytes, so a file still being copied answers too)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(PULSE_SIGNATURE))
    except OSError:
        head = b""
    if path.suffix.lower() in PULSEWAVES.suffixes or head.startswith(PULSE_SIGNATURE):
        return True
    if len(head) < LAS_GLOBAL_ENCODING_AT + 2 or not head.startswith(LAS_SIGNATURE):
        return False  # not LAS (yet): whoever opens it says what is wrong
    return bool(int.from_bytes(head[LAS_GLOBAL_ENCODING_AT:LAS_GLOBAL_ENCODING_AT + 2], "little")
                & LAS_EXTERNAL_PACKETS)


@dataclasses.dataclass(frozen=True)
class InputSummary:
    """What a run needs to know of a file before reading it."""

    records: int  # point records (LAS) or pulse records (PulseWaves) present
    adjusted_standard_gps_time: bool  # LAS global encoding bit: GPS time - 1e9 s; otherwise week seconds or absolute


@dataclasses.dataclass(frozen=True)
class Format:
    """One input format, as data: how a file shows it, and what each entry point does with it (None: it cannot).

    open(path) -> the opened header; plan(path, points_per_range, opened) -> [PointRange];
    read(range_or_path, opened) -> PulseBatch; summary(path, opened) -> InputSummary;
    crs(path, opened) -> (WKT or None, where it came from); describe(path) -> dict; samples_beside(path) -> the
    file holding its samples.
    """

    name: str
    kind: str  # what a file of it is, in words: for messages only
    signature: bytes  # its files' first bytes
    reads_with: str  # the command that takes it
    open: Callable[[Path], Any]
    describe: Callable[[Path], dict]
    suffixes: tuple[str, ...] = ()  # names that say the format whatever the first bytes (lower case)
    plan: Callable[..., list[PointRange]] | None = None
    read: Callable[..., PulseBatch] | None = None
    summary: Callable[..., InputSummary] | None = None
    crs: Callable[..., tuple[str | None, str]] | None = None
    samples_beside: Callable[[Path], Path | None] | None = None
    sniff: Callable[[Path], bool] | None = None  # for a signature several formats share (HDF5): is it this one?


def _lazy(module: str, name: str) -> Callable:
    """A format's function, imported when first called: the formats' modules load only for the files read."""
    def call(*args, **kwargs):
        return getattr(importlib.import_module(module), name)(*args, **kwargs)
    return call


def _named(call: Callable, message: Callable[[ForeignFileError, Kind], str]) -> Callable:
    """A reader's entry point whose ForeignFileError (a file of another kind) is raised again with `message`:
    what the file is instead, from its first bytes (kind_of)."""
    def named(*args, **kwargs):
        try:
            return call(*args, **kwargs)
        except ForeignFileError as err:
            raise type(err)(message(err, kind_of(err.path)), err.path, err.wanted, err.detail) from None
    return named


def _not_las(err: ForeignFileError, kind: Kind) -> str:
    if kind is FOREIGN_BINARY:  # random bytes, or a LAS whose signature is damaged
        return f"{err.path}: not a readable LAS/LAZ file: {kind.words} ({err.detail})"
    return wrong_kind(err.path, err.wanted)  # a known other kind (text, CSV, packets): say which


def _not_neon_csv(err: ForeignFileError, kind: Kind) -> str:
    # a text file of another layout, or NEON's with a damaged header: the reader's own message says it
    return str(err) if kind.text or kind.format is NEON_CSV else wrong_kind(err.path, err.wanted)


def _las_plan(path, points_per_range, opened=None):
    return _lazy("fwcore.io.las", "plan_las_ranges")(path, points_per_range, wf=opened)


def _las_summary(path, opened=None):
    opened = opened or LAS.open(path)
    return InputSummary(opened.point_count, opened.adjusted_standard_gps_time)


def _las_crs(path, opened=None):
    import laspy

    with laspy.open(path) as reader:  # the header alone: a file that is not a full-waveform file has one too
        return las_crs_wkt(reader.header)


def _pw_summary(path, opened=None):
    return InputSummary((opened or PULSEWAVES.open(path)).point_count, False)


def _pw_crs(path, opened=None):
    return _opened_crs(opened or PULSEWAVES.open(path))


def _opened_crs(opened) -> tuple[str | None, str]:
    """(WKT, where it came from) of an opened file that read its CRS with its header (PulseWaves, GEDI, LVIS)."""
    return opened.crs_wkt, opened.crs_source


def _neon_describe(path):
    waveforms = NEON_CSV.open(path)
    lengths = [len(s) for s in waveforms.samples]
    return {"file": str(path), "format": "NEON waveform CSV", "waveforms": len(lengths),
            "samples": {"min": min(lengths), "max": max(lengths)}, "problems": []}


LAS = Format(name="LAS/LAZ", kind="a LAS/LAZ file", signature=LAS_SIGNATURE, reads_with="fwl run",
             open=_named(_lazy("fwcore.io.las", "open_waveform_file"), _not_las),
             describe=_named(_lazy("fwcore.io.info", "describe_las"), _not_las), plan=_named(_las_plan, _not_las),
             read=_named(_lazy("fwcore.io.las", "read_las_pulses"), _not_las), summary=_las_summary, crs=_las_crs,
             samples_beside=lambda path: _lazy("fwcore.io.packets", "external_packet_file")(Path(path)))
PULSEWAVES = Format(name="PulseWaves", kind="a PulseWaves pulse file (.pls)", signature=PULSE_SIGNATURE,
                    reads_with="fwl run", open=_lazy("fwcore.io.pulsewaves", "open_pulsewaves"),
                    describe=_lazy("fwcore.io.info", "describe_pulsewaves"), suffixes=(".pls",),
                    plan=_lazy("fwcore.io.pulsewaves", "plan_pulse_ranges"),
                    read=_lazy("fwcore.io.pulsewaves", "read_pulsewaves"), summary=_pw_summary, crs=_pw_crs,
                    samples_beside=lambda path: _lazy("fwcore.io.pulsewaves", "waves_file")(Path(path)))
NEON_CSV = Format(name="NEON waveform CSV", kind="a NEON-layout waveform CSV", signature=NEON_CSV_HEADER,
                  reads_with="fwl decompose-csv", open=_named(_lazy("fwcore.io.neon", "read_neon_csv"), _not_neon_csv),
                  describe=_neon_describe)
GEDI_L1B = Format(name="GEDI L1B", kind="a GEDI L1B granule (HDF5)", signature=HDF5_SIGNATURE, reads_with="fwl run",
                  open=_lazy("fwcore.io.gedi", "open_gedi"), describe=_lazy("fwcore.io.gedi", "describe_gedi"),
                  plan=_lazy("fwcore.io.gedi", "plan_gedi_ranges"), read=_lazy("fwcore.io.gedi", "read_gedi"),
                  summary=lambda path, opened=None: InputSummary((opened or GEDI_L1B.open(path)).point_count, False),
                  crs=lambda path, opened=None: _opened_crs(opened or GEDI_L1B.open(path)),
                  sniff=_lazy("fwcore.io.gedi", "is_gedi_l1b"))
LVIS_L1B = Format(name="LVIS L1B", kind="an LVIS L1B waveform file (HDF5)", signature=HDF5_SIGNATURE,
                  reads_with="fwl run", open=_lazy("fwcore.io.lvis", "open_lvis"),
                  describe=_lazy("fwcore.io.lvis", "describe_lvis"), plan=_lazy("fwcore.io.lvis", "plan_lvis_ranges"),
                  read=_lazy("fwcore.io.lvis", "read_lvis"),
                  summary=lambda path, opened=None: InputSummary((opened or LVIS_L1B.open(path)).point_count, False),
                  crs=lambda path, opened=None: _opened_crs(opened or LVIS_L1B.open(path)),
                  sniff=_lazy("fwcore.io.lvis", "is_lvis_l1b"))
FORMATS = (LAS, PULSEWAVES, GEDI_L1B, LVIS_L1B, NEON_CSV)


def format_of(path: str | Path) -> Format:
    """The format of a file by its name (.pls) or first bytes; LAS otherwise, whose opener names what else a
    file is."""
    by_name = [fmt for fmt in FORMATS if Path(path).suffix.lower() in fmt.suffixes]
    return by_name[0] if by_name else kind_of(path).format or LAS


def _able(fmt: Format, path, what: str):
    action = getattr(fmt, what)
    if action is None:
        raise WaveformFileError(f"{path} is {kind_of(path).words}, not a flight line of full waveforms: give it to "
                                f"{fmt.reads_with}")
    return action


def open_input(path: str | Path):
    """The opened header of either flight-line format (WaveformFile or PulseWavesFile); errors name the file."""
    fmt = format_of(path)
    _able(fmt, path, "plan")
    return fmt.open(path)


def input_summary(path: str | Path, opened=None) -> InputSummary:
    """Record count and GPS time type, from the header (`opened`, when the caller has it open)."""
    fmt = format_of(path)
    return _able(fmt, path, "summary")(path, opened)


def crs_wkt(path: str | Path, opened=None) -> str | None:
    """The file's coordinate reference system as OGC WKT (LAS: WKT record or GeoTIFF keys; PulseWaves: keys,
    or Earth-centred by magnitude), None when it names none."""
    fmt = format_of(path)
    return _able(fmt, path, "crs")(path, opened)[0]


@dataclasses.dataclass(frozen=True)
class InputCrs:
    """An input's CRS as the outputs write it: OGC WKT (None: unknown), where it came from, and whether it names a
    CRS (an EPSG code, a WKT record, --crs) rather than only a unit (an unnamed CRS) or nothing."""

    wkt: str | None
    source: str
    named: bool

    @property
    def name(self) -> str | None:
        return crs_name(self.wkt)


def input_crs(path: str | Path, given: str | None = None) -> InputCrs:
    """The one answer to "the CRS of this input" that every output (LAS, GeoParquet, MCAP, COPC) writes: `given`
    (--crs, as fwcore.io.crs.parse_crs reads it) overrides what the file says, as PDAL's override_srs; else its
    format's (Format.crs: a WKT record, GeoTIFF keys with a code or only a unit, PulseWaves' Earth-centred
    coordinates)."""
    if given:
        return InputCrs(parse_crs(given), GIVEN, True)
    try:
        fmt = format_of(path)
        wkt, source = _able(fmt, path, "crs")(path)
    except Exception as err:  # noqa: BLE001  damaged CRS records: the CRS is unknown, not invented; the file may run
        return InputCrs(None, f"unreadable ({type(err).__name__}: {err})", False)
    return InputCrs(wkt, source, bool(wkt) and "unnamed CRS" not in source)


def plan_point_ranges(path: str | Path, points_per_range: int = 10_000, opened=None) -> list[PointRange]:
    """Ranges of a file's records (LAS points, PulseWaves pulses), each pulse in exactly one."""
    fmt = format_of(path)
    return _able(fmt, path, "plan")(path, points_per_range, opened)


def read_pulses(point_range: PointRange | str | Path, wf=None) -> PulseBatch:
    """The pulses of a range (or of a whole file, given its path)."""
    path = point_range.path if isinstance(point_range, PointRange) else point_range
    fmt = format_of(path)
    return _able(fmt, path, "read")(point_range, wf)


def describe_file(path: str | Path) -> dict:
    """What `fwl info` prints: format, counts, descriptors and their use, packets, CRS, bounds, times."""
    return format_of(path).describe(path)
