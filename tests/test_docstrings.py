"""Every public name has a numpydoc docstring: a summary, ``Parameters`` and ``Returns`` (python-control's rule).

The public API is each package's ``__all__`` (:data:`PACKAGES`). A docstring is parsed with numpydoc's
:class:`~numpydoc.docscrape.NumpyDocString` (an unknown section or a malformed one is a failure). A callable with
parameters documents each of them, by its name, in ``Parameters`` (a class: its constructor's, in ``Parameters``
or, for a dataclass, ``Attributes``), none left out and none that the signature does not have; a function whose
body returns a value has ``Returns`` (one that yields, ``Yields``); every entry has a description. A quantity
typed ``float`` names its unit (SI) or says it has none: the description holds a unit from :data:`UNITS` or one of
the words of :data:`NO_UNIT`. A constant has a ``#:`` comment (what the API reference shows for it).
"""
from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import os
import pkgutil
import re
import subprocess
import sys
import textwrap
import types
import warnings
from pathlib import Path

import pytest
from numpydoc.docscrape import NumpyDocString
from sphinx.pycode import ModuleAnalyzer

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("udrobot_ctrl", "udrobot_ctrl.vehicle", "udrobot_ctrl.dynamics", "udrobot_ctrl.control",
            "udrobot_ctrl.ardusub", "udrobot_ctrl.autopilot", "udrobot_ctrl.io", "udrobot_ctrl.gap",
            "udrobot_ctrl.sensitivity",
            "identification")
#: Public names whose definition another branch of issue 60 is adding (the coordinator empties this on merging):
#: gap's Diagnosis (the coordinator's diagnose() result) and control's Comparison (v6-layers' compare() result).
PENDING = set()
#: Unit symbols (SI and the derived ones the code uses) that a float quantity's description may name.
UNITS = ("m", "s", "kg", "N", "rad", "deg", "Hz", "W", "V", "A", "Pa", "us", "µs", "°", "%", "1/s", "m/s",
         "rad/s", "N m", "N·m", "kg m^2", "m^2", "m^3", "kg/m^3", "m/s^2", "rad/s^2", "N/m", "ms", "PWM", "mm",
         "dB", "degrees", "radians", "seconds", "metres", "newtons")
#: Words saying a float quantity has no unit.
NO_UNIT = ("dimensionless", "fraction", "ratio", "count", "factor", "probability", "no unit", "unitless",
           "normalised", "normalized", "relative", "index", "level", "weight", "multiplier", "p-value")


def _public(package: str):
    module = importlib.import_module(package)
    return [(f"{package}.{name}", name, module) for name in module.__all__]


PUBLIC = [entry for package in PACKAGES for entry in _public(package)]


def _resolve(qualified: str, name: str, module):
    if qualified in PENDING:
        if hasattr(module, name):
            pytest.fail(f"{qualified} exists now: remove it from PENDING so that it is checked (and documented)")
        pytest.xfail(f"{qualified} is added by another branch of issue 60 (PENDING)")
    return getattr(module, name)


def _signature_parameters(obj) -> list[str]:
    """The names a caller passes (``self``/``cls`` dropped; ``*args`` and ``**kwargs`` by their starred names)."""
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return []
    stars = {inspect.Parameter.VAR_POSITIONAL: "*", inspect.Parameter.VAR_KEYWORD: "**"}
    return [stars.get(p.kind, "") + p.name for p in sig.parameters.values() if p.name not in ("self", "cls")]


def _own_nodes(fn_node):
    """The AST nodes of a function's own body (not of the functions and classes nested in it)."""
    stack = list(fn_node.body)
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            stack.extend(ast.iter_child_nodes(node))


def _gives(fn) -> str | None:
    """``"Returns"`` if ``fn``'s body returns a value, ``"Yields"`` if it yields, None if neither."""
    try:
        source = textwrap.dedent(inspect.getsource(inspect.unwrap(fn)))
    except (OSError, TypeError):
        return None
    node = ast.parse(source).body[0]
    own = list(_own_nodes(node))
    if any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in own):
        return "Yields"
    if any(isinstance(n, ast.Return) and n.value is not None for n in own):
        return "Returns"
    return None


def _parsed(obj, qualified: str) -> NumpyDocString:
    doc = inspect.getdoc(obj)
    assert doc, f"{qualified} has no docstring"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpydoc warns on an unknown section: a misspelt heading is a failure
        return NumpyDocString(doc)


def _names(entries) -> list[str]:
    """The parameter names of numpydoc entries (``a, b : float`` documents both)."""
    return [n.strip() for e in entries for n in e.name.split(",")]


def _has_unit(text: str) -> bool:
    low = text.lower()
    if any(w in low for w in NO_UNIT):
        return True
    return any(re.search(rf"(?<![\w/^]){re.escape(u)}(?![\w^])", text) for u in UNITS)


def _problems(obj, qualified: str) -> list[str]:
    doc = _parsed(obj, qualified)
    out = []
    if not " ".join(doc["Summary"]).strip():
        out.append("no summary line")
    is_class = inspect.isclass(obj)
    if is_class and issubclass(obj, BaseException):
        return out  # an error is documented by its summary (its message names the problem)
    wanted = _signature_parameters(obj)
    sections = ("Parameters", "Attributes") if is_class and dataclasses.is_dataclass(obj) else ("Parameters",)
    entries = [e for s in sections for e in doc[s]]
    documented = _names(entries)
    if wanted:
        missing = [n for n in wanted if n not in documented]
        if missing:
            out.append(f"{' or '.join(sections)} missing {missing}")
        if "Parameters" in sections and doc["Parameters"]:
            extra = [n for n in _names(doc["Parameters"]) if n not in wanted and n.lstrip("*") not in wanted]
            if extra:
                out.append(f"Parameters documents {extra}, not in the signature")
    gives = None if is_class else _gives(obj)
    if gives and not doc[gives]:
        out.append(f"no {gives} section (the function {gives.lower()[:-1]}s a value)")
    for section in (*sections, "Returns", "Yields"):
        for e in doc[section]:
            text = " ".join(e.desc).strip()
            if not text:
                out.append(f"{section} entry {e.name!r} has no description")
            elif re.search(r"\bfloat\b", e.type) and not _has_unit(f"{e.type} {text}"):
                out.append(f"{section} entry {e.name or e.type!r} (float) names no unit")
    return out


def test_every_package_lists_its_public_api():
    """Each package has a non-empty ``__all__`` without repeats, naming no submodule of its own."""
    for package in PACKAGES:
        module = importlib.import_module(package)
        names = list(module.__all__)
        assert names and len(names) == len(set(names)), package
        # a package attribute that is also a submodule's name changes meaning once the submodule is imported
        here = Path(module.__file__).parent if module.__file__.endswith("__init__.py") else None
        clash = [n for n in names if here is not None and ((here / f"{n}.py").exists() or (here / n).is_dir())]
        assert not clash, f"{package} exports names of its own submodules: {clash}"


def _has_doc_comment(module, name: str) -> bool:
    """A ``#:`` comment documents ``name`` in ``module`` or in one of its package's modules (what autodoc shows)."""
    names = [module.__name__]
    if hasattr(module, "__path__"):
        names += [f"{module.__name__}.{m.name}" for m in pkgutil.iter_modules(module.__path__)]
    return any(("", name) in ModuleAnalyzer.for_module(n).find_attr_docs() for n in names)


@pytest.mark.parametrize("qualified, name, module", PUBLIC, ids=[q for q, _, _ in PUBLIC])
def test_public_name_has_numpydoc_docstring(qualified, name, module):
    obj = _resolve(qualified, name, module)
    assert not isinstance(obj, types.ModuleType), f"{qualified} is a module, not a function or class"
    if not callable(obj):  # a constant: its ``#:`` comment is its documentation (autodoc shows it)
        assert _has_doc_comment(module, name), f"{qualified}: a constant without a '#:' comment saying what it is"
        return
    problems = _problems(obj, qualified)
    assert not problems, f"{qualified}: " + "; ".join(problems)


def test_checker_finds_missing_sections():
    """The checker fails a function without Parameters/Returns and one whose float names no unit."""

    def bare(x, dt=0.1):
        """Do something."""
        return x * dt

    def unitless(x):
        """Scale.

        Parameters
        ----------
        x : float
            The value.

        Returns
        -------
        y : float
            Twice ``x``, m.
        """
        return 2 * x

    def good(x, *args):
        """Scale.

        Parameters
        ----------
        x : float
            Distance, m.
        *args
            Ignored.

        Returns
        -------
        float
            Twice ``x``, m.
        """
        return 2 * x

    assert _problems(bare, "bare") == ["Parameters missing ['x', 'dt']",
                                       "no Returns section (the function returns a value)"]
    assert _problems(unitless, "unitless") == ["Parameters entry 'x' (float) names no unit"]
    assert _problems(good, "good") == []


def test_checker_finds_undocumented_constants(tmp_path, monkeypatch):
    """A constant counts as documented by a ``#:`` comment in its package or one of the package's modules."""
    (tmp_path / "docpkg").mkdir()
    (tmp_path / "docpkg" / "__init__.py").write_text("#: documented here\nA = 1\nB = 2\n")
    (tmp_path / "docpkg" / "part.py").write_text("#: documented in a module\nC = 3\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("docpkg")
    assert [_has_doc_comment(module, n) for n in ("A", "B", "C")] == [True, False, True]


@pytest.mark.slow
@pytest.mark.parametrize("package", PACKAGES)
def test_public_names_import_in_a_fresh_interpreter(package):
    """``from package import name`` works first thing in a new process, for every name (no import cycle)."""
    module = importlib.import_module(package)
    names = [n for n in module.__all__ if f"{package}.{n}" not in PENDING]
    code = f"from {package} import {', '.join(names)}"
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert res.returncode == 0, res.stderr[-2000:]
