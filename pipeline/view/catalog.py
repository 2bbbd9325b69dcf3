"""What the viewer may read: the folders and files it was started on, the runs and inputs under them.

Every path a request names is an id relative to one of these roots; it is
resolved and checked to stay inside its root before anything is opened, so a
request can never reach another file of the machine (`..` and absolute paths
are refused, and so are symbolic links that leave the root, except an input
file linked into a viewed folder: whoever put the link there shares that
file, and the viewer follows it to decompose it).
"""

from __future__ import annotations

import dataclasses
import functools
import glob
import os
from collections.abc import Iterator
from pathlib import Path

from pipeline.layout import ECHOES, RUN_JSON
from pipeline.outputs import INPUT_SUFFIXES, is_complete, read_run


class OutsideRoots(PermissionError):
    """A request named a path outside the folders the viewer was started on."""


def is_complete_run(folder: Path) -> bool:
    """A finished run (`fwl run` writes run.json last) with an echo table to show."""
    return is_complete(folder) and (folder / ECHOES).is_dir()


@dataclasses.dataclass(frozen=True)
class Roots:
    """The folders (searched for runs and inputs) and single input files the viewer serves."""

    folders: tuple[Path, ...]
    files: tuple[Path, ...] = ()

    @classmethod
    def from_paths(cls, paths: list[str | Path], runs_dir: str | Path) -> "Roots":
        folders, files = [], []
        for p in map(Path, paths):
            if p.is_dir():
                folders.append(p.resolve())
            elif p.is_file() and p.suffix.lower() in INPUT_SUFFIXES:
                files.append(p.resolve())
            elif p.is_file():
                raise ValueError(f"{p}: not a run folder nor a .las/.laz/.pls input")
            else:
                raise FileNotFoundError(f"{p}: no such file or folder")
        runs = Path(runs_dir).resolve()
        if not any(runs == f or runs.is_relative_to(f) for f in folders):
            folders.append(runs)  # where the runs of picked inputs are written, so they can be shown
        return cls(tuple(folders), tuple(files))

    # ------------------------------------------------------------ ids <-> paths

    def id_of(self, path: Path) -> str:
        """The id of a path under the roots: by its own name first (a link inside a folder keeps its place),
        then by where it resolves to."""
        for candidate in (Path(os.path.abspath(path)), path.resolve()):
            for i, f in enumerate(self.files):
                if candidate == f:
                    return f"f{i}"
            for i, root in enumerate(self.folders):
                if candidate == root or candidate.is_relative_to(root):
                    rel = candidate.relative_to(root).as_posix()
                    return f"{i}/{'' if rel == '.' else rel}"
        raise OutsideRoots(f"{path} is outside the viewer's folders")

    def path_of(self, ident: str, follow_link: bool = False) -> Path:
        """The path an id names, refused unless it stays inside its root after resolving links and `..`
        (with follow_link, a file linked into the root is its link's path)."""
        head, _, rest = str(ident).partition("/")
        if head.startswith("f") and not rest:
            try:
                return self.files[int(head[1:])]
            except (ValueError, IndexError):
                raise OutsideRoots(f"{ident!r} names no input the viewer was started on") from None
        try:
            root = self.folders[int(head)]
        except (ValueError, IndexError):
            raise OutsideRoots(f"{ident!r} names no folder the viewer was started on") from None
        if Path(rest).is_absolute() or "\\" in rest:
            raise OutsideRoots(f"{ident!r}: absolute paths are refused")
        path = (root / rest).resolve()
        if path != root and not path.is_relative_to(root):
            linked = root / rest
            if follow_link and ".." not in Path(rest).parts and linked.is_symlink() and linked.is_file():
                return linked
            raise OutsideRoots(f"{ident!r} leaves the viewer's folders")
        return path

    def run_of(self, ident: str) -> Path:
        path = self.path_of(ident)
        if not is_complete_run(path):
            raise FileNotFoundError(f"{ident!r} is not a complete run folder (no run.json)")
        return path

    def input_of(self, ident: str) -> Path:
        path = self.path_of(ident, follow_link=True)
        if not (path.is_file() and path.suffix.lower() in INPUT_SUFFIXES):
            raise FileNotFoundError(f"{ident!r} is not a .las/.laz/.pls input")
        return path

    # ------------------------------------------------------------ listing

    def runs(self) -> list[Path]:
        found = set()
        for root in self.folders:
            for marker in files_under(root, RUN_JSON):
                folder = marker.parent.resolve()
                if folder.is_relative_to(root) and is_complete_run(folder):
                    found.add(folder)
        return sorted(found)

    def inputs(self) -> list[Path]:
        """Waveform inputs: the files given, and those under the folders outside any run folder
        (a run's las/ holds decomposed point clouds, not waveforms)."""
        runs = self.runs()
        found = set(self.files)
        for root in self.folders:
            for path in files_under(root):
                if (path.suffix.lower() in INPUT_SUFFIXES and path.is_file()
                        and not any(path.is_relative_to(r) for r in runs)
                        and _has_waveforms(path, _mtime_ns(path))):
                    found.add(path)  # a link keeps its own name and place in the folder
        return sorted(found)


def files_under(root: Path, named: str | None = None) -> Iterator[Path]:
    """Every file (and link) under `root`, or those `named` so, not entering linked folders. A folder that
    vanishes while it is walked (a running job's temporary files) is skipped: listing must not fail because a
    run is writing."""
    for parent, _folders, names in os.walk(root, followlinks=False):
        for name in names:
            if named is None or name == named:
                yield Path(parent) / name


def _mtime_ns(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:  # gone since it was listed: _has_waveforms then finds nothing to read
        return -1


@functools.lru_cache(maxsize=4096)
def _has_waveforms(path: Path, mtime_ns: int) -> bool:
    """PulseWaves always; LAS/LAZ only with a waveform point format (4, 5, 9, 10)."""
    if path.suffix.lower() == ".pls":
        return True
    if path.suffix.lower() == ".h5":  # a GEDI or LVIS L1B granule; L2A and L2B hold no waveforms
        from pipeline.outputs import is_flight_line
        return is_flight_line(path)
    import laspy
    try:
        with laspy.open(path) as f:
            return f.header.point_format.id in (4, 5, 9, 10)
    except Exception:  # an unreadable file is not offered; `fwl run` would say why
        return False


def run_summary(folder: Path) -> dict:
    return read_run(folder)


def run_inputs(folder: Path) -> dict[str, Path]:
    """The run's local input files by name (the echo tables' source_file), from run.json."""
    named = {}
    for entry in run_summary(folder).get("inputs", []):
        if isinstance(entry, dict):  # {path, name, ...}: the name the run's tables use
            if "://" not in entry["path"]:
                named[entry["name"]] = Path(entry["path"])
            continue
        for match in sorted(glob.glob(entry)) if "://" not in entry else []:  # runs before names: patterns
            named.setdefault(Path(match).name, Path(match))
    return named
