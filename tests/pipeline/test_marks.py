"""A range's mark: written last, listing every file the range wrote at its size; a range is trusted only with
its mark and those files as they were."""

import json

from fwcore.engine.config import DecompositionConfig
from pipeline.layout import progress_mark, range_files
from pipeline.marks import counts_from_marks, mark_range_done, range_is_complete, remove_range_files
from pipeline.plan import InputToPlan, plan_input, planned_pulses


def test_a_range_is_finished_only_with_its_mark_and_every_file_it_lists_at_its_size(tmp_path, leica_dir):
    task = plan_input(InputToPlan(str(leica_dir / "leica_a.las"), "leica_a.las", "leica_a"),
                      DecompositionConfig(), 400).tasks[1]
    echoes, _, _, las, _ = files = range_files(tmp_path, task)
    for f, data in ((echoes, b"PAR1 rows"), (las, b"LASF points")):
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(data)
    assert not range_is_complete(tmp_path, task)  # parts without their mark: never trusted
    counts = {"pulses_decomposed": 309, "echoes_kept": 700, "echoes_spurious": 12}
    mark_range_done(tmp_path, task, planned_pulses(task), 1, counts)
    mark = json.loads(progress_mark(tmp_path, "leica_a", 400).read_text())
    assert mark == {"pulses": 310, "rejected": 1, "counts": counts,
                    "files": {"echoes/leica_a-000000000400.parquet": 9, "parts/leica_a-000000000400.las": 11}}
    assert counts_from_marks(tmp_path, [task]) == {"leica_a.las": counts}
    assert range_is_complete(tmp_path, task)
    las.write_bytes(b"LASF")  # rewritten since, cut short
    assert not range_is_complete(tmp_path, task)
    las.unlink()
    assert not range_is_complete(tmp_path, task)
    remove_range_files(tmp_path, task)
    assert not any(p.exists() for p in files + [progress_mark(tmp_path, "leica_a", 400)])
