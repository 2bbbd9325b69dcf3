"""The output folder of a run: which inputs, under which names, which files are ours, and run.json.

A run never removes what it did not write. It takes a folder that is new,
empty, or holds only an earlier run's outputs, which it knows by the manifest
(fwl-output.json) it writes before anything else. run.json is written last:
a folder without it holds an incomplete run.

The manifest also fingerprints the run: its settings (the decomposition's
configuration and what shapes the outputs) and each input's identity (sizes
and digests of the file and its packet file). A folder is taken three ways:

    replace  a new run: the earlier run's files go (fwl run)
    resume   the same inputs and settings: every file stays, the run goes on (fwl run --resume)
    add      the same settings: more inputs join the folder's, a replaced input's outputs go (fwl watch)
"""

from __future__ import annotations

import dataclasses
import datetime
import glob
import hashlib
import json
import os
import re
from pathlib import Path, PurePosixPath
from typing import Any

from pipeline.layout import (BUCKET_SUFFIX, GRID_DIR, GRID_MARK, LOCK, LOGS, MANIFEST, OUTPUT_DIRS, PARTS,
                             RANGE_SUFFIX, RUN_JSON, TILE_SUFFIX)

INPUT_SUFFIXES = (".las", ".laz", ".pls", ".h5")  # what a folder given as input is expanded to (.h5: waveforms only)


def is_flight_line(path: Path) -> bool:
    """A file a folder given as input offers: its suffix, and for HDF5 a GEDI or LVIS L1B granule (not the L2A and
    L2B granules that often lie beside them)."""
    if path.suffix.lower() != ".h5":
        return path.suffix.lower() in INPUT_SUFFIXES
    from fwcore.io.formats import kind_of

    return kind_of(path).format is not None


class OutputFolderError(ValueError):
    """The output folder holds something a run did not write, or cannot be used."""


class IncompleteRunError(ValueError):
    """A folder without run.json: its run did not finish (or it is not a run's folder)."""


class ResumeError(OutputFolderError):
    """A folder that cannot be resumed or added to by this call: other inputs or settings; says which."""


# ---------------------------------------------------------------- inputs

@dataclasses.dataclass(frozen=True)
class MatchedInputs:
    """What the inputs given name: the files to run, and each match that is not one, with why."""

    paths: list[str]
    not_taken: list[tuple[str, str]]  # (the match, why it is not an input)


def match_inputs(inputs: list[str]) -> MatchedInputs:
    """Files, glob patterns and folders (their *.las, *.laz and *.pls, not recursive) -> sorted distinct paths;
    a folder (given or matched by a pattern) that holds none of those is named with why. Local paths are
    resolved; a pattern that matches nothing, or inputs that leave no file to run, are an error naming them."""
    paths: list[str] = []
    not_taken: list[tuple[str, str]] = []
    for item in inputs:
        if "://" in item:
            from apache_beam.io.filesystems import FileSystems
            found = [m.path for r in FileSystems.match([item]) for m in r.metadata_list]
            if not found:
                raise FileNotFoundError(f"{item}: no file matches this input")
        else:
            matched = glob.glob(item) if glob.has_magic(item) else [item] if Path(item).exists() else []
            found = []
            for m in sorted(matched):
                if Path(m).is_dir():
                    named = sorted(p for p in Path(m).iterdir() if p.suffix.lower() in INPUT_SUFFIXES
                                   and (not p.is_file() or is_flight_line(p)))
                    inside = [str(p) for p in named if p.is_file()]
                    if not inside:
                        not_taken.append((m, "a folder that holds no .las, .laz, .pls or GEDI/LVIS L1B .h5 file"))
                    not_taken += [(str(p), _not_a_file(p)) for p in named if not p.is_file()]
                    found += inside
                elif Path(m).is_file():
                    found.append(m)
                else:  # a link to a file that is gone, a socket: matched, yet nothing to read
                    not_taken.append((m, _not_a_file(Path(m))))
            if not found and not matched:
                raise FileNotFoundError(f"{item}: no file matches this input")
        paths.extend(p if "://" in p else str(Path(p).resolve()) for p in found)
    if not paths:
        raise FileNotFoundError("; ".join(f"{m}: {why}" for m, why in not_taken) or "no input file")
    return MatchedInputs(sorted(set(paths)), not_taken)


def _not_a_file(path: Path) -> str:
    if path.is_dir():
        return "a folder (folders inside a folder given are not searched)"
    if path.is_symlink():
        return f"a link to {os.readlink(path)}, which does not exist"
    return "not a regular file"


def expand_inputs(inputs: list[str]) -> list[str]:
    """The files the inputs name (match_inputs), without what is not taken."""
    return match_inputs(inputs).paths


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


# ---------------------------------------------------------------- what a run is made of

# of a file's head and of its tail: where a re-delivered flight line differs (header, VLRs, last points or
# packets); small, as the driver reads them for every input of a survey before anything runs
DIGEST_BYTES = 1 << 16


def _file_identity(path: str) -> dict[str, Any]:
    if "://" in path:  # object stores: what their listing says
        from apache_beam.io.filesystems import FileSystems
        meta = FileSystems.match([path])[0].metadata_list[0]
        return {"size": meta.size_in_bytes, "updated": meta.last_updated_in_seconds}
    try:
        size = os.path.getsize(path)
        digest = hashlib.sha256()
        with open(path, "rb") as f:
            digest.update(f.read(DIGEST_BYTES))
            if size > DIGEST_BYTES:
                f.seek(max(DIGEST_BYTES, size - DIGEST_BYTES))
                digest.update(f.read(DIGEST_BYTES))
    except OSError as err:  # planning rejects the file with its reason; here it is only told apart
        return {"unreadable": err.strerror or str(err)}
    return {"size": size, "sha256": digest.hexdigest()}


def input_identity(path: str) -> dict[str, dict[str, Any]]:
    """What tells an input from a changed one, cheaply at any size: per file (the input and the file beside it
    that holds its samples) its size and a digest of its first and last 64 KiB. Times are left out: a copy
    changes them, not the data."""
    from fwcore.io import packet_file
    files = [path] + ([str(c)] if "://" not in path and (c := packet_file(path)) else [])
    return {PurePosixPath(f.split("://", 1)[-1]).name: _file_identity(f) for f in files}


def differences(before: Any, now: Any, where: str = "") -> list[str]:
    """Each leaf of two nested dicts that differs, as "key.sub: before -> now"."""
    if isinstance(before, dict) and isinstance(now, dict):
        return [d for k in sorted(set(before) | set(now), key=str)
                for d in differences(before.get(k), now.get(k), f"{where}.{k}" if where else str(k))]
    return [] if before == now else [f"{where}: {before!r} -> {now!r}"]


# ---------------------------------------------------------------- the folder

def _is_ours(relative: PurePosixPath, stems: set[str], listed: set[str]) -> bool:
    """A file of an earlier run: listed in its run.json, or in one of our folders and named after its inputs."""
    if str(relative) in listed or str(relative) in (MANIFEST, RUN_JSON):
        return True
    if len(relative.parts) < 2 or relative.parts[0] not in OUTPUT_DIRS:
        return False
    name = relative.name
    return relative.parts[0] == LOGS or any(name.startswith(s + ".") or name.startswith(s + "-") for s in stems)


def _grid_files(folder: Path) -> set[str]:
    """fwl grid's files in the run's grid/ folder: its mark and the maps the mark lists (each maybe half-written)."""
    try:
        names = [str(n) for n in json.loads((folder / GRID_DIR / GRID_MARK).read_text())["files"]]
    except (OSError, ValueError, KeyError, TypeError):
        names = []
    return {f"{GRID_DIR}/{n}{tmp}" for n in (GRID_MARK, *names) if "/" not in n for tmp in ("", ".tmp")}


def files_under(folder: Path) -> list[PurePosixPath]:
    """The files under `folder`, relative; not its lock (pipeline.lock), which is its writer's, not an output."""
    out = []
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        for f in sorted(files):
            if f == LOCK and Path(root) == folder:
                continue
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
    files = files_under(folder)
    if not files and not _holds_anything(folder):
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
    listed |= _grid_files(folder)
    foreign = [f for f in files if Path(folder, f).is_symlink() or not _is_ours(f, stems, listed)]
    foreign += [PurePosixPath(p.name) for p in folder.iterdir() if p.is_dir() and p.name not in (*OUTPUT_DIRS, GRID_DIR)
                and not any(f.parts[0] == p.name for f in files)]
    if foreign:
        shown = ", ".join(str(f) for f in foreign[:5]) + (" ..." if len(foreign) > 5 else "")
        raise OutputFolderError(f"{folder}: holds files that fwl run did not write: {shown}. Move them, or "
                                f"choose another folder: fwl run removes only what an earlier run wrote")
    return files


def _manifest_entry(path: str, names: InputNames, identities: dict[str, dict] | None) -> dict:
    name = names.name(path)
    return {"path": path, "name": name, "stem": names.stem(name),
            "identity": (identities or {}).get(path), "done": False}


def take_output_folder(folder: Path, names: InputNames, inputs: list[str], settings: dict | None = None,
                       identities: dict[str, dict] | None = None) -> None:
    """Check, then empty the earlier run's files from `folder`, and claim it for this run with a manifest that
    fingerprints it (`settings`, each input's identity).

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
    for d in (*OUTPUT_DIRS, GRID_DIR):
        if (folder / d).is_dir():
            for sub in sorted((p for p in (folder / d).rglob("*") if p.is_dir()), reverse=True):
                sub.rmdir()
            (folder / d).rmdir()
    write_manifest(folder, settings, [_manifest_entry(p, names, identities) for p in inputs])


def read_manifest(folder: Path) -> dict:
    """The manifest of an fwl output folder (OutputFolderError when it is missing or unreadable)."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        for entry in manifest["inputs"]:  # each names its input's path and output stem
            entry["path"], entry["stem"]
        return manifest
    except FileNotFoundError:
        raise OutputFolderError(f"{folder}: not an fwl run output folder (no {MANIFEST})") from None
    except (ValueError, KeyError, TypeError) as err:
        raise OutputFolderError(f"{folder / MANIFEST}: unreadable manifest ({err}); remove the folder yourself") \
            from None


def write_manifest(folder: Path, settings: dict | None, inputs: list[dict], started: str | None = None) -> None:
    manifest = {
        "written_by": "fwl run",
        "started": started or datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "note": f"fwl run owns this folder's {', '.join(OUTPUT_DIRS)} folders; {RUN_JSON} marks a complete run",
        "settings": settings,
        "inputs": inputs,
    }
    write_atomically(folder / MANIFEST, json.dumps(manifest, indent=2) + "\n")


def mark_inputs_done(folder: Path, paths: list[str], planned: dict[str, dict]) -> None:
    """In the manifest: these inputs are complete, with what their plan measured (for later run.json files)."""
    manifest = read_manifest(folder)
    for entry in manifest["inputs"]:
        if entry["path"] in paths:
            entry["done"] = True
            entry["planned"] = planned.get(entry["path"], {})
    write_manifest(folder, manifest.get("settings"), manifest["inputs"], manifest.get("started"))


def _holds_anything(folder: Path) -> bool:
    """Anything in `folder` but its lock."""
    return any(p.name != LOCK for p in folder.iterdir())


def _is_new(folder: Path) -> bool:
    """Nothing there yet to resume or add to: no folder, or an empty one (but for its lock)."""
    return not folder.exists() or (folder.is_dir() and not _holds_anything(folder))


def _fingerprinted(folder: Path, how: str) -> dict:
    earlier_run_files(folder)  # refuses a folder that holds what is not ours
    manifest = read_manifest(folder)
    if manifest.get("settings") is None:
        raise ResumeError(f"{folder}: its run was written by an fwl that did not fingerprint its runs, so it cannot "
                          f"{how}; run without --resume into it (which replaces it), or choose another folder")
    manifest["settings"] = current_fingerprint(manifest["settings"])
    return manifest


def current_fingerprint(settings: dict) -> dict:
    """A fingerprint an earlier fwl wrote, as this one writes the same run's: its `pulse` is `overrides`, and its
    config names no retired setting at its one value (fwcore.engine.config.RETIRED_SETTINGS)."""
    from fwcore.engine.config import current_settings

    settings = {("overrides" if k == "pulse" and "overrides" not in settings else k): v for k, v in settings.items()}
    if isinstance(settings.get("config"), dict):
        settings["config"] = current_settings(settings["config"])
    return settings


def resume_output_folder(folder: Path, inputs: list[str], settings: dict,
                         identities: dict[str, dict]) -> tuple[InputNames, str]:
    """Claim `folder` to go on with its interrupted run: the same inputs, unchanged, and the same settings,
    else ResumeError naming what differs. Returns the inputs' names (those the folder gave them: fwl watch
    names inputs as they come) and "resumed"; "new" when there was nothing to resume (a new or empty folder,
    now claimed as by take_output_folder); "complete" when its run had finished (left as is), unless it failed
    (nothing decomposed: its inputs are done again)."""
    if _is_new(folder):
        names = InputNames.of(inputs)
        take_output_folder(folder, names, inputs, settings, identities)
        return names, "new"
    manifest = _fingerprinted(folder, "be resumed")
    fix = "run without --resume to start over, or resume with the interrupted run's inputs and options"
    changed = differences(manifest["settings"], settings)
    if changed:
        raise ResumeError(f"{folder}: cannot resume: the settings differ from the interrupted run's "
                          f"({'; '.join(changed)}); {fix}")
    before = {i["path"]: i for i in manifest["inputs"]}
    missing, added = sorted(set(before) - set(inputs)), sorted(set(inputs) - set(before))
    if missing or added:
        said = ([f"not given now: {', '.join(missing)}"] if missing else []) + \
            ([f"not in the interrupted run: {', '.join(added)}"] if added else [])
        raise ResumeError(f"{folder}: cannot resume: other inputs ({'; '.join(said)}); {fix}")
    for path in inputs:
        changed = differences(before[path].get("identity"), identities[path])
        if changed:
            raise ResumeError(f"{path}: changed since the interrupted run in {folder} read it "
                              f"({'; '.join(changed)}); {fix}")
    names = _names_of(manifest["inputs"])
    if is_complete(folder) and read_run(folder).get("status") != "failed":
        return names, "complete"
    if is_complete(folder):  # failed: done again (earlier fwl rejected the pulses of a full disk's ranges)
        for entry in manifest["inputs"]:
            entry["done"] = False
        write_manifest(folder, manifest.get("settings"), manifest["inputs"], manifest.get("started"))
    (folder / RUN_JSON).unlink(missing_ok=True)  # a damaged one, or a failed run's
    return names, "resumed"


def _names_of(entries: list[dict]) -> InputNames:
    """The names a folder's manifest gave its inputs."""
    return InputNames({e["path"]: e["name"] for e in entries}, {e["name"]: e["stem"] for e in entries})


def add_to_output_folder(folder: Path, inputs: list[str], settings: dict,
                         identities: dict[str, dict]) -> tuple[InputNames, list[str]]:
    """Claim `folder` for more inputs beside those it holds (fwl watch): the same settings, else ResumeError.
    An input it holds whose identity changed (a replaced file) loses its outputs, to be made anew; one it
    holds unchanged keeps them (its finished ranges are reused). Returns the names of all the folder's
    inputs, and the inputs replaced."""
    if _is_new(folder):
        names = InputNames.of(inputs)
        take_output_folder(folder, names, inputs, settings, identities)
        return names, []
    manifest = check_settings(folder, settings)
    entries = {i["path"]: i for i in manifest["inputs"]}
    replaced = [p for p in inputs if p in entries and entries[p].get("identity") != identities[p]]
    for path in replaced:
        remove_input_outputs(folder, entries[path]["stem"])
        entries[path].update(identity=identities[path], done=False, planned={})
    names = InputNames.of(list(entries) + [p for p in inputs if p not in entries])
    kept = _names_of(list(entries.values()))  # the names given earlier stay; new inputs join them
    for path in inputs:
        if path not in entries:  # a new input: its own name, and a stem no earlier input has
            name, stem = names.name(path), names.stem(names.name(path))
            taken = set(kept.stems.values())
            stem = stem if stem not in taken else name.replace("/", "__")
            entries[path] = {"path": path, "name": name, "stem": stem, "identity": identities[path], "done": False}
            kept.names[path], kept.stems[name] = name, stem
    (folder / RUN_JSON).unlink(missing_ok=True)
    write_manifest(folder, settings, list(entries.values()), manifest.get("started"))
    return kept, replaced


def check_settings(folder: Path, settings: dict) -> dict:
    """The manifest of a folder to add inputs to, if it made its outputs with these settings (a new or empty
    folder has none: {}); else ResumeError naming the settings that differ."""
    if _is_new(folder):
        return {}
    manifest = _fingerprinted(folder, "take more inputs")
    changed = differences(manifest["settings"], settings)
    if changed:
        raise ResumeError(f"{folder}: holds outputs made with other settings ({'; '.join(changed)}); "
                          f"use the same options, or another --output")
    return manifest


def remove_input_outputs(folder: Path, stem: str, dirs: tuple[str, ...] = OUTPUT_DIRS) -> list[Path]:
    """Every file of one input in our folders `dirs` (all: its tables' parts, point cloud, MCAP, parts and
    plan), and the folders under parts/ left empty."""
    # <stem>.las, <stem>-<range>.parquet, <stem>-tile-<n>.parquet (fwl compact), ...: not <stem>.las.las, the file
    # of an input whose stem is <stem>.las
    own = re.compile(re.escape(stem) + rf"({RANGE_SUFFIX}|{TILE_SUFFIX}|{BUCKET_SUFFIX})?"
                     + r"\.(parquet|las|laz|copc\.laz|mcap|json|fault|pickle)(\.tmp)?")
    gone = []
    for d in dirs:
        for p in sorted((folder / d).rglob("*")) if d != LOGS and (folder / d).is_dir() else []:
            if p.is_file() and own.fullmatch(p.name):
                p.unlink()
                gone.append(p)
    parts = folder / PARTS
    for d in sorted((p for p in parts.rglob("*") if p.is_dir()), reverse=True) if parts.is_dir() else []:
        if not any(d.iterdir()):
            d.rmdir()
    if parts.is_dir() and not any(parts.iterdir()):
        parts.rmdir()
    return gone


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
    return [str(f) for f in files_under(folder) if f.parts[0] in OUTPUT_DIRS]


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_run_json(folder: Path, summary: dict) -> Path:
    """run.json, atomically: the last file a run writes, the mark of a complete run."""
    write_atomically(folder / RUN_JSON, json.dumps(summary, indent=2, default=str) + "\n")
    return folder / RUN_JSON


# ---------------------------------------------------------------- reading runs

# what run.json's inputs[] (and the manifest's planned) held of the file's pulse before it was one record
_FLAT_PULSE = {"system_pulse_fwhm_ps": "fwhm_ps", "system_pulse_fwhm_source": "fwhm_source",
               "shape_tolerance": "shape_tolerance", "shape_tolerance_source": "shape_source",
               "range_offset_ps": "range_offset_ps", "range_offset_source": "range_offset_source",
               "system_response": "response", "model": "model", "model_choice": "model_choice"}


def with_system_pulse(planned: dict) -> dict:
    """An input's planned entry (the manifest's, run.json's inputs[]) with its pulse as one record, `system_pulse`
    (SystemPulse.to_dict()): a folder written before that held it flattened, and is read or resumed the same."""
    if "system_pulse" in planned or "system_pulse_fwhm_ps" not in planned:
        return planned
    kept = {k: v for k, v in planned.items() if k not in _FLAT_PULSE}
    pulse = {new: planned.get(old) for old, new in _FLAT_PULSE.items()}
    return {**kept, "system_pulse": {**pulse, "model": pulse["model"] or "", "model_choice": pulse["model_choice"] or ""}}


def recorded_pulse(entry: dict):
    """The system pulse a run decomposed an input's pulses with, from its run.json entry (SystemPulse.from_dict);
    None when the entry records none (a file rejected before its pulse was measured)."""
    from fwcore.instrument.pulse import SystemPulse

    record = with_system_pulse(entry).get("system_pulse")
    return SystemPulse.from_dict(record) if record else None


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
