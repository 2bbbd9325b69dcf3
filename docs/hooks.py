"""MkDocs hook: the pages that are generated from the code, so that they cannot drift from it.

    <!-- cli-reference -->        every `fwl` command and option, from pipeline.cli.build_parser()
    <!-- output-columns -->       every output table's columns with unit and meaning, from pipeline.tables
    <!-- include PATH -->         a file of the repository (deploy/README.md), its headings one level down
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def cli_reference() -> str:
    from pipeline.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in commands._choices_actions}
    out = []
    for name, sub in commands.choices.items():
        out += [f"## fwl {name}", "", _cell(helps.get(name, "")), "", "```", sub.format_usage().strip(), "```", ""]
        rows = [a for a in sub._actions if not isinstance(a, (argparse._HelpAction, argparse._VersionAction))]
        out += ["| argument | default | meaning |", "|---|---|---|"]
        for a in rows:
            flag = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.dest}`"
            hidden = a.default is None or a.default is False or a.default == argparse.SUPPRESS
            default = "" if hidden else f"`{a.default}`"
            out.append(f"| {flag} | {default} | {_cell(a.help or '')} |")
        if sub.epilog:
            out += ["", _cell(sub.epilog)]
        out.append("")
    return "\n".join(out)


def output_columns() -> str:
    from fwcore.io.writer import EXTRA_DIMENSIONS, RADIOMETRY_DIMENSIONS, RADIOMETRY_FLAG
    from pipeline.tables import TABLES, table_column

    where = {"echoes": "`echoes/*.parquet` (one row per echo, kept and spurious)",
             "pulses": "`pulses/*.parquet` (one row per decomposed pulse)",
             "rejected": "`rejected/*.parquet` (one row per rejected pulse, range or file)",
             "csv echoes": "`fwl decompose-csv`: the echo table",
             "csv waveforms": "`fwl decompose-csv`: the `.waveforms.parquet` table"}
    out = ["Generated from `pipeline/tables.py`; every Parquet field also carries its `unit` and `description` in "
           "its metadata.", ""]
    for table, names in TABLES.items():
        out += [f"### {where[table]}", "", "| column | type | unit | meaning |", "|---|---|---|---|"]
        out += [f"| `{c.name}` | {str(c.type).replace('<', '&lt;')} | {_cell(c.unit)} | {_cell(c.meaning)} |"
                for c in map(table_column, names)]
        out.append("")
    out += ["### `las/*.las`: Extra Bytes beside the standard point fields", "",
            "| name | description (unit) |", "|---|---|"]
    out += [f"| `{n}` | {_cell(d)} |" for n, d in EXTRA_DIMENSIONS]
    out += [f"| `{n}` | {_cell(cal)} (relative: {_cell(rel)}) |" for n, cal, rel in RADIOMETRY_DIMENSIONS]
    out += [f"| `{RADIOMETRY_FLAG[0]}` | {_cell(RADIOMETRY_FLAG[1])} |", ""]
    return "\n".join(out)


def include(path: str) -> str:
    text = (ROOT / path).read_text()
    return re.sub(r"^(#+) ", r"#\1 ", text, flags=re.M)


def on_page_markdown(markdown: str, page, config, files) -> str:
    markdown = markdown.replace("<!-- cli-reference -->", cli_reference())
    markdown = markdown.replace("<!-- output-columns -->", output_columns())
    return re.sub(r"<!-- include (\S+) -->", lambda m: include(m.group(1)), markdown)
