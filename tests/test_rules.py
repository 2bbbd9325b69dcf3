"""The house rules that can be checked from the source, checked: no function over 80 lines, a test file per module.

Both read the tree as files (the AST, the paths), not by importing it. A function is every `def` and `async def`
the AST holds: module-level functions, methods and functions nested in another function alike, each counted on
its own from its `def` line to its last line (decorators excluded, a nested function's lines counting in its
parent too). A module of fwcore or pipeline other than a package's `__init__.py` has its tests at the matching
path under tests/: fwcore/engine/x.py -> tests/fwcore/engine/test_x.py (a private `_x.py` -> `test_x.py`).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fwcore", "pipeline")
MAX_LINES = 80


def source_files() -> list[Path]:
    """Every .py file of PACKAGES, sorted."""
    return sorted(path for package in PACKAGES for path in (ROOT / package).rglob("*.py"))


def long_functions(source: str, limit: int = MAX_LINES) -> list[tuple[str, int]]:
    """(qualified name, lines) of every function in `source` longer than `limit` lines, decorators excluded."""
    found = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                lines = child.end_lineno - child.lineno + 1
                if lines > limit:
                    found.append((name, lines))
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


def test_long_functions_counts_methods_and_nested_functions_without_decorators():
    body = "\n".join(f"    x{i} = {i}" for i in range(80))  # 80 body lines: 81 with the def
    source = (f"@decorator\n@another(1)\ndef top():\n{body}\n"
              f"class A:\n    def method(self):\n{body.replace('    ', '        ')}\n"
              f"def outer():\n    def inner():\n{body.replace('    ', '        ')}\n    return inner\n"
              "def short():\n    return 1\n")
    assert long_functions(source) == [("top", 81), ("A.method", 81), ("outer", 83), ("outer.inner", 81)]
    assert long_functions(source, limit=81) == [("outer", 83)]


def test_no_function_over_80_lines_in_fwcore_or_pipeline():
    found = [f"{path.relative_to(ROOT)}: {name} ({lines})"
             for path in source_files() for name, lines in long_functions(path.read_text())]
    assert found == []


def matching_test_file(path: Path) -> Path:
    """The test file of module `path`: tests/<its folder>/test_<its name without a leading underscore>."""
    relative = path.relative_to(ROOT)
    return ROOT / "tests" / relative.parent / f"test_{relative.name.lstrip('_')}"


def modules() -> list[Path]:
    """The modules that need a test file: every source file but a package's __init__.py."""
    return [path for path in source_files() if path.name != "__init__.py"]


def test_matching_test_file_mirrors_the_source_tree():
    assert matching_test_file(ROOT / "fwcore" / "engine" / "model.py") == ROOT / "tests" / "fwcore" / "engine" / "test_model.py"
    assert matching_test_file(ROOT / "pipeline" / "view" / "app.py") == ROOT / "tests" / "pipeline" / "view" / "test_app.py"
    assert matching_test_file(ROOT / "fwcore" / "_jit.py") == ROOT / "tests" / "fwcore" / "test_jit.py"
    assert ROOT / "fwcore" / "engine" / "model.py" in modules()
    assert not any(path.name == "__init__.py" for path in modules())


def test_every_module_has_its_test_file():
    names = [matching_test_file(path) for path in modules()]
    assert len(set(names)) == len(names)  # no `x.py` beside a `_x.py`: each test file is one module's
    missing = [str(path.relative_to(ROOT)) for path in modules() if not matching_test_file(path).is_file()]
    assert missing == []


def test_the_naive_references_import_nothing_they_check():
    # tests/fwcore/naive.py re-derives the kernels from their equations: of fwcore only the shared random stream
    tree = ast.parse((ROOT / "tests" / "fwcore" / "naive.py").read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    assert {name for name in imported if name.split(".")[0] in PACKAGES + ("tests",)} == {"fwcore.rng"}
