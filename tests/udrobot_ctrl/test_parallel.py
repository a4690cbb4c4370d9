"""fork_map: the serial loop's results, in order, from forked workers; Background: one job beside the caller."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from udrobot_ctrl.parallel import JOBS_ENV, Background, can_fork, default_jobs, fork_map, workers


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
import os, time
from udrobot_ctrl.parallel import Background, fork_map, workers
data = list(range(100_000))
assert workers() == 2
t0 = time.perf_counter()
job = Background(lambda: (os.getpid(), sum(data), workers(), time.sleep(1.0)))
assert workers() == 1  # the job holds one of the two cores: fork_map runs here meanwhile
assert fork_map(lambda k: os.getpid(), range(3)) == [os.getpid()] * 3
time.sleep(1.0)  # the caller's own work, while the job runs
pid, total, inner, _ = job.result()
assert time.perf_counter() - t0 < 1.9, time.perf_counter() - t0  # the two seconds overlapped
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
Background(lambda: time.sleep(5.0))  # never asked: its core comes back when it is dropped
assert workers() == 2
print("ok")
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform: everything runs in the caller")
def test_a_background_job_runs_beside_the_caller_and_holds_one_core():
    """In a fresh interpreter with two jobs: the job's result (computed in a forked worker, over data it inherits)
    arrives while the caller did its own second of work, fork_map stays in the caller meanwhile, a worker's error is
    raised at every result(), and a job never asked for gives its core back."""
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
