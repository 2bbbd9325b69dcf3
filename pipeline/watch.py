"""`fwl watch`: process flight lines as they land in a folder, each once, also across restarts.

    poll IN_DIR -> inputs complete and steady across two polls -> those the output folder lacks
        -> one `fwl run` of them into the output folder (pipeline.run, adding to it) -> poll again

Polling lives here, outside Beam, and each batch is an ordinary run on the
configured runner (Direct or Dask): Beam 2.77's `fileio.MatchContinuously`
does not serve as a watch source on those runners (with deduplication it
polls hundreds of times a second, with a stop time it ignores the interval,
a GroupByKey downstream never fires, and the Dask runner lists once).

An input is complete when the file that holds its samples is there too (a
LAS file whose header says its packets are external needs its .wdp/.wdz, a
.pls its .wvs), and steady when the sizes and times of both are unchanged
since the previous poll. The output folder's manifest remembers each input
it finished, with its identity (pipeline.outputs.input_identity) and the
settings of the folder: a restarted watcher skips what is done; a file
replaced by another (a new identity) has its outputs removed and is made
again; a batch interrupted midway is resumed, its finished ranges kept.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path
from typing import Callable

from fwcore.engine.config import DecompositionConfig
from fwcore.io import needs_packet_file, packet_file
from pipeline.faults import RunStopped
from pipeline.outputs import OutputFolderError, check_settings, input_identity, is_flight_line, read_manifest

LOG = logging.getLogger("fwl")
Snapshot = tuple[tuple[int, int], ...]  # (size, mtime_ns) of an input and of its packet file


def input_files(folder: Path) -> list[Path]:
    """The inputs a folder holds now (its *.las, *.laz, *.pls and GEDI/LVIS L1B *.h5, not recursive), sorted, as
    the paths a run records (a symbolic link resolved to its target, as fwl run resolves its inputs)."""
    return sorted({p.resolve() for p in folder.iterdir() if p.is_file() and is_flight_line(p)})


def snapshot(path: Path) -> Snapshot | None:
    """Sizes and times of an input and of the file beside it that holds its samples; None while that is missing."""
    try:
        companion = packet_file(path)
        if companion is None and needs_packet_file(path):
            return None
        return tuple((s.st_size, s.st_mtime_ns) for s in (os.stat(f) for f in [path] + ([companion] if companion
                                                                                          else [])))
    except OSError:  # moved away between the listing and now, say: not ready
        return None


class FolderWatch:
    """What a folder holds that is complete and steady: unchanged since the previous poll."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.previous: dict[Path, Snapshot | None] = {}
        self._identities: dict[tuple[Path, Snapshot], dict] = {}

    def ready(self) -> dict[str, dict]:
        """Each input steady across two polls, with its identity (computed once per snapshot)."""
        now = {p: snapshot(p) for p in input_files(self.folder)}
        steady = {p: s for p, s in now.items() if s is not None and self.previous.get(p) == s}
        self.previous = now
        self._identities = {k: v for k, v in self._identities.items() if k in steady.items()}  # bounded
        out = {}
        for path, snap in steady.items():
            if (path, snap) not in self._identities:
                try:
                    self._identities[(path, snap)] = input_identity(str(path))
                except OSError:  # gone since its snapshot: not ready
                    continue
            out[str(path)] = self._identities[(path, snap)]
        return out


def due(ready: dict[str, dict], output: Path) -> list[str]:
    """The ready inputs that the output folder does not hold finished with the same identity."""
    try:
        done = {e["path"]: e.get("identity") for e in read_manifest(output)["inputs"] if e.get("done")}
    except ValueError:  # a new folder: nothing done
        done = {}
    return sorted(p for p, identity in ready.items() if done.get(p) != identity)


def watch(folder: str | Path, output: str | Path, config: DecompositionConfig, settings: dict,
          run_batch: Callable[[list[str]], dict], poll: float = 5.0, once: bool = False,
          say: Callable[[str], None] = print, stop: threading.Event | None = None) -> int:
    """Poll `folder` every `poll` seconds and give each batch of due inputs to `run_batch` (an fwl run that adds
    to `output`), until `stop` is set or, with `once`, after the first two polls. Returns the batches run.

    The folder and the output's settings are checked first: a missing folder is FileNotFoundError, an output
    made with other settings ResumeError, before anything runs.
    """
    folder, output = Path(folder).resolve(), Path(output).resolve()
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder to watch")
    if output == folder:
        raise ValueError(f"{output}: the output folder cannot be the watched folder; choose another --output")
    check_settings(output, settings)
    stop = stop or threading.Event()
    watcher, batches = FolderWatch(folder), 0
    say(f"fwl watch: {folder} every {poll:g} s -> {output}; {config.optimizer.value}/{config.model.value} "
        f"(Ctrl-C to stop)")
    watcher.ready()  # the first look: a file counts as steady from the second on
    while not stop.wait(poll):
        batch = due(watcher.ready(), output)
        if batch:
            say(f"fwl watch: {len(batch)} new or replaced file(s): {', '.join(Path(p).name for p in batch)}")
            try:
                summary = run_batch(batch)
            except OutputFolderError:
                raise  # the output folder itself cannot be used: waiting changes nothing
            except RunStopped as stopped:  # a full disk...: said in one line each, tried again once fixed
                for line in stopped.lines("the watch tries the batch again at its next poll"):
                    say(f"fwl watch: stopped: {line}")
            except Exception as err:  # noqa: BLE001  a file moved away, a failed job: the watch goes on
                LOG.exception("fwl watch: batch %s failed", batch)
                say(f"fwl watch: this batch did not finish ({type(err).__name__}: {err}); its files are tried "
                    f"again at the next poll, their finished ranges kept")
            else:
                batches += 1
                c = summary["counts"]
                say(f"fwl watch: done; the folder holds {len(summary['inputs'])} file(s), {c['pulses_read']:,} "
                    f"pulses read = {c['pulses_decomposed']:,} decomposed + {c['pulses_rejected']:,} rejected")
        if once:
            break
    return batches
