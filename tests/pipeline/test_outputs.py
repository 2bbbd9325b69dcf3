"""The run folder: a folder fwl run claimed by its manifest, holding only its outputs; resumed only when its run did
not finish or failed, a folder an earlier fwl wrote included; the file's pulse read back from run.json as one
record."""

import dataclasses
import json

import pytest

from fwcore.engine.config import DecompositionConfig
from fwcore.instrument.pulse import SystemPulse
from fwcore.instrument.response import gaussian_response
from pipeline.layout import LOCK, MANIFEST
from pipeline.outputs import (InputNames, ResumeError, earlier_run_files, input_identity, read_manifest,
                              recorded_pulse, resume_output_folder, take_output_folder, with_system_pulse,
                              write_manifest, write_run_json)


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


def test_a_folder_an_earlier_fwl_fingerprinted_resumes_under_today_s_names(tmp_path, leica_dir):
    out, path = tmp_path / "out", str(leica_dir / "leica_a.las")
    identities = {path: input_identity(path)}
    given = {"system_pulse_fwhm_ps": None, "shape_tolerance": 0.0, "system_response": None}
    config = DecompositionConfig().to_dict()
    earlier = {"limit": 1, "pulse": given, "config": {**config, "de_scale_factor": 0.5, "init_spread": 0.25}}
    take_output_folder(out, InputNames.of([path]), [path], earlier, identities)  # as an earlier fwl fingerprinted it
    assert resume_output_folder(out, [path], {"limit": 1, "overrides": given, "config": config},
                                identities)[1] == "resumed"
    other = {**given, "shape_tolerance": 0.05}
    with pytest.raises(ResumeError, match=r"overrides\.shape_tolerance: 0\.0 -> 0\.05"):
        resume_output_folder(out, [path], {"limit": 1, "overrides": other, "config": config}, identities)
    earlier["config"]["init_spread"] = 0.5  # a value no run of this fwl can make: not the same run
    write_manifest(out, earlier, read_manifest(out)["inputs"])
    with pytest.raises(ResumeError, match=r"config\.init_spread: 0\.5 -> None"):
        resume_output_folder(out, [path], {"limit": 1, "overrides": given, "config": config}, identities)


def test_an_input_s_pulse_is_one_record_and_an_earlier_run_s_flattened_one_reads_the_same():
    pulse = SystemPulse(4312.5, "single returns (95)", 0.05, "single returns (95)", -1213.25, "single returns (268)",
                        gaussian_response(4312.5), "system", "system: at held-out samples ...")
    entry = {"name": "a.las", "pulses_planned": 1125, "system_pulse": pulse.to_dict()}
    assert with_system_pulse(entry) is entry and recorded_pulse(json.loads(json.dumps(entry))) == pulse
    flattened = {"name": "a.las", "pulses_planned": 1125, "system_pulse_fwhm_ps": 4312.5,
                 "system_pulse_fwhm_source": "single returns (95)", "shape_tolerance": 0.05,
                 "shape_tolerance_source": "single returns (95)", "range_offset_ps": -1213.25,
                 "range_offset_source": "single returns (268)", "system_response": gaussian_response(4312.5).to_dict(),
                 "model": "system", "model_choice": "system: at held-out samples ..."}
    assert with_system_pulse(flattened) == {**entry, "system_pulse": pulse.to_dict()}
    assert recorded_pulse(json.loads(json.dumps(flattened))) == pulse
    unmeasured = {**flattened, "model": None, "model_choice": None, "system_response": None}
    assert recorded_pulse(unmeasured) == dataclasses.replace(pulse, response=None, model="", model_choice="")
    assert recorded_pulse({"name": "rejected.las"}) is None  # rejected before its pulse was measured
