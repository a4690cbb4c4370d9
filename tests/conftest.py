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
defined in the test tree is put in one xdist group (:func:`shared_fixture_group`): the module's path for a
module-scoped fixture, ``<where it is defined>::<name>`` for a package- or session-scoped one. A test that carries
its own ``@pytest.mark.xdist_group(...)`` keeps it (a factory fixture whose cases are independent, e.g.
``test_diagnose.diagnosed``, groups each case by what it shares). Tests without a shared fixture are dealt one by one
to whichever worker is free.

``--cpu-durations=N`` prints the N tests with the most CPU time (setup + call + teardown: this process's user and
system time plus that of the subprocesses it waited for). On a shared machine the wall times of ``--durations`` grow
with the load; CPU times do not, so they are the ones to compare between runs.
"""
from __future__ import annotations

import os
import resource
import time

import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):  # set by xdist in its workers before this file is imported
    os.environ.setdefault("UDROBOT_JOBS", "1")

SHARED_SCOPES = ("module", "package", "session")
_START = pytest.StashKey[tuple]()  # (CPU s, wall s) when a test's setup began
_LOGGED: dict = {}  # node id -> (CPU s, wall s) of setup + call + teardown, as reported (from every worker)


def shared_fixture_group(item) -> str | None:
    """The xdist group of a test that requests a shared fixture defined in the test tree, or None.

    Parameters
    ----------
    item : pytest.Item
        A collected test.

    Returns
    -------
    str or None
        ``<where>::<name>`` of its first (sorted by name) package- or session-scoped fixture, else the module's
        node id if it requests a module-scoped one, else None. Fixtures of pytest and its plugins
        (``tmp_path_factory`` ...: no ``baseid``) are not shared work and do not count.
    """
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return None
    wide, module = [], False
    for name in sorted(info.name2fixturedefs):
        defs = info.name2fixturedefs[name]
        if not defs:
            continue
        fixturedef = defs[-1]
        if not fixturedef.baseid or fixturedef.scope not in SHARED_SCOPES:
            continue
        if fixturedef.scope == "module":
            module = True
        else:
            wide.append(f"{fixturedef.baseid}::{name}")
    if wide:
        return wide[0]
    if module:
        return item.nodeid.split("::", 1)[0]
    return None


@pytest.hookimpl(tryfirst=True)  # before xdist's worker hook, which appends the group names to the node ids
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue
        group = shared_fixture_group(item)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))


def pytest_addoption(parser):
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
