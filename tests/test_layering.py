"""The packages depend one way (docs/architecture.md): udrobot_files <- identification <- udrobot_ctrl, and inside
udrobot_ctrl its subpackages and top-level modules in the layers of :data:`LAYERS`.

``identification`` produces the coefficient sets that the vehicle models and the plant consume, so it never
imports ``udrobot_ctrl``; both share the file rules of ``udrobot_files``, which imports neither. A module's
dependencies are read from its head: an import of the project's own modules inside a function is allowed only
with a ``# local import: <reason>`` comment on its line or the line above (e.g. deferring a numba compilation
that only some callers need). Every import statement counts for the layers (module level, inside functions and
under ``TYPE_CHECKING``).

The package graph in docs/architecture.md is generated from the source by this module:
``python tests/test_layering.py --write`` rewrites it; :func:`test_architecture_page_is_current` fails when it is
stale.
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


#: udrobot_ctrl's units (subpackages, top-level modules, the package's own ``__init__`` as ``udrobot_ctrl``), bottom
#: layer first. A unit imports only units of lower layers (docs/architecture.md says why each sits where it does).
LAYERS = (
    ("constants", "caches", "parallel", "ardusub"),  # shared names, the cache folders, the process pool, ArduSub's
    # parameters and mode numbers as the firmware defines them: import no unit
    ("dynamics",),  # the plant: equations, effects, thrusters, simulators
    ("vehicle",),  # model files -> Vehicle (reads effects and thruster curves; hands its loader to dynamics.sim)
    ("udrobot_ctrl",),  # the package's __init__: re-exports vehicle's load_model
    ("io",),  # log formats, mappings, the udrobot-run/1 run
    ("control",),  # controllers, missions, EKF, metrics, compare
    ("sensitivity",),  # parameter spaces, local and global sensitivity over the controllers
    ("autopilot",),  # ArduSub's emulation and its gain design (uses control metrics and sensitivity)
    ("convert",),  # log -> run, with ArduSub's mixer, joystick and gain fits
    ("gap",),  # the sim-to-real gap diagnosis
    ("cli",),  # the commands
)
LAYER = {unit: i for i, units in enumerate(LAYERS) for unit in units}
CTRL = ROOT / "udrobot_ctrl"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
BEGIN, END = "<!-- BEGIN generated by tests/test_layering.py -->", "<!-- END generated -->"


def _unit_of_path(path: Path) -> str:
    """The unit a module of udrobot_ctrl belongs to (its subpackage, its own name, or ``udrobot_ctrl``)."""
    parts = path.relative_to(CTRL).with_suffix("").parts
    return "udrobot_ctrl" if parts == ("__init__",) else parts[0]


def _units_imported(node, path: Path) -> list[str]:
    """The udrobot_ctrl units an import statement names (``from udrobot_ctrl import io`` names the unit io)."""
    if isinstance(node, ast.ImportFrom) and not node.level and node.module == "udrobot_ctrl":
        return ["udrobot_ctrl" if a.name not in LAYER else a.name for a in node.names]
    out = []
    for name in _imported(node, path, "udrobot_ctrl"):
        parts = name.split(".")
        if parts[0] == "udrobot_ctrl":
            out.append(parts[1] if len(parts) > 1 else "udrobot_ctrl")
    return out


def unit_imports() -> dict:
    """(importing unit, imported unit) -> ["path:line", ...] of every import between two units of udrobot_ctrl."""
    edges: dict = {}
    for path in _modules("udrobot_ctrl"):
        src = _unit_of_path(path)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for dst in _units_imported(node, path):
                    if dst != src:
                        edges.setdefault((src, dst), []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return edges


def _cycles(edges) -> list:
    """Every cycle of the unit graph, one list of units per strongly connected group of more than one unit."""
    graph: dict = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index, low, stack, on, groups = {}, {}, [], set(), []

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return groups


def test_every_unit_has_a_layer():
    """A new subpackage or top-level module is placed in :data:`LAYERS` (and so on the architecture page)."""
    units = {_unit_of_path(p) for p in _modules("udrobot_ctrl")}
    assert units == set(LAYER), (f"units without a layer: {sorted(units - set(LAYER))}; "
                                 f"layers naming no unit: {sorted(set(LAYER) - units)}")


def test_no_unit_imports_upward():
    """Each unit of udrobot_ctrl imports only units of lower layers (none of its own layer, none above)."""
    wrong = [f"{where} ({a}, layer {LAYER[a]}) imports {b} (layer {LAYER[b]})"
             for (a, b), places in sorted(unit_imports().items()) if LAYER[b] >= LAYER[a] for where in places]
    assert not wrong, "imports against the layers of udrobot_ctrl:\n" + "\n".join(wrong)


def test_no_import_cycle_between_units():
    """The unit graph has no cycle, whatever the declared layers say."""
    assert _cycles(unit_imports()) == []


def test_cycle_finder_finds_a_cycle():
    """The cycle check can fail: a two-unit and a three-unit cycle beside an acyclic edge are both reported."""
    edges = {("a", "b"): [], ("b", "a"): [], ("c", "d"): [], ("d", "e"): [], ("e", "c"): [], ("a", "c"): []}
    assert sorted(_cycles(edges)) == [["a", "b"], ["c", "d", "e"]]


@pytest.mark.slow
def test_importing_the_plant_loads_no_io_or_autopilot():
    """``import udrobot_ctrl.dynamics.plant`` loads only the layers up to the vehicle (the package's __init__ loads
    vehicle.py): no io, control, autopilot or other module above."""
    code = ("import sys, udrobot_ctrl.dynamics.plant\n"
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'udrobot_ctrl')))")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={"MPLBACKEND": "Agg", **os.environ})
    assert res.returncode == 0, res.stderr
    loaded = res.stdout.split()
    assert "udrobot_ctrl.dynamics.plant" in loaded
    above = [m for m in loaded if LAYER["udrobot_ctrl" if m == "udrobot_ctrl" else m.split(".")[1]]
             > LAYER["udrobot_ctrl"]]
    assert not above, f"import udrobot_ctrl.dynamics.plant loads {above}"


def architecture_block(edges=None) -> str:
    """The generated part of docs/architecture.md: the layers and a Mermaid graph of the imports between units."""
    edges = unit_imports() if edges is None else edges
    lines = [BEGIN, "", "| layer | units | imports |", "|---|---|---|"]
    for i, units in reversed(list(enumerate(LAYERS))):
        for u in units:
            deps = sorted({b for a, b in edges if a == u}, key=lambda b: (-LAYER[b], b))
            lines.append(f"| {i} | `{u}` | {', '.join(f'`{d}`' for d in deps) or '(none)'} |")
    lines += ["", "```mermaid", "flowchart TD"]
    for i, units in reversed(list(enumerate(LAYERS))):
        lines += [f"    subgraph L{i} [\"layer {i}\"]", *(f"        {u}" for u in units), "    end"]
    lines += [f"    {a} --> {b}" for a, b in sorted(edges, key=lambda e: (-LAYER[e[0]], e[0], -LAYER[e[1]], e[1]))]
    lines += ["```", "", END]
    return "\n".join(lines)


def _page_block(text: str) -> str:
    start, end = text.find(BEGIN), text.find(END)
    assert 0 <= start < end, f"{ARCHITECTURE}: no generated block ({BEGIN} ... {END})"
    return text[start:end + len(END)]


def test_architecture_page_is_current():
    """docs/architecture.md holds the graph the source has now (regenerate: python tests/test_layering.py --write)."""
    assert _page_block(ARCHITECTURE.read_text()) == architecture_block(), (
        "docs/architecture.md is stale: run python tests/test_layering.py --write")


def write_architecture_page() -> None:
    """Replace the generated block of docs/architecture.md with the current graph."""
    text = ARCHITECTURE.read_text()
    ARCHITECTURE.write_text(text.replace(_page_block(text), architecture_block()))


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        raise SystemExit("usage: python tests/test_layering.py --write  (rewrites docs/architecture.md's graph)")
    write_architecture_page()
