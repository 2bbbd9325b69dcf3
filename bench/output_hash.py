"""A restructure's proof: one hash over the echo and pulse tables of the shared inputs, for every model and preset.

Runs `fwl run` (Leica LAS, RIEGL PulseWaves) and `fwl decompose-csv` (NEON) as a user would, one process each,
with every model under every preset, and every optimizer once on Leica, then hashes the tables' values (not
their files' bytes, which carry the library's version). Run it before and after a change that must not change a
result, and compare the last line:

    python bench/output_hash.py            # prints a hash per case and the hash of them all
    python bench/output_hash.py --quick    # fewer pulses (a check while working, not the proof)
    python bench/output_hash.py --las      # fwl run's cases also write LAS, and its points' values are hashed
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
LEICA = DATA / "leica_als" / "leica_a.las"
RIEGL = DATA / "pulsewaves" / "riegl_example3.pls"
NEON = DATA / "neon_harvard"

MODELS = ("system", "generalized", "gaussian", "auto")
PRESETS = ("default", "fast", "paper")
OPTIMIZERS = ("none", "lm", "lbfgs", "ga", "pso", "de", "mde", "mde-lm", "ga-iterative", "lm-mde", "gold",
              "richardson-lucy")


def cases(limit: int) -> list[tuple[str, list[str]]]:
    """(name, fwl arguments before --output) for every case."""
    found = []
    for preset in PRESETS:
        chosen = [] if preset == "default" else ["--preset", preset]
        for model in MODELS:
            settings = [*chosen, "--model", model]
            found.append((f"leica {preset} {model}", ["run", str(LEICA), "--limit", str(limit), *settings]))
            found.append((f"riegl {preset} {model}", ["run", str(RIEGL), "--limit", str(limit), *settings]))
            found.append((f"neon {preset} {model}", ["decompose-csv", str(NEON / "return_waveforms.csv"),
                                                    "--outgoing", str(NEON / "outgoing_pulses.csv"), *settings]))
    for optimizer in OPTIMIZERS:
        # 25 pulses: the patent's GA takes seconds a pulse
        found.append((f"leica optimizer {optimizer}", ["run", str(LEICA), "--limit", "25", "--optimizer", optimizer]))
    return found


def table_digest(paths: list[Path]) -> str:
    """A hash of the rows of Parquet files, in a fixed order, whatever their files' layout."""
    if not paths:
        return "no table"
    import pyarrow as pa
    table = pa.concat_tables([pq.read_table(p) for p in sorted(paths)], promote_options="default")
    keys = [c for c in ("pulse_id", "echo_index", "waveform_id", "echo") if c in table.column_names]
    if keys:
        table = table.sort_by([(k, "ascending") for k in keys])
    digest = hashlib.sha256()
    for name in sorted(table.column_names):
        digest.update(name.encode())
        digest.update(repr(table.column(name).to_pylist()).encode())
    return digest.hexdigest()[:16]


def las_digest(paths: list[Path]) -> str:
    """A hash of LAS files' point values, every dimension (standard and Extra Bytes), and their headers' counts,
    scales and offsets; not their bytes, which carry the writer's version."""
    if not paths:
        return "no las"
    import laspy
    digest = hashlib.sha256()
    for path in sorted(paths):
        las = laspy.read(path)
        digest.update(repr((las.header.point_count, list(las.header.scales), list(las.header.offsets))).encode())
        for name in las.point_format.dimension_names:
            digest.update(name.encode())
            digest.update(las[name].tobytes() if hasattr(las[name], "tobytes") else bytes(las[name]))
    return digest.hexdigest()[:16]


def run_case(arguments: list[str], folder: Path, las: bool = False) -> str:
    out = folder / "out"
    command = [sys.executable, "-m", "pipeline.cli", *arguments, "--seed", "7"]
    if arguments[0] == "run":
        command += ["--output", str(out), "--formats", "parquet,las" if las else "parquet", "--direct_num_workers=1",
                    "--direct_running_mode=in_memory"]
    else:
        command += ["--output", str(out / "echoes.parquet"), "--threads", "1"]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if done.returncode not in (0, 3):  # 3: the run finished with pulses in rejected/ (counted, hashed below)
        raise SystemExit(f"{' '.join(arguments)}: exit {done.returncode}\n{done.stderr[-3000:]}")
    tables = {"echoes": sorted((out / "echoes").glob("*.parquet")) if (out / "echoes").is_dir()
              else sorted(out.glob("echoes*.parquet")),
              "pulses": sorted((out / "pulses").glob("*.parquet")),
              "rejected": sorted((out / "rejected").glob("*.parquet"))}
    said = " ".join(f"{name}={table_digest(paths)}" for name, paths in tables.items())
    return f"{said} las={las_digest(sorted((out / 'las').glob('*.las')))}" if las and arguments[0] == "run" else said


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100 pulses an input instead of 400")
    parser.add_argument("--only", default="", help="run only the cases whose name contains this")
    parser.add_argument("--las", action="store_true", help="fwl run's cases write LAS too, its values hashed")
    args = parser.parse_args(argv)
    every = hashlib.sha256()
    for name, arguments in cases(100 if args.quick else 400):
        if args.only not in name:
            continue
        with tempfile.TemporaryDirectory() as folder:
            line = f"{name}: {run_case(arguments, Path(folder), args.las)}"
        print(line, flush=True)
        every.update(line.encode())
    print(f"all: {every.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
