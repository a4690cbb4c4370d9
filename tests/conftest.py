"""Test-session settings shared by every test module.

The default run (``python -m pytest -q``) is spread over the machine's cores by pytest-xdist (``-n auto`` in
``pyproject.toml``). Each xdist worker then runs ``fork_map`` / ``Background`` / ``Helper`` work in its own process
(``UDROBOT_JOBS=1``) instead of forking one worker per core as well: the xdist workers already keep every core busy,
and a second level of workers would only oversubscribe them. The results are the serial loop's either way
(:mod:`udrobot_ctrl.parallel`). Tests that need forked workers set ``UDROBOT_JOBS`` themselves (``test_parallel``,
``test_signals``, ``test_attribute``), which overrides this default. A serial run (``-n 0``) keeps the usual
default (one worker per core).

Shared fixtures and xdist (``--dist loadgroup`` in ``pyproject.toml``): a module-, package- or session-scoped
fixture is computed once per xdist worker that runs a test requesting it. So that a diagnosis (simulation, design)
several tests read is computed once per test run, not once per worker, every test that requests such a fixture
defined in the test tree is put in one xdist group with every other test reading the same instance
(:func:`shared_fixture_groups`). A test that carries
its own ``@pytest.mark.xdist_group(...)`` keeps it (a factory fixture whose cases are independent, e.g.
``test_diagnose.diagnosed``, groups each case by what it shares). Tests without a shared fixture are dealt one by one
to whichever worker is free.

The extended tier (``python -m pytest --extended``): tests marked ``extended`` are further cases of a mechanism the
default run already checks with one representative case (more effects, look-alike pairs, log variants of one field
dive); they are deselected from the default run so that it stays within its time budget on 2 cores, and run with
``--extended`` (alone: ``python -m pytest --extended -m extended``).

``--cpu-durations=N`` prints the N tests with the most CPU time (setup + call + teardown: this process's user and
system time plus that of the subprocesses it waited for). On a shared machine the wall times of ``--durations`` grow
with the load; CPU times do not, so they are the ones to compare between runs.
"""
from __future__ import annotations

import os
import resource
import time
import types

import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):  # set by xdist in its workers before this file is imported
    os.environ.setdefault("UDROBOT_JOBS", "1")

SHARED_SCOPES = ("module", "package", "session")
_START = pytest.StashKey[tuple]()  # (CPU s, wall s) when a test's setup began
_LOGGED: dict = {}  # node id -> (CPU s, wall s) of setup + call + teardown, as reported (from every worker)


def shared_fixtures(item) -> list:
    """The shared fixtures a test reads, each as the key of its one instance in a run.

    Parameters
    ----------
    item : pytest.Item
        A collected test.

    Returns
    -------
    list of str
        ``<module node id>::<name>`` of each module-scoped fixture in its closure (one instance per module) and
        ``<where it is defined>::<name>`` of each package- or session-scoped one. Fixtures of pytest and its plugins
        (``tmp_path_factory`` ...: no ``baseid``) are not shared work and do not count.
    """
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    module = item.nodeid.split("::", 1)[0]
    keys = []
    for name in sorted(info.name2fixturedefs):
        defs = info.name2fixturedefs[name]
        if not defs or not defs[-1].baseid or defs[-1].scope not in SHARED_SCOPES:
            continue
        keys.append(f"{module}::{name}" if defs[-1].scope == "module" else f"{defs[-1].baseid}::{name}")
    return keys


def shared_fixture_groups(items) -> dict:
    """The xdist group of every test that shares a fixture instance with another test (or reads one at all).

    Tests are linked when they read the same instance of a shared fixture (:func:`shared_fixtures`); each connected
    set of tests is one group, named after its first fixture key (sorted), so that independent fixtures of one module
    (three diagnoses, say) may run on different workers while the tests reading one of them run on one.

    Parameters
    ----------
    items : list of pytest.Item

    Returns
    -------
    dict
        node id -> group name, for the tests that read a shared fixture.
    """
    parent: dict = {}

    def root(key):
        while parent[key] != key:
            parent[key] = parent[parent[key]]
            key = parent[key]
        return key

    reads = {item.nodeid: shared_fixtures(item) for item in items}
    for keys in reads.values():
        for key in keys:
            parent.setdefault(key, key)
        for key in keys[1:]:
            a, b = root(keys[0]), root(key)
            if a != b:
                parent[max(a, b)] = min(a, b)
    return {nodeid: root(keys[0]) for nodeid, keys in reads.items() if keys}


def extended_cases(items, run_extended: bool) -> tuple:
    """Split the collected tests into those to run and those deselected: a test marked ``extended`` (a further
    case of a mechanism the default run already checks with one representative case) runs only with
    ``--extended``.

    Returns
    -------
    tuple of list
        (kept, deselected), each in collection order.
    """
    if run_extended:
        return list(items), []
    kept = [item for item in items if item.get_closest_marker("extended") is None]
    return kept, [item for item in items if item.get_closest_marker("extended") is not None]


@pytest.hookimpl(tryfirst=True)  # before xdist's worker hook, which appends the group names to the node ids
def pytest_collection_modifyitems(config, items):
    kept, deselected = extended_cases(items, config.getoption("--extended"))
    if deselected:
        config.hook.pytest_deselected(items=deselected)
        items[:] = kept
    free = [item for item in items if item.get_closest_marker("xdist_group") is None]  # an explicit group is kept
    groups = shared_fixture_groups(free)
    for item in free:
        if item.nodeid in groups:
            item.add_marker(pytest.mark.xdist_group(groups[item.nodeid]))


def xdist_can_group() -> bool:
    """Whether pytest-xdist's way of putting a test in its group works under this pytest: xdist (3.8) appends
    ``@group`` to a test's node id by assigning ``item._nodeid`` and schedules by that suffix; pytest 9 derives
    ``nodeid`` from another attribute, so the suffix is lost and ``--dist loadgroup`` splits the groups over the
    workers (each then computing the shared fixtures again)."""
    probe = types.SimpleNamespace(_nodeid="test_x@group", _id="test_x")
    try:
        return pytest.Item.nodeid.fget(probe) == "test_x@group"
    except AttributeError:
        return False


def pytest_configure(config):
    if config.getoption("dist", "no") == "loadgroup" and not os.environ.get("PYTEST_XDIST_WORKER") \
            and not xdist_can_group():
        raise pytest.UsageError(
            f"pytest {pytest.__version__} with --dist loadgroup: pytest-xdist cannot put the tests in their groups "
            f"(it renames item._nodeid, which this pytest no longer reads), so every worker would compute the shared "
            f"fixtures again; install pytest<9 (python -m pip install -e '.[dev]')")


def pytest_addoption(parser):
    parser.addoption("--extended", action="store_true", default=False,
                     help="also run the tests marked extended (further cases of mechanisms the default run checks "
                          "with one case each; list them with --extended -m extended --collect-only)")
    parser.addoption("--cpu-durations", type=int, default=None, metavar="N",
                     help="show the N tests with the most CPU time (process + waited-for children), N=0 for all")


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    if call.when == "teardown":  # the protocol's timing ends after this report: measure up to here
        report = outcome.get_result()
        start = item.stash.get(_START, None)
        if start is not None:
            report.user_properties.append(("cpu_s", _cpu_seconds() - start[0]))
            report.user_properties.append(("wall_s", time.perf_counter() - start[1]))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_START] = (_cpu_seconds(), time.perf_counter())


def pytest_runtest_logreport(report):
    if report.when != "teardown":
        return
    props = dict(report.user_properties)
    if "cpu_s" in props:
        _LOGGED[report.nodeid] = (props["cpu_s"], props["wall_s"])


def pytest_terminal_summary(terminalreporter, config):
    n = config.getoption("--cpu-durations")
    if n is None or not _LOGGED:
        return
    rows = sorted(_LOGGED.items(), key=lambda kv: -kv[1][0])
    total_cpu = sum(c for c, _ in _LOGGED.values())
    terminalreporter.write_sep("=", f"slowest {n or len(rows)} by CPU time (of {len(rows)} tests: "
                                    f"{total_cpu:.1f} CPU-s in tests)")
    for nodeid, (cpu, wall) in rows[: n or None]:
        terminalreporter.write_line(f"{cpu:8.2f}s cpu {wall:8.2f}s wall  {nodeid}")
