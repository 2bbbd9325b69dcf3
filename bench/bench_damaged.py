"""Every kind of damage, three draws of each random one, in one `fwl run "v/*.las" "v/*.laz"`.

    python bench/bench_damaged.py [--rounds 3] [--seed 12] [--keep DIR]

The issue's check, at the size of a survey's worst folder (60 variants of the Leica sample with rounds=3,
and the folder dir.las and the link missing.las that the patterns also match): the run ends with exit 0 or 3,
no traceback on the terminal, every input accounted for (rows in pulses/ or rejected/, or named among the
matches that are no input), the intact file 924 of 924 pulses. Prints one line per check and the time; exit
1 when a check fails. tests/pipeline/test_reliability_damaged.py runs one draw of each kind in `make test`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.dataset as ds

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.damaged import NOT_INPUTS, SAMPLE_PULSES, write_variants  # noqa: E402


def check(folder: Path, rounds: int, seed: int) -> bool:
    variants = write_variants(ROOT / "examples" / "data" / "leica_als", folder / "v", seed=seed, rounds=rounds)
    out = folder / "out"
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "v/*.las", "v/*.laz", "--output", str(out),
                           "--optimizer", "none", "--points-per-range", "400"],
                          cwd=folder, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    said = done.stdout + done.stderr
    summary = json.loads((out / "run.json").read_text()) if (out / "run.json").is_file() else {"inputs": []}
    tables = {t: set(ds.dataset(str(out / t), format="parquet").to_table(columns=["source_file"])
                     .column("source_file").to_pylist()) if (out / t).is_dir() else set()
              for t in ("pulses", "rejected")}
    good = next((i["counts"] for i in summary["inputs"] if i["name"] == "good.las"), {})
    named = {Path(n["path"]).name for n in summary.get("not_inputs", [])}
    checks = {
        f"exit code {done.returncode} (0 or 3)": done.returncode in (0, 3),
        "no traceback": "Traceback" not in said,
        f"{len(variants)} inputs in run.json": len(summary["inputs"]) == len(variants),
        "every input in pulses/ or rejected/": all(v.file_name in tables["pulses"] | tables["rejected"]
                                                   for v in variants),
        f"{', '.join(NOT_INPUTS)} named in run.json and on the terminal": named == set(NOT_INPUTS)
        and all(f"{n}: " in said for n in NOT_INPUTS),
        f"the intact file {good.get('pulses_decomposed')} of {SAMPLE_PULSES} pulses":
            good.get("pulses_decomposed") == good.get("pulses_read") == SAMPLE_PULSES,
    }
    for what, ok in checks.items():
        print(f"{'ok  ' if ok else 'FAIL'} {what}")
    c = summary.get("counts", {})
    print(f"{len(variants)} variants + {len(NOT_INPUTS)} matches that are no input: {seconds:.1f} s; pulses read "
          f"{c.get('pulses_read')} = decomposed {c.get('pulses_decomposed')} + rejected {c.get('pulses_rejected')}; "
          f"files rejected {c.get('files_rejected')}, problems {c.get('problems')}")
    if not all(checks.values()):
        print(said[-3000:])
    return all(checks.values())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="draws of each random damage (default 3)")
    parser.add_argument("--seed", type=int, default=12)
    parser.add_argument("--keep", help="write the variants and the run here (default: a temporary folder)")
    args = parser.parse_args()
    if args.keep:
        return 0 if check(Path(args.keep), args.rounds, args.seed) else 1
    with tempfile.TemporaryDirectory() as folder:
        return 0 if check(Path(folder), args.rounds, args.seed) else 1


if __name__ == "__main__":
    sys.exit(main())
