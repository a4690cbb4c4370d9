"""Killed runs (issue 40, item 5): SIGTERM or Ctrl-C during ``diagnose`` or ``sensitivity`` stops the forked workers,
removes the command's temporary files and exits with 143 / 130 after one line, no traceback.

Each case launches the CLI in a subprocess (its own session, as a terminal's foreground job is its own group) on a
small synthetic case, waits until its worker processes exist, sends the signal (SIGINT to the whole group, as a
Ctrl-C at a terminal does) and checks: the command ends within a few seconds, none of its workers is left, no
temporary file stays, stderr has the one-line message and no traceback.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.io.runlog import write_run
from udrobot_ctrl.vehicle import load_model

# subprocesses that import the package and are signalled mid-run: seconds each, so out of the fast lane
pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc to find the workers"),
              pytest.mark.slow]

RATE = 20.0  # Hz


def _children(pid: int) -> list:
    """The processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat_line = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat_line.rsplit(")", 1)[1].split()
        if int(fields[1]) == pid:
            out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two 40 s open-loop thrust sweeps of UDrobot (no noise): a fit run and a holdout run."""
    d = tmp_path_factory.mktemp("signals")
    model = load_model("pendulum:chin")
    paths = []
    for k in (1, 2):
        t = np.arange(0.0, 40.0, 1.0 / RATE)
        s = np.sin(2 * np.pi * t / (9.0 + k))
        c = 6 * np.cos(2 * np.pi * t / 7.0)
        f = np.column_stack([20 * s + 10, 20 * s + 8, c, c])
        x0 = np.zeros(12)
        x0[2] = 1.0
        res = simulate(model, x0, t[-1] + 1.0 / RATE, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
        xs = res.x[::5][: t.size]
        paths.append(write_run(d / f"run{k}.csv", t, {n: xs[:, i] for i, n in enumerate(STATE_NAMES)}, "thrust", f))
    return paths


def _default_signals():
    """In the child before exec: SIGINT and SIGTERM at their defaults, as under a terminal. A shell without job
    control starts background jobs with SIGINT ignored, and a command started so keeps ignoring it (as it should)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _interrupt(argv, signum, cwd, group=False, wait_for_workers=True, ready=None, delay=0.5):
    """Start ``udrobot-ctrl argv``, send ``signum`` once its workers run (or ``ready`` is printed); return
    (exit status, seconds to exit, stderr, workers seen, workers still alive)."""
    env = {**os.environ, "UDROBOT_JOBS": "2", "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "udrobot_ctrl.cli", *argv], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=_default_signals)
    try:
        t0 = time.monotonic()
        seen = []
        if ready is not None:
            line = ""
            while ready not in line and time.monotonic() - t0 < 120:
                line = proc.stdout.readline()
                assert line or proc.poll() is None, proc.stderr.read()
        while wait_for_workers and not seen and time.monotonic() - t0 < 120:
            assert proc.poll() is None, f"ended before its workers started: {proc.stderr.read()}"
            seen = _children(proc.pid)
            time.sleep(0.05)
        assert seen or not wait_for_workers, "no worker started within 120 s"
        time.sleep(delay)  # the workers are at work (or being forked, at delay 0)
        seen = sorted(set(seen) | set(_children(proc.pid)))
        if group:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        t1 = time.monotonic()
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - t1
        time.sleep(0.2)
        return proc.returncode, took, err, seen, [p for p in seen if _alive(p)]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()


#: a command stops within this many seconds of the signal on an idle machine: its workers finish the numpy or
#: compiled call they are in (a signal is handled between bytecodes) and the pools shut down
STOP_S = 10.0


def stop_limit() -> float:
    """``STOP_S`` stretched by the machine's load (1-minute load average per core, at least 1): the calls the
    workers finish take that much longer when more processes than cores share the machine (the suite's own workers
    beside the command's)."""
    return STOP_S * max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))


def _complete_json(path) -> bool:
    """Whether ``path`` holds a whole JSON document (a report written to its end)."""
    try:
        json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return True


def _check(status, took, err, left, signum, command):
    assert status == 128 + signum, err
    limit = stop_limit()
    assert took < limit, f"took {took:.1f} s to stop (limit {limit:.1f} s at this load)"
    assert not left, f"workers left running: {left}"
    assert "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"udrobot-ctrl {command}: interrupted by {signal.Signals(signum).name}"), err


@pytest.mark.parametrize("signum, group", [(signal.SIGTERM, False), (signal.SIGINT, True)],
                         ids=["sigterm", "ctrl-c"])
def test_diagnose_stops_its_workers_and_exits(runs, tmp_path, signum, group):
    argv = ["diagnose", "--model", "pendulum:chin", "--json", str(tmp_path / "r.json"), str(runs[0]),
            "--holdout", str(runs[1])]
    status, took, err, seen, left = _interrupt(argv, signum, tmp_path, group=group)
    assert seen
    _check(status, took, err, left, signum, "diagnose")
    assert not (tmp_path / "r.json").exists()
    assert [p.name for p in tmp_path.iterdir()] == [], "temporary or partial files left"


@pytest.mark.parametrize("delay", [0.0, 0.2, 1.0, 2.5])
def test_diagnose_stops_whenever_the_signal_comes(runs, tmp_path, delay):
    """At any moment of the run: while workers are being forked (the signal may land in an at-fork callback, where
    Python drops the exception the handler raises), computing, or between two pools."""
    argv = ["diagnose", "--model", "pendulum:chin", "--json", str(tmp_path / "r.json"), str(runs[0]),
            "--holdout", str(runs[1])]
    status, took, err, seen, left = _interrupt(argv, signal.SIGTERM, tmp_path, delay=delay)
    if status == 0:  # finished before the signal came: nothing to check
        return
    if status == -signal.SIGTERM and _complete_json(tmp_path / "r.json"):
        return  # finished its work and wrote its report; the signal came while the interpreter was exiting
    _check(status, took, err, left, signal.SIGTERM, "diagnose")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("signum, group", [(signal.SIGTERM, False), (signal.SIGINT, True)],
                         ids=["sigterm", "ctrl-c"])
def test_sensitivity_stops_its_workers_and_exits(tmp_path, signum, group):
    out = tmp_path / "study"
    argv = ["sensitivity", "--model", "pendulum:chin", "--method", "sobol", "--samples", "64", "--workers", "2",
            "--params", "surge.KQ,heave.KQ", "--out", str(out), "--quiet"]
    status, took, err, seen, left = _interrupt(argv, signum, tmp_path, group=group)
    assert seen
    _check(status, took, err, left, signum, "sensitivity")
    assert not list(out.rglob("*.tmp")), "temporary files left"
    assert not (out / "results.csv").exists()


def _gone_within(pids, limit) -> list:
    """The processes of ``pids`` still alive after ``limit`` s (polled)."""
    t0 = time.monotonic()
    left = [p for p in pids if _alive(p)]
    while left and time.monotonic() - t0 < limit:
        time.sleep(0.1)
        left = [p for p in left if _alive(p)]
    return left


@pytest.mark.parametrize("command", ["sensitivity", "diagnose"])
def test_sigkill_of_the_command_leaves_no_worker(runs, tmp_path, command):
    """SIGKILL reaches no handler: the workers notice their parent's death themselves (parallel.die_with_parent)
    and end within seconds instead of waiting for tasks for ever (issue 62)."""
    if command == "sensitivity":
        argv = ["sensitivity", "--model", "pendulum:chin", "--method", "sobol", "--samples", "64", "--workers", "2",
                "--params", "surge.KQ,heave.KQ", "--out", str(tmp_path / "study"), "--quiet"]
    else:
        argv = ["diagnose", "--model", "pendulum:chin", "--json", str(tmp_path / "r.json"), str(runs[0]),
                "--holdout", str(runs[1])]
    status, took, err, seen, left = _interrupt(argv, signal.SIGKILL, tmp_path)
    assert seen and status == -signal.SIGKILL, err
    survivors = _gone_within(seen, stop_limit())
    assert not survivors, f"workers left running after the SIGKILL of {command}: {survivors}"


SLOW_WRITER = """
import sys, time
import udrobot_ctrl.cli.model as model_cli
from udrobot_ctrl.cli.main import main
from udrobot_files.output import open_atomic

def slow_write(model, path, **kwargs):  # the model file written slowly: the signal comes mid-write
    with open_atomic(path, "w") as fh:
        fh.write("{")
        fh.flush()
        print("writing", flush=True)
        time.sleep(60)

model_cli.write_model_file = slow_write
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_write_leaves_no_temporary_file(tmp_path, signum):
    """The hidden temporary file of an atomic write in progress is removed, and no output appears."""
    script = tmp_path / "slow.py"
    script.write_text(SLOW_WRITER)
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, str(script), "model", "export", "--model", "pendulum:chin", "--out",
                             str(out / "m.json")], cwd=tmp_path, env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True, preexec_fn=_default_signals)
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        assert len(list(out.iterdir())) == 1  # the hidden temporary file
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err, err
    assert "interrupted by" in err.strip().splitlines()[-1]
    assert list(out.iterdir()) == []


def test_workers_ignore_ctrl_c_and_die_at_sigterm():
    """The signal set-up of every worker forked by udrobot_ctrl.parallel and the sensitivity executor's pool."""
    code = (
        "import os, signal\n"
        "from udrobot_ctrl.parallel import fork_map\n"
        "print(fork_map(lambda k: (signal.getsignal(signal.SIGINT) is signal.SIG_IGN,\n"
        "                          signal.getsignal(signal.SIGTERM) is signal.SIG_DFL, os.getpid()), [1, 2], jobs=2))\n"
    )
    env = {**os.environ, "UDROBOT_JOBS": "2"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("(True, True,") == 2, done.stdout
