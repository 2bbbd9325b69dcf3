"""The ranges' order for claiming workers: each range's cost from the engine on a sample of its shots, costliest
first; none for small-footprint files or as few ranges as workers; a run whose workers claim in that order writes
the same tables as one whose ranges Beam deals."""

import dataclasses
from pathlib import Path

import pyarrow.dataset as ds
import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.cli import main
from pipeline.plan import plan_file
from pipeline.schedule import MAX_RANGES_A_WORKER, estimated, longest_first, range_cost

DATA = Path(__file__).resolve().parents[2] / "examples" / "data"
L1B = DATA / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
LEICA = DATA / "leica_als" / "leica_a.las"
CONFIG = DecompositionConfig()


@pytest.fixture(scope="module")
def gedi_tasks():
    return plan_file(str(L1B), L1B.name, L1B.stem, CONFIG, 20, None)


def test_a_range_cost_is_the_engine_evaluations_of_its_sample_scaled_to_its_pulses(gedi_tasks):
    costs = [range_cost(t, CONFIG, sample=8) for t in gedi_tasks]
    assert len(gedi_tasks) >= 8 and all(c > 0 for c in costs)
    assert costs == [range_cost(t, CONFIG, sample=8) for t in gedi_tasks]  # the same order on every run
    assert len(set(costs)) > 1  # the beams' shots differ
    # a sample as large as the range reads the whole range: no scaling
    whole = gedi_tasks[0]
    assert range_cost(whole, CONFIG, sample=whole.point_range.stop - whole.point_range.start) > 0


def test_longest_first_puts_the_costliest_ranges_first_and_keeps_ties_in_file_order(gedi_tasks):
    ordered = longest_first(gedi_tasks, CONFIG, workers=2, sample=8)
    costs = {t.start: range_cost(t, CONFIG, sample=8) for t in gedi_tasks}
    assert sorted(t.start for t in ordered) == sorted(t.start for t in gedi_tasks)
    seen = [costs[t.start] for t in ordered]
    assert seen == sorted(seen, reverse=True)
    assert [t.start for t in ordered] != [t.start for t in gedi_tasks]  # this granule's beams are not in cost order


def test_no_order_for_as_few_ranges_as_workers_nor_for_small_footprints(gedi_tasks, tmp_path):
    assert longest_first(gedi_tasks[:2], CONFIG, workers=2) is None
    assert len(gedi_tasks) > MAX_RANGES_A_WORKER // 4 and longest_first(gedi_tasks, CONFIG, workers=1) is not None
    many = gedi_tasks * (MAX_RANGES_A_WORKER // len(gedi_tasks) + 1)  # more than MAX_RANGES_A_WORKER for one worker
    assert longest_first(many, CONFIG, workers=1) is None
    gone = [dataclasses.replace(t, source=dataclasses.replace(t.source, path=str(tmp_path / "gone.h5")))
            for t in gedi_tasks]  # a sample that cannot be read: no order, and no error
    assert longest_first(gone, CONFIG, workers=2) is None
    leica = plan_file(str(LEICA), LEICA.name, LEICA.stem, CONFIG, 300, None)
    assert len(leica) > 2 and not estimated(leica[0])
    assert longest_first(leica, CONFIG, workers=2) is None


def test_a_run_claiming_ranges_costliest_first_writes_what_a_dealt_run_writes(tmp_path):
    args = [str(L1B), "--formats", "parquet", "--optimizer", "lm", "--points-per-range", "20"]
    assert main(["run", *args, "--output", str(tmp_path / "claimed")]) == 0  # the default runner: claimed
    assert main(["run", *args, "--output", str(tmp_path / "dealt"), "--direct_running_mode=multi_threading"]) == 0
    for table in ("echoes", "pulses"):
        claimed = ds.dataset(str(tmp_path / "claimed" / table), format="parquet").to_table()
        dealt = ds.dataset(str(tmp_path / "dealt" / table), format="parquet").to_table()
        assert claimed.num_rows > 0 and claimed.equals(dealt)
