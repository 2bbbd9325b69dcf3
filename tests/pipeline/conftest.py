"""A forest flight run once for the session (fwl simulate --scene forest, fwl run): the classification, the forest's
maps and the footprints are measured on it against the scene's truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from fwcore.engine.config import DecompositionConfig
from pipeline.cli import main
from pipeline.run import run

FOREST_PULSES = 40_000  # 24 m of flight over the 220 m swath: trees, the ditch, a building or two
IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]


@pytest.fixture(scope="session")
def forest_flight(tmp_path_factory) -> Path:
    las = tmp_path_factory.mktemp("forest") / "forest.las"
    assert main(["simulate", "--scene", "forest", "--pulses", str(FOREST_PULSES), "--seed", "21",
                 "--output", str(las)]) == 0
    return las


@pytest.fixture(scope="session")
def forest_run(forest_flight, tmp_path_factory) -> Path:
    """The flight decomposed (LM, a few iterations: the echoes' positions are what the terrain needs)."""
    out = tmp_path_factory.mktemp("forest-run") / "run"
    run([str(forest_flight)], out, DecompositionConfig(optimizer="lm", lm_iterations=5), ("parquet",),
        points_per_range=10_000, beam_args=IN_PROCESS, watch=False)
    return out
