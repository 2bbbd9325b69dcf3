"""The viewer's background runs: each input its own run folder, claimed before the run starts, so that one input
never replaces another's of the same name, and a run made elsewhere belongs to its one input."""

import json

from pipeline.view.jobs import Jobs, _claim, _owner


def test_inputs_of_one_name_get_folders_of_their_own(tmp_path):
    jobs = Jobs(tmp_path / "runs")
    first, second = tmp_path / "a" / "leica_a.las", tmp_path / "b" / "leica_a.las"
    assert jobs.output_for(first) == tmp_path / "runs" / "leica_a"
    (tmp_path / "runs").mkdir()
    _claim(tmp_path / "runs" / "leica_a").write_text(f"{first}\n")  # as start() claims it
    assert jobs.output_for(second) == tmp_path / "runs" / "leica_a-2"
    assert jobs.output_for(first) == tmp_path / "runs" / "leica_a"  # its own, again
    assert _owner(tmp_path / "runs" / "leica_a") == first and _owner(tmp_path / "runs" / "leica_a-2") is None


def test_a_run_made_elsewhere_belongs_to_its_one_input_or_to_no_one_we_may_replace(tmp_path):
    run = tmp_path / "runs" / "x"
    run.mkdir(parents=True)
    (run / "run.json").write_text(json.dumps({"inputs": [{"path": str(tmp_path / "data" / "x.las")}]}))
    assert _owner(run) == tmp_path / "data" / "x.las"
    assert Jobs(tmp_path / "runs").output_for(tmp_path / "data" / "x.las") == run  # its input's: reused
    (run / "run.json").write_text(json.dumps({"inputs": [{"path": "x.las"}, {"path": "y.las"}]}))
    assert Jobs(tmp_path / "runs").output_for(tmp_path / "x.las") == tmp_path / "runs" / "x-2"
    (run / "run.json").write_text("{")  # unreadable: someone's
    assert Jobs(tmp_path / "runs").output_for(tmp_path / "x.las") == tmp_path / "runs" / "x-2"
