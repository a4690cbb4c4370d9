"""Sphinx configuration: the guides (Markdown, via myst-parser) and the API reference (numpydoc docstrings).

Build (warnings are errors, as in CI)::

    python -m pip install -e ".[docs]"
    sphinx-build -W -b html docs docs/_build/html

The API pages are generated here, before reading, from each package's ``__all__`` (the public API that
tests/test_docstrings.py checks), into ``docs/api/`` (not in git): one page per package, with an autosummary
table whose entries get a page each; likewise ``docs/examples/`` from the scripts in ``examples/``.
"""
from __future__ import annotations

import ast
import importlib
import inspect
import sys
from pathlib import Path

from pygments.lexers.special import TextLexer

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))

project = "udrobot-ctrl"
author = "udrobot-ctrl authors"
copyright = "udrobot-ctrl authors, MIT licence"  # noqa: A001 (Sphinx's name)

extensions = ["sphinx.ext.autodoc", "sphinx.ext.autosummary", "numpydoc", "myst_parser"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "api/generated/*.rst.tmp", "tutorial_run.py"]
html_theme = "alabaster"
html_static_path: list = []

myst_heading_anchors = 4  # the guides link to sections by their GitHub-style anchors (runlog.md#segments)
myst_enable_extensions = ["dollarmath"]
templates_path = ["_templates"]  # autosummary/class.rst: a class page documents its public methods in full
autosummary_generate = True
autosummary_imported_members = True
numpydoc_show_class_members = False  # a class page shows its docstring (fields in Parameters/Attributes)
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

#: The packages whose ``__all__`` is the public API, in the order of the reference (as the docstring test).
PACKAGES = ("udrobot_ctrl", "udrobot_ctrl.vehicle", "udrobot_ctrl.dynamics", "udrobot_ctrl.control",
            "udrobot_ctrl.ardusub", "udrobot_ctrl.autopilot", "udrobot_ctrl.io", "udrobot_ctrl.gap",
            "udrobot_ctrl.sensitivity",
            "identification")


def pending() -> set:
    """The public names another branch is still adding: ``PENDING`` of tests/test_docstrings.py (one list)."""
    tree = ast.parse((ROOT / "tests" / "test_docstrings.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "PENDING" for t in node.targets):
            return set(ast.literal_eval(node.value))
    raise RuntimeError("tests/test_docstrings.py defines no PENDING")


def _kind(obj) -> str:
    if inspect.isclass(obj):
        return "class"
    return "function" if callable(obj) else "data"


def package_page(package: str, skip: set) -> str:
    """The reST of one package's API page: its docstring and an autosummary table of its ``__all__``."""
    module = importlib.import_module(package)
    names = [n for n in module.__all__ if f"{package}.{n}" not in skip]
    rows = {"class": [], "function": [], "data": []}
    for name in names:
        rows[_kind(getattr(module, name))].append(name)
    title = f"``{package}``"
    out = [title, "=" * len(title), "", f".. automodule:: {package}", "   :no-members:", "",
           f".. currentmodule:: {package}", ""]
    for kind, heading in (("function", "Functions"), ("class", "Classes"), ("data", "Constants")):
        if not rows[kind]:
            continue
        out += [heading, "-" * len(heading), "", ".. autosummary::"]
        if kind != "data":
            out += ["   :toctree: generated", "   :nosignatures:"]
        out += [""] + [f"   {n}" for n in rows[kind]] + [""]
        if kind == "data":
            out += [f".. autodata:: {n}\n" for n in rows[kind]]
    return "\n".join(out) + "\n"


def api_index() -> str:
    """The reST of the API reference's front page: what the public API is, the package pages, the layers."""
    out = ["API reference", "=============", "",
           "The public API is each package's ``__all__``: what ``from udrobot_ctrl.dynamics import simulate`` and "
           "the like give. Every name has a numpydoc docstring with its parameters and results in SI units "
           "(checked by ``tests/test_docstrings.py``); everything else is an implementation detail that may "
           "change.", "", ".. toctree::", "   :maxdepth: 1", ""]
    out += [f"   {package}" for package in PACKAGES]
    if (DOCS / "architecture.md").exists():  # the package graph, generated from the imports by the layering test
        out.append("   ../architecture")
    return "\n".join(out) + "\n"


def _write(page: Path, text: str) -> None:
    """Write a generated page only when its text changed (so rebuilds stay quick)."""
    if not page.exists() or page.read_text(encoding="utf-8") != text:
        page.write_text(text, encoding="utf-8")


def write_api_pages() -> None:
    """Write docs/api/index.rst and docs/api/<package>.rst for every package."""
    folder = DOCS / "api"
    folder.mkdir(exist_ok=True)
    skip = pending()
    _write(folder / "index.rst", api_index())
    for package in PACKAGES:
        _write(folder / f"{package}.rst", package_page(package, skip))


def examples_page() -> str:
    """The reST of the examples page: each script of examples/ with its docstring and its source."""
    out = ["Examples", "========", "",
           "The scripts in ``examples/`` of the repository, each run as ``python examples/NAME.py`` from the "
           "repository's root (``--help`` lists its options).", ""]
    for script in sorted((ROOT / "examples").glob("*.py")):
        doc = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
        title = f"``{script.name}``"
        out += [title, "-" * len(title), "", "::", ""]
        out += [f"    {line}" if line else "" for line in doc.splitlines()] + [""]
        out += [f".. literalinclude:: ../../examples/{script.name}", "   :language: python", ""]
    return "\n".join(out) + "\n"


def write_generated_pages() -> None:
    """The API pages (:func:`write_api_pages`) and docs/examples/index.rst (not in git)."""
    write_api_pages()
    folder = DOCS / "examples"
    folder.mkdir(exist_ok=True)
    _write(folder / "index.rst", examples_page())


def escape_bars(line: str) -> str:
    """``|u|`` (an absolute value in the docstrings' formulas) escaped outside ``literals``: not a substitution."""
    parts = line.split("``")
    return "``".join(p if i % 2 else p.replace("|", r"\|") for i, p in enumerate(parts))


def plain_bars(app, what, name, obj, options, lines) -> None:
    """autodoc-process-docstring: the docstrings write math in plain text, where ``|x|`` is a magnitude."""
    lines[:] = [escape_bars(line) for line in lines]


def setup(app):
    # Mermaid graphs (docs/architecture.md) are shown as their source: no highlighter, no extra dependency
    app.add_lexer("mermaid", TextLexer)
    app.connect("config-inited", lambda app, config: write_generated_pages())
    app.connect("autodoc-process-docstring", plain_bars, priority=400)

