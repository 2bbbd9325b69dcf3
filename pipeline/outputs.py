"""The output folder of a run: which inputs, under which names, which files are ours, and run.json.

A run never removes what it did not write. It takes a folder that is new,
empty, or holds only an earlier run's outputs, which it knows by the manifest
(fwl-output.json) it writes before anything else. run.json is written last:
a folder without it holds an incomplete run.
"""

from __future__ import annotations

import dataclasses
import datetime
import glob
import json
import os
from pathlib import Path, PurePosixPath

MANIFEST = "fwl-output.json"
RUN_JSON = "run.json"
# the folders a run writes into; nothing else under the output folder is ours
OUTPUT_DIRS = ("echoes", "pulses", "rejected", "las", "mcap", "logs", "parts")  # parts: per-range LAS/MCAP
INPUT_SUFFIXES = (".las", ".laz", ".pls")  # what a folder given as input is expanded to


class OutputFolderError(ValueError):
    """The output folder holds something a run did not write, or cannot be used."""


class IncompleteRunError(ValueError):
    """A folder without run.json: its run did not finish (or it is not a run's folder)."""


# ---------------------------------------------------------------- inputs

def expand_inputs(inputs: list[str]) -> list[str]:
    """Files, glob patterns and folders (their *.las, *.laz and *.pls, not recursive) -> sorted distinct paths.

    Local paths are resolved; anything that matches nothing is an error naming it.
    """
    paths: list[str] = []
    for item in inputs:
        if "://" in item:
            from apache_beam.io.filesystems import FileSystems
            found = [m.path for r in FileSystems.match([item]) for m in r.metadata_list]
        elif Path(item).is_dir():
            found = [str(p) for p in Path(item).iterdir() if p.is_file() and p.suffix.lower() in INPUT_SUFFIXES]
            if not found:
                raise FileNotFoundError(f"{item}: folder holds no .las or .laz file (nor .pls)")
        elif glob.has_magic(item):
            found = [p for p in glob.glob(item) if Path(p).is_file()]
        else:
            found = [item] if Path(item).is_file() else []
        if not found:
            raise FileNotFoundError(f"{item}: no file matches this input")
        paths.extend(p if "://" in p else str(Path(p).resolve()) for p in found)
    return sorted(set(paths))


@dataclasses.dataclass(frozen=True)
class InputNames:
    """Each input's name (in tables, rejected rows, run.json) and output stem (in file names), both unique.

    The name is the file name, or, when inputs share a file name, the shortest tail of the path that
    tells them apart (flightA/leica_a.las). The stem is the name without extension, '/' as '__'
    (flightA__leica_a), keeping the extension where stems would collide (x.las and x.laz: x.las, x.laz).
    """

    names: dict[str, str]  # path -> name
    stems: dict[str, str]  # name -> stem

    @classmethod
    def of(cls, paths: list[str]) -> "InputNames":
        parts = {p: PurePosixPath(p.split("://", 1)[-1]).parts for p in paths}
        names: dict[str, str] = {}
        for p in paths:
            for k in range(1, len(parts[p]) + 1):
                tail = parts[p][-k:]
                if sum(1 for q in paths if parts[q][-k:] == tail) == 1:
                    break
            names[p] = "/".join(tail)
        plain = {n: str(PurePosixPath(n).with_suffix("")).replace("/", "__") for n in names.values()}
        stems = {n: (s if list(plain.values()).count(s) == 1 else n.replace("/", "__")) for n, s in plain.items()}
        return cls(names, stems)

    def name(self, path: str) -> str:
        return self.names.get(path) or Path(path).name

    def stem(self, name: str) -> str:
        return self.stems.get(name) or Path(name).stem


# ---------------------------------------------------------------- the folder

def _is_ours(relative: PurePosixPath, stems: set[str], listed: set[str]) -> bool:
    """A file of an earlier run: listed in its run.json, or in one of our folders and named after its inputs."""
    if str(relative) in listed or str(relative) in (MANIFEST, RUN_JSON):
        return True
    if len(relative.parts) < 2 or relative.parts[0] not in OUTPUT_DIRS:
        return False
    name = relative.name
    return relative.parts[0] == "logs" or any(name.startswith(s + ".") or name.startswith(s + "-") for s in stems)


def _files_under(folder: Path) -> list[PurePosixPath]:
    out = []
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        for f in sorted(files):
            out.append(PurePosixPath(Path(root, f).relative_to(folder).as_posix()))
        for d in dirs:  # a symlinked folder is not followed, and not ours
            if Path(root, d).is_symlink():
                out.append(PurePosixPath(Path(root, d).relative_to(folder).as_posix()))
    return out


def earlier_run_files(folder: Path) -> list[PurePosixPath]:
    """The files of an earlier run in `folder`; OutputFolderError if it holds anything else."""
    if not folder.exists():
        return []
    if not folder.is_dir():
        raise OutputFolderError(f"{folder}: exists and is not a folder")
    files = _files_under(folder)
    if not files and not any(folder.iterdir()):
        return []
    manifest = folder / MANIFEST
    if not manifest.is_file():
        shown = ", ".join(str(f) for f in files[:5]) + (" ..." if len(files) > 5 else "")
        raise OutputFolderError(f"{folder}: not empty and not an fwl run output folder (no {MANIFEST}); it holds "
                                f"{shown or 'empty folders'}. Choose a new or empty folder: fwl run removes only "
                                f"what an earlier run wrote")
    try:
        stems = {i["stem"] for i in json.loads(manifest.read_text())["inputs"]}
    except (ValueError, KeyError, TypeError) as err:
        raise OutputFolderError(f"{manifest}: unreadable manifest ({err}); remove the folder yourself") from None
    listed: set[str] = set()
    if (folder / RUN_JSON).is_file():
        try:
            listed = set(json.loads((folder / RUN_JSON).read_text()).get("files", []))
        except ValueError:
            pass  # a damaged run.json lists nothing; the names decide
    foreign = [f for f in files if Path(folder, f).is_symlink() or not _is_ours(f, stems, listed)]
    foreign += [PurePosixPath(p.name) for p in folder.iterdir()
                if p.is_dir() and p.name not in OUTPUT_DIRS and not any(f.parts[0] == p.name for f in files)]
    if foreign:
        shown = ", ".join(str(f) for f in foreign[:5]) + (" ..." if len(foreign) > 5 else "")
        raise OutputFolderError(f"{folder}: holds files that fwl run did not write: {shown}. Move them, or "
                                f"choose another folder: fwl run removes only what an earlier run wrote")
    return files


def take_output_folder(folder: Path, names: InputNames, inputs: list[str]) -> None:
    """Check, then empty the earlier run's files from `folder`, and claim it for this run with a manifest.

    run.json goes first, so that a folder interrupted here reads as incomplete.
    """
    files = earlier_run_files(folder)
    doomed = {(folder / f).resolve() for f in files if str(f) != MANIFEST}
    for path in inputs:
        if "://" not in path and Path(path).resolve() in doomed:
            raise OutputFolderError(f"{path}: is an output of the earlier run in {folder}, which this run replaces; "
                                    f"copy it elsewhere first")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RUN_JSON).unlink(missing_ok=True)
    for f in files:
        if str(f) not in (MANIFEST, RUN_JSON):
            (folder / f).unlink()
    for d in OUTPUT_DIRS:
        if (folder / d).is_dir():
            for sub in sorted((p for p in (folder / d).rglob("*") if p.is_dir()), reverse=True):
                sub.rmdir()
            (folder / d).rmdir()
    manifest = {
        "written_by": "fwl run", "started": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "note": f"fwl run owns this folder's {', '.join(OUTPUT_DIRS)} folders; {RUN_JSON} marks a complete run",
        "inputs": [{"path": p, "name": names.name(p), "stem": names.stem(names.name(p))} for p in inputs],
    }
    _write_atomically(folder / MANIFEST, json.dumps(manifest, indent=2) + "\n")


def remove_partial_files(folder: Path) -> list[Path]:
    """The .tmp files an interrupted writer left in our folders."""
    gone = []
    for d in OUTPUT_DIRS:
        for p in sorted((folder / d).rglob("*.tmp")) if (folder / d).is_dir() else []:
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def list_outputs(folder: Path) -> list[str]:
    """Every file a run wrote into its folders, relative, sorted (for run.json)."""
    return [str(f) for f in _files_under(folder) if f.parts[0] in OUTPUT_DIRS]


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_run_json(folder: Path, summary: dict) -> Path:
    """run.json, atomically: the last file a run writes, the mark of a complete run."""
    _write_atomically(folder / RUN_JSON, json.dumps(summary, indent=2, default=str) + "\n")
    return folder / RUN_JSON


# ---------------------------------------------------------------- reading runs

def is_complete(folder: str | Path) -> bool:
    """Whether `folder` holds a finished fwl run (its run.json is there and reads)."""
    try:
        read_run(folder)
    except (IncompleteRunError, FileNotFoundError):
        return False
    return True


def read_run(folder: str | Path) -> dict:
    """The summary of a finished run; IncompleteRunError for a folder whose run did not finish."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    path = folder / RUN_JSON
    if not path.is_file():
        what = "its run did not finish (interrupted or failed); rerun it into the same folder" \
            if (folder / MANIFEST).is_file() else "not an fwl run output folder"
        raise IncompleteRunError(f"{folder}: incomplete, no {RUN_JSON}: {what}")
    try:
        return json.loads(path.read_text())
    except ValueError as err:
        raise IncompleteRunError(f"{path}: unreadable ({err})") from None
