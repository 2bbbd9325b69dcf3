"""The documentation site builds with --strict, and its generated pages say what the code does."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

from pipeline.cli import build_parser
from pipeline.tables import TABLES, table_column

ROOT = Path(__file__).resolve().parents[2]


def test_the_site_builds_strictly_with_every_command_and_column(tmp_path):
    site = tmp_path / "site"
    mkdocs = Path(sys.executable).with_name("mkdocs")
    done = subprocess.run([str(mkdocs), "build", "--strict", "--site-dir", str(site)], cwd=ROOT, capture_output=True,
                          text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    cli = (site / "cli" / "index.html").read_text()
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    for name, sub in commands.items():
        assert f"fwl {name}" in cli
        for action in sub._actions:
            if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
                continue
            for flag in action.option_strings:
                assert f"<code>{flag}</code>" in cli, (name, flag)
    outputs = (site / "outputs" / "index.html").read_text()
    for table in TABLES.values():
        for column in map(table_column, table):
            assert f"<code>{column.name}</code>" in outputs, column.name
    assert "ps^(alpha^2/2)" in outputs and "sigma_chauve" in outputs
    api = (site / "api" / "index.html").read_text()
    assert "echo_radiometry" in api and "decompose_batch" in api  # from the docstrings


def test_the_readme_is_short_and_starts_with_the_two_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 250
    assert lines[2:6] == ["```", "make run    # sets up .venv, runs the Beam pipeline on the bundled Leica sample "
                                 "into out/run/", "make test   # sets up .venv and runs the test suite", "```"]
