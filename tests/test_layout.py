"""Module and function sizes against the limits of docs/design.md §2 ("Size")."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("quadslam_env", "estimators", "agents")
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
# An entry of the design doc's list: "- `path/to/module.py` `function`: why".
LIST_TITLE = "Functions over 80 lines, and why"
ENTRY = re.compile(r"^\s+- `(?P<path>[\w/]+\.py)` `(?P<name>\w+)`")


def _modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def _long_functions(path: Path, limit: int) -> dict[str, int]:
    """``{name: lines}`` of the functions (methods and nested ones too) in ``path`` longer than
    ``limit`` lines, counted from the ``def`` line to the last line, docstring included."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return {
        node.name: length
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and (length := (node.end_lineno or node.lineno) - node.lineno + 1) > limit
    }


def documented_exceptions(text: str) -> set[tuple[str, str]]:
    """``(path, function)`` pairs of the design doc's list "Functions over 80 lines, and why":
    the indented bullet items that follow the line naming it, up to the first other line.

    Raises:
        ValueError: The doc has no such list.
    """
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if LIST_TITLE in line), None)
    if start is None:
        raise ValueError(f"docs/design.md: no list {LIST_TITLE!r}")
    found: set[tuple[str, str]] = set()
    for line in lines[start + 1 :]:
        if not re.match(r"^\s+- ", line):
            break
        match = ENTRY.match(line)
        if match:
            found.add((match["path"], match["name"]))
    return found


def test_documented_exceptions_parse_the_list() -> None:
    text = (
        "- Size: at most 80 lines.\n"
        f"  {LIST_TITLE} (the test reads this list):\n"
        "  - `estimators/a.py` `kernel_one`: one loop.\n"
        "  - `agents/b.py` `run`: reason.\n"
        "- Next convention, not an item:\n"
        "  - `estimators/c.py` `not_listed`: after the list.\n"
    )
    assert documented_exceptions(text) == {
        ("estimators/a.py", "kernel_one"),
        ("agents/b.py", "run"),
    }
    assert documented_exceptions(f"{LIST_TITLE}:\n  - none.\n") == set()
    with pytest.raises(ValueError, match="no list"):
        documented_exceptions(text.replace(LIST_TITLE, "Long functions"))


def test_long_functions_counts_def_to_last_line(tmp_path: Path) -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(80))
    path = tmp_path / "m.py"
    # 1 def line + 80 body lines = 81 lines; the short one has 2.
    path.write_text(f"def long():\n{body}\n\n\ndef short():\n    return 1\n")
    assert _long_functions(path, 80) == {"long": 81}
    assert _long_functions(path, 81) == {}


def test_no_module_over_500_lines() -> None:
    too_long = {
        str(p.relative_to(ROOT)): n
        for p in _modules()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not too_long, f"modules over {MAX_MODULE_LINES} lines: {too_long}"


def test_no_function_over_80_lines_unless_the_design_doc_lists_it() -> None:
    allowed = documented_exceptions((ROOT / "docs" / "design.md").read_text(encoding="utf-8"))
    long = {
        (str(p.relative_to(ROOT)), name): n
        for p in _modules()
        for name, n in _long_functions(p, MAX_FUNCTION_LINES).items()
    }
    unlisted = {k: n for k, n in long.items() if k not in allowed}
    assert not unlisted, (
        f"functions over {MAX_FUNCTION_LINES} lines not in docs/design.md §2 "
        f"('Functions over 80 lines'): {unlisted}"
    )
    stale = allowed - set(long)
    assert not stale, f"docs/design.md §2 lists functions no longer over 80 lines: {stale}"


def test_test_modules_have_unique_names() -> None:
    """pytest imports each test folder's modules by their bare names (no ``__init__.py``), so
    two modules of one name in different folders would stop the collection."""
    names: dict[str, list[str]] = {}
    for p in (ROOT / "tests").rglob("*.py"):
        if p.name != "conftest.py" and "__pycache__" not in p.parts:
            names.setdefault(p.stem, []).append(str(p.relative_to(ROOT)))
    assert not {k: v for k, v in names.items() if len(v) > 1}


def _package_names(module: str) -> tuple[set[str], dict[str, str]]:
    """The names a module defines, and those it imports from the project (name → module)."""
    path = ROOT / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    defined: set[str] = set()
    imported: dict[str, str] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            defined.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            defined |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif (
            isinstance(node, ast.ImportFrom)
            and node.module
            and node.level == 0
            and node.module.split(".")[0] in PACKAGES
        ):
            imported |= {a.asname or a.name: node.module for a in node.names}
    return defined, imported


def test_the_project_imports_each_name_from_the_module_that_defines_it() -> None:
    """One import path per name inside the project (docs/design.md §1): a package's
    ``__init__`` may list names defined in its modules for the users, but no module of the
    packages, the tests or the tools imports a name through such a re-export."""
    reexports: dict[str, dict[str, str]] = {}
    for top in PACKAGES:
        for init in (ROOT / top).rglob("__init__.py"):
            package = ".".join(init.parent.relative_to(ROOT).parts)
            defined, imported = _package_names(package)
            reexports[package] = {k: v for k, v in imported.items() if k not in defined}
    through: list[str] = []
    for top in (*PACKAGES, "tests", "tools"):
        for p in (ROOT / top).rglob("*.py"):
            if p.name == "__init__.py" or "__pycache__" in p.parts:
                continue
            for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.module in reexports:
                    through += [
                        f"{p.relative_to(ROOT)}: {node.module}.{a.name}"
                        for a in node.names
                        if a.name in reexports[node.module]
                    ]
    assert not through, through
