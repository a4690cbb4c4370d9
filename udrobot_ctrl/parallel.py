"""Independent pieces of work spread over the machine's cores: :func:`fork_map`.

The diagnoser's heavy steps are independent per run or per effect set (smoothing each run, replaying the holdout
with each candidate), written as closures over large prepared data. Forked worker processes inherit those closures
and data without pickling them (only the results travel back), so they run on every core with no change to the
code that computes them; the results are those of the serial loop, in order.

The number of workers is ``jobs`` when given, else the ``UDROBOT_JOBS`` environment variable, else the cores this
process may use. One worker, a platform without ``fork`` (Windows), a call from inside a worker (no nesting), or a
process that has run numba's OpenMP threading layer (a forked child using it again aborts) runs the loop in the
calling process.
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

JOBS_ENV = "UDROBOT_JOBS"

_task = None  # (func, items) of the running fork_map, inherited by its workers
_in_worker = False


def default_jobs() -> int:
    """Workers :func:`fork_map` uses without ``jobs``: ``$UDROBOT_JOBS`` or the cores this process may use.

    Raises
    ------
    ValueError
        If ``$UDROBOT_JOBS`` is not a positive integer.
    """
    env = os.environ.get(JOBS_ENV, "").strip()
    if env:
        if not env.isdigit() or int(env) < 1:
            raise ValueError(f"{JOBS_ENV}={env!r}: expected a positive integer number of worker processes")
        return int(env)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def can_fork() -> bool:
    """Whether :func:`fork_map` may fork workers here: the platform has ``fork`` and numba's OpenMP threading layer
    has not run in this process (a threaded batch simulation: OpenMP aborts a forked child that uses it again)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return False
    try:
        import numba
        return numba.threading_layer() != "omp"
    except ValueError:  # no threaded kernel has run yet
        return True


def workers(jobs: int | None = None) -> int:
    """Worker processes :func:`fork_map` would use here for ``jobs`` (default :func:`default_jobs`) and enough
    items: 1 when the work stays in the calling process (one job, inside a worker, or :func:`can_fork` false)."""
    jobs = default_jobs() if jobs is None else int(jobs)
    return jobs if jobs > 1 and not _in_worker and _task is None and can_fork() else 1


def _mark_worker() -> None:
    global _in_worker
    _in_worker = True


def _run(i):
    func, items = _task
    return func(items[i])


def fork_map(func, items, jobs: int | None = None, warm: bool = False) -> list:
    """``[func(x) for x in items]``, spread over forked worker processes.

    Parameters
    ----------
    func : callable
        Any callable, closures included (the workers inherit it); its results must pickle.
    items : iterable
    jobs : int, optional
        Worker processes (default :func:`default_jobs`); at most one per item.
    warm : bool
        Compute the first item in the calling process before forking, so that what it caches (a compiled model,
        say) is inherited by the workers and kept for later calls, instead of being built in every worker and lost.

    Returns
    -------
    list
        The results in the order of ``items``; an exception in a worker is raised here.
    """
    global _task
    items = list(items)
    jobs = workers(jobs)
    if jobs <= 1 or len(items) <= 1:
        return [func(x) for x in items]
    if warm:
        return [func(items[0])] + fork_map(func, items[1:], jobs)
    n = min(jobs, len(items))
    _task = (func, items)
    try:
        with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"), initializer=_mark_worker) as ex:
            return list(ex.map(_run, range(len(items))))
    finally:
        _task = None
