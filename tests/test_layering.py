"""The packages depend one way (ARCHITECTURE.md): udrobot_files <- identification <- udrobot_ctrl.

``identification`` produces the coefficient sets that the vehicle models and the plant consume, so it never
imports ``udrobot_ctrl``; both share the file rules of ``udrobot_files``, which imports neither. A module's
dependencies are read from its head: an import of the project's own modules inside a function is allowed only
with a ``# local import: <reason>`` comment on its line or the line above (e.g. deferring a numba compilation
that only some callers need).
"""
from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("udrobot_files", "identification", "udrobot_ctrl")
#: What each package may import from the project (itself included).
ALLOWED = {"udrobot_files": {"udrobot_files"},
           "identification": {"udrobot_files", "identification"},
           "udrobot_ctrl": {"udrobot_files", "identification", "udrobot_ctrl"}}
MARKER = "local import:"


def _modules(package):
    return sorted((ROOT / package).rglob("*.py"))


def _imported(node, path: Path, package: str) -> list[str]:
    """Absolute names of the modules an Import/ImportFrom node imports (relative ones resolved)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        parts = path.relative_to(ROOT).with_suffix("").parts
        base = parts[:len(parts) - node.level]
        return [".".join(base + ((node.module,) if node.module else ()))]
    return [node.module]


def _project_imports(path: Path, package: str):
    """(line, imported name, inside a function?) of every import of a project package in ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    out = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                for name in _imported(child, path, package):
                    if name.split(".")[0] in PACKAGES:
                        out.append((child.lineno, name, in_function))
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(tree, False)
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_follow_the_data_flow(package):
    """No module imports a package above its own (identification never imports udrobot_ctrl)."""
    wrong = [f"{p.relative_to(ROOT)}:{line} imports {name}"
             for p in _modules(package) for line, name, _ in _project_imports(p, package)
             if name.split(".")[0] not in ALLOWED[package]]
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)


@pytest.mark.slow
def test_importing_identification_loads_no_udrobot_ctrl():
    """Importing every identification module (at run time, re-exports included) loads no udrobot_ctrl module."""
    names = sorted(f"identification.{p.stem}" for p in _modules("identification") if p.stem != "__init__")
    code = ("import importlib, sys\n"
            f"for n in {names!r}: importlib.import_module(n)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'udrobot_ctrl'))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={"MPLBACKEND": "Agg", **os.environ})
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


@pytest.mark.slow
def test_project_imports_are_at_the_top_or_justified():
    """Imports of the project's own modules inside functions carry a ``# local import: reason`` comment."""
    hidden = []
    for package in PACKAGES:
        for p in _modules(package):
            lines = p.read_text().splitlines()
            for line, name, in_function in _project_imports(p, package):
                if in_function and not any(MARKER in lines[i - 1] for i in (line - 1, line) if i >= 1):
                    hidden.append(f"{p.relative_to(ROOT)}:{line} imports {name} inside a function")
    assert not hidden, "function-local imports of the project's modules without a reason:\n" + "\n".join(hidden)
