"""fork_map: the serial loop's results, in order, from forked workers; Background: one job beside the caller."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from udrobot_ctrl.parallel import (
    JOBS_ENV,
    Background,
    Helper,
    blas_threads,
    can_fork,
    default_jobs,
    fork_map,
    one_blas_thread,
    workers,
)


def test_results_in_order_from_a_closure_over_large_data():
    data = np.arange(200_000.0)  # inherited by the workers, not sent to them
    items = list(range(7))
    out = fork_map(lambda k: (os.getpid(), float(data[k::7].sum())), items, jobs=2)
    assert [v for _, v in out] == [float(data[k::7].sum()) for k in items]
    if can_fork():  # else (no fork, or numba's OpenMP layer ran in this process) the loop ran here
        assert os.getpid() not in {pid for pid, _ in out}


def test_a_worker_error_is_raised_in_the_caller():
    def fail_on_three(k):
        if k == 3:
            raise ValueError("three")
        return k
    with pytest.raises(ValueError, match="three"):
        fork_map(fail_on_three, range(5), jobs=2)


WORKERS_CHECK = """
import os
from udrobot_ctrl.parallel import can_fork, fork_map
assert can_fork()
seen = []

def work(k):
    seen.append(k)  # lands in this process only when computed here
    inner = fork_map(lambda j: (os.getpid(), j * k), range(3), jobs=2)
    return os.getpid(), [v for _, v in inner], {pid for pid, _ in inner}

out = fork_map(work, [1, 2, 3], jobs=2, warm=True)
assert seen == [1], seen
assert out[0][0] == os.getpid() and all(pid != os.getpid() for pid, _, _ in out[1:]), out
assert [v for _, v, _ in out] == [[0, k, 2 * k] for k in (1, 2, 3)], out
assert all(pids == {pid} for pid, _, pids in out[1:]), out  # nested: ran in that worker
print("ok")
"""


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform: everything runs in the caller")
def test_warm_runs_the_first_item_here_and_nesting_stays_in_the_worker():
    """In a fresh interpreter (this one may have run numba's OpenMP layer, after which nothing is forked): the first
    item is computed in the caller, the others in forked workers, and a fork_map inside a worker stays there."""
    env = {**os.environ, JOBS_ENV: "2"}
    done = subprocess.run([sys.executable, "-c", WORKERS_CHECK], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_jobs_from_the_environment(monkeypatch):
    monkeypatch.setenv(JOBS_ENV, "1")
    assert default_jobs() == 1 and workers() == 1
    assert workers(2) == (2 if can_fork() else 1)
    assert fork_map(lambda k: os.getpid(), range(3)) == [os.getpid()] * 3  # one job: in this process
    monkeypatch.setenv(JOBS_ENV, "two")
    with pytest.raises(ValueError, match=JOBS_ENV):
        default_jobs()


BACKGROUND_CHECK = """
import os, select
from udrobot_ctrl.parallel import Background, fork_map, workers
data = list(range(100_000))
assert workers() == 2
started_r, started_w = os.pipe()  # the job says it runs; the caller lets it finish (no timer: events on pipes)
go_r, go_w = os.pipe()

def body():
    os.write(started_w, b"s")
    os.read(go_r, 1)  # held until the caller has done its own work
    return os.getpid(), sum(data), workers()
job = Background(body)
assert workers() == 1  # the job holds one of the two cores: fork_map runs here meanwhile
assert fork_map(lambda k: os.getpid(), range(3)) == [os.getpid()] * 3
# the job runs beside the caller: it started before its result is asked for (computed in the caller, it never would)
assert select.select([started_r], [], [], 60.0)[0], "the job did not start beside the caller"
os.write(go_w, b"g")
pid, total, inner = job.result()
assert pid != os.getpid() and total == sum(data) and inner == 1  # computed in a worker, which forks nothing
assert workers() == 2 and job.result()[1] == total  # its core back; the result kept

def fail():
    raise KeyError("lost")
bad = Background(fail)
for _ in range(2):
    try:
        bad.result()
    except KeyError as exc:
        assert "lost" in str(exc)
    else:
        raise AssertionError("no error")
assert workers() == 2
hold_r, hold_w = os.pipe()
Background(lambda: os.read(hold_r, 1))  # never asked, still running: its core comes back when it is dropped
assert workers() == 2
os.write(hold_w, b"x")  # let it end, so that the interpreter's exit does not wait on it
print("ok")
"""


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform: everything runs in the caller")
def test_a_background_job_runs_beside_the_caller_and_holds_one_core():
    """In a fresh interpreter with two jobs: the job (computed in a forked worker, over data it inherits) starts
    before the caller asks for its result and waits for the caller's go (events on pipes, no timer), fork_map stays
    in the caller meanwhile, a worker's error is raised at every result(), and a job never asked for gives its core
    back."""
    env = {**os.environ, JOBS_ENV: "2"}
    done = subprocess.run([sys.executable, "-c", BACKGROUND_CHECK], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_a_background_job_without_workers_is_computed_when_asked(monkeypatch):
    monkeypatch.setenv(JOBS_ENV, "1")
    calls = []
    job = Background(lambda: calls.append(os.getpid()) or 42)
    assert calls == []  # nothing yet: computed here, when asked
    assert job.result() == 42 and job.result() == 42 and calls == [os.getpid()]


HELPER_CHECK = """
import os, select, signal
from udrobot_ctrl.parallel import Helper, fork_map, workers

class Counter:
    def __init__(self):
        self.seen = []  # what this copy has computed: the worker keeps its own
        self.data = list(range(100_000))

    def work(self, k, started=None, hold=None):
        if started is not None:
            os.write(started, b"s")  # running (no timer: events on pipes)
        if hold is not None:
            os.read(hold, 1)  # held until the caller writes to the pipe (never, for a call stopped at close)
        self.seen.append(k)
        return os.getpid(), k, sum(self.data), list(self.seen), workers()

    def fail(self):
        raise KeyError("lost")

obj = Counter()
started_r, started_w = os.pipe()  # before the helper forks: its worker inherits them
go_r, go_w = os.pipe()
held_r, held_w = os.pipe()
helper = Helper(obj)
assert helper.forked and workers() == 2  # idle: it holds no core
a = helper.submit("work", 1, started_w, go_r)
assert workers() == 1  # a call not collected: the worker holds one of the two cores
b = helper.submit("work", 2)
# the call runs beside the caller: it started before its result is asked for
assert select.select([started_r], [], [], 60.0)[0], "the helper's call did not start beside the caller"
os.read(started_r, 1)
os.write(go_w, b"g")
pid_b, k_b, total, seen_b, inner = helper.result(b)  # out of order: a's reply is kept
pid_a, k_a, _, seen_a, _ = helper.result(a)
assert pid_a == pid_b != os.getpid() and (k_a, k_b) == (1, 2) and total == sum(obj.data) and inner == 1
assert seen_a == [1] and seen_b == [1, 2] and obj.seen == []  # one worker keeps its state; the caller's untouched
assert workers() == 2  # every call collected: its core back
try:
    helper.result(helper.submit("fail"))
except KeyError as exc:
    assert "lost" in str(exc)
else:
    raise AssertionError("no error")
assert helper.result(helper.submit("work", 3))[3] == [1, 2, 3]  # the worker goes on after an error
d = helper.submit("work", 4, started_w, held_r)  # a call the worker holds until the pipe is written (never, there)
assert select.select([started_r], [], [], 60.0)[0], "the helper's last call did not start"
os.read(started_r, 1)
proc = helper._proc
helper.close()  # a call still running: the worker is stopped, not waited for; the call computed here when asked
# stopped at once by SIGTERM: waited for, it would have been killed (SIGKILL) at the end of close's join timeout
assert proc.exitcode == -signal.SIGTERM, proc.exitcode
assert workers() == 2 and not helper.forked
os.write(held_w, b"x")  # computed here, it finds the pipe written
pid_d, _, _, seen_d, _ = helper.result(d)
assert pid_d == os.getpid() and seen_d == [4]
print("ok")
"""


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform: everything runs in the caller")
def test_a_helper_serves_calls_beside_the_caller_and_keeps_its_state():
    """In a fresh interpreter with two jobs: calls sent to the helper run in one forked worker that keeps what it
    computed, while the caller works (a call starts before its result is asked for: events on pipes, no timer);
    replies come back by token in any order; the worker holds a core only while
    calls are not collected; an error is raised in the caller and the worker goes on; a call still running at close
    is computed in the caller."""
    env = {**os.environ, JOBS_ENV: "2"}
    done = subprocess.run([sys.executable, "-c", HELPER_CHECK], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_a_helper_without_workers_computes_in_the_caller(monkeypatch):
    monkeypatch.setenv(JOBS_ENV, "1")
    calls = []

    class Obj:
        def f(self, x):
            calls.append(os.getpid())
            return 2 * x
    helper = Helper(Obj())
    assert not helper.forked
    t = helper.submit("f", 21)
    assert calls == []  # computed when asked
    assert helper.result(t) == 42 and calls == [os.getpid()]
    with pytest.raises(KeyError):
        helper.result(t)  # collected once


def _blas_counts(_):
    return sorted(set(blas_threads().values()))


@pytest.mark.skipif(not can_fork(), reason="needs fork")
def test_workers_run_blas_on_one_thread_and_the_caller_gets_its_threads_back(monkeypatch):
    """A threaded BLAS in each of one-per-core workers only oversubscribes the cores (parallel.py docstring)."""
    monkeypatch.setenv(JOBS_ENV, "2")
    np.linalg.svd(np.ones((4, 4)))  # BLAS loaded
    before = blas_threads()
    if not before:
        pytest.skip("no BLAS library threadpoolctl can control")
    if not can_fork():  # checked again now: a threaded numba kernel run earlier in this process forbids forking
        pytest.skip("a threaded (OpenMP) numba kernel ran in this process: fork_map runs in the caller")
    assert fork_map(_blas_counts, [0, 1]) == [[1], [1]]
    job = Background(lambda: sorted(set(blas_threads().values())))
    assert job.result() == [1]
    assert blas_threads() == before  # restored once the job's core is given back
    previous = blas_threads(1)
    assert previous == before and set(blas_threads(previous).values()) == {1}
    assert blas_threads() == before


def test_one_blas_thread_holds_every_blas_on_one_thread_and_restores_them_even_on_error():
    """A diagnosis runs in one_blas_thread: its BLAS does not depend on the number of workers (module docstring)."""
    np.linalg.svd(np.ones((4, 4)))  # BLAS loaded
    before = blas_threads()
    if not before:
        pytest.skip("no BLAS library threadpoolctl can control")
    with one_blas_thread():
        assert set(blas_threads().values()) == {1}
        job = Background(lambda: sorted(set(blas_threads().values())))  # a core taken and given back inside
        assert job.result() == [1] and set(blas_threads().values()) == {1}
    assert blas_threads() == before
    with pytest.raises(RuntimeError), one_blas_thread():
        raise RuntimeError("the body failed")
    assert blas_threads() == before
