"""The run folder: a folder fwl run claimed by its manifest, holding only its outputs; resumed only when its run did
not finish or failed."""

import json

from pipeline.layout import LOCK, MANIFEST
from pipeline.outputs import (InputNames, earlier_run_files, input_identity, read_manifest, resume_output_folder,
                              take_output_folder, write_run_json)


def test_resume_calls_complete_only_a_run_that_did_not_fail_and_takes_the_lock_for_no_output(tmp_path, leica_dir):
    out, path = tmp_path / "out", str(leica_dir / "leica_a.las")
    identities = {path: input_identity(path)}
    take_output_folder(out, InputNames.of([path]), [path], {"limit": 1}, identities)
    manifest = read_manifest(out)
    manifest["inputs"][0]["done"] = True
    (out / MANIFEST).write_text(json.dumps(manifest))
    (out / LOCK).write_text("{}")  # the writer's lock, not an output: neither foreign nor listed
    assert [str(f) for f in earlier_run_files(out)] == [MANIFEST]
    write_run_json(out, {"status": "partial"})
    assert resume_output_folder(out, [path], {"limit": 1}, identities)[1] == "complete"
    write_run_json(out, {"status": "failed"})  # nothing decomposed (a full disk's pulses, by an earlier fwl)
    assert resume_output_folder(out, [path], {"limit": 1}, identities)[1] == "resumed"
    assert not (out / "run.json").exists() and [e["done"] for e in read_manifest(out)["inputs"]] == [False]
