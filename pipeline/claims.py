"""Which files a command other than `fwl run` may write: its earlier output, or anything with --overwrite.

One rule for every command that writes: it writes over nothing that is not its own earlier output (exit 2,
nothing touched), unless the user says --overwrite; and an output named with a suffix is written in the
format that suffix names. Ours is what carries fwl's mark: a run's folder its manifest (pipeline.outputs), a folder of
another command the same manifest naming that command, a Parquet file fwl's metadata, and the files written
beside a first one (a simulated flight's) that first one's mark.

    check_suffix(command, path, suffixes, what)   the suffix names the format written there
    claim_files(command, files, ours, overwrite)  single files: refused unless ours(path) or --overwrite
    claim_command_folder / record_command_folder  a folder of several files, and its manifest

A run's own folder is pipeline.outputs'.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.layout import MANIFEST
from pipeline.outputs import OutputFolderError, files_under, write_atomically

OVERWRITE_HINT = "choose another --output, or give --overwrite to replace it"


def check_suffix(command: str, path: str | Path, suffixes: tuple[str, ...], what: str) -> Path:
    """`path` if its suffix is one of `suffixes` (what the command writes there), else OutputFolderError."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise OutputFolderError(f"{command}: --output {path}: writes {what}, so its name ends "
                                f"{' or '.join(suffixes)}, not {path.suffix or 'without a suffix'}")
    return path


def parquet_is_ours(path: Path) -> bool:
    """A Parquet file fwl wrote: its schema metadata carries an fwlidar.* key."""
    import pyarrow.parquet as pq  # here: the command line starts without pyarrow
    try:
        metadata = pq.read_schema(path).metadata or {}
    except Exception:  # not Parquet, or damaged: not ours to replace
        return False
    return any(k.startswith(b"fwlidar.") for k in metadata)


def first_line_is(path: Path, first: str) -> bool:
    """A text file whose first line starts with what fwl writes there."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().startswith(first)
    except (OSError, UnicodeDecodeError):
        return False


def claim_files(command: str, files: list[Path], ours, overwrite: bool) -> None:
    """Refuse (OutputFolderError, before anything is written) to write the files `files` if any of them exists and
    is not `command`'s earlier output (`ours(path)`), unless `overwrite`; a folder in a file's place always."""
    there = [f for f in files if f.exists() or f.is_symlink()]
    folders = [f for f in there if f.is_dir()]
    if folders:
        raise OutputFolderError(f"{command}: {folders[0]} is a folder, where a file would be written; "
                                f"choose another --output")
    foreign = [f for f in there if not overwrite and (f.is_symlink() or not ours(f))]
    if foreign:
        raise OutputFolderError(f"{command}: {', '.join(map(str, foreign))}: exists and is not an earlier output "
                                f"of {command}; {OVERWRITE_HINT}")


def claim_command_folder(command: str, folder: Path, overwrite: bool) -> None:
    """A folder `command` writes several files into: new, empty, or holding only its earlier output (a manifest
    naming the command, and the files it lists), unless `overwrite` (which replaces same-named files only)."""
    if not folder.exists():
        return
    if not folder.is_dir():
        raise OutputFolderError(f"{command}: {folder}: exists and is not a folder; choose another --output")
    files = [str(f) for f in files_under(folder)]
    if not files or overwrite:
        return
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        listed, by = set(manifest["files"]), manifest["written_by"]
    except (OSError, ValueError, KeyError, TypeError):
        listed, by = set(), None
    foreign = [f for f in files if by != command or (f != MANIFEST and f not in listed)]
    if foreign:
        shown = ", ".join(foreign[:5]) + (" ..." if len(foreign) > 5 else "")
        raise OutputFolderError(f"{command}: {folder}: holds files that {command} did not write: {shown}; "
                                f"{OVERWRITE_HINT}")


def record_command_folder(command: str, folder: Path, files: list[str]) -> None:
    """The manifest of a folder `command` wrote: which files are its own (claim_command_folder reads it)."""
    earlier: list[str] = []
    if (folder / MANIFEST).is_file():
        try:
            manifest = json.loads((folder / MANIFEST).read_text())
        except ValueError:
            manifest = {}
        if manifest.get("written_by", command) != command:  # another command's (--overwrite): its mark stays
            return
        earlier = manifest.get("files", [])
    kept = sorted(f for f in set(earlier) | set(files) if (folder / f).is_file())
    write_atomically(folder / MANIFEST, json.dumps({"written_by": command, "files": kept}, indent=2) + "\n")
