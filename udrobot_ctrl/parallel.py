"""Independent pieces of work spread over the machine's cores: :func:`fork_map` and :class:`Background`.

The diagnoser's heavy steps are independent per run or per effect set (smoothing each run, replaying the holdout
with each candidate), written as closures over large prepared data. Forked worker processes inherit those closures
and data without pickling them (only the results travel back), so they run on every core with no change to the
code that computes them; the results are those of the serial loop, in order.

The number of workers is ``jobs`` when given, else the ``UDROBOT_JOBS`` environment variable, else the cores this
process may use. One worker, a platform without ``fork`` (Windows), a call from inside a worker (no nesting), or a
process that has run numba's OpenMP threading layer (a forked child using it again aborts) runs the loop in the
calling process.

A :class:`Background` job is one piece of work a forked worker computes while the caller goes on with another
(the nominal replays while the fits run); it holds one of the cores until its result is taken, so that
:func:`fork_map` meanwhile uses one worker fewer.
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

JOBS_ENV = "UDROBOT_JOBS"

_task = None  # (func, items) of the running fork_map, inherited by its workers
_in_worker = False
_background = {}  # id -> func of the Background jobs being started (inherited by their worker)
_running = 0  # Background jobs whose worker is computing: each takes one of the cores fork_map would use


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
    jobs = (default_jobs() if jobs is None else int(jobs)) - _running
    return jobs if jobs > 1 and not _in_worker and _task is None and can_fork() else 1


def _mark_worker() -> None:
    global _in_worker
    _in_worker = True


def _forked_pool(n: int) -> ProcessPoolExecutor:
    """A pool of ``n`` forked workers that know they are workers (no nesting). A fork context's pool forks its
    workers at the first submit: they inherit the caller's state of that moment (the task registered for them)."""
    return ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"), initializer=_mark_worker)


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
        with _forked_pool(n) as ex:
            return list(ex.map(_run, range(len(items))))
    finally:
        _task = None


def _run_background(key):
    return _background[key]()


class Background:
    """``func()`` computed in a forked worker while the caller goes on; :meth:`result` returns it (or raises its
    exception). Where :func:`fork_map` would run serially (one job, no fork, inside a worker) it is computed in the
    caller when the result is first asked for: the same value either way.

    Parameters
    ----------
    func : callable
        No arguments; closures included (the worker inherits it); its result must pickle.
    jobs : int, optional
        As :func:`fork_map`'s: a worker is forked only when at least two would be used.
    """

    def __init__(self, func, jobs: int | None = None):
        global _running
        self._func, self._pool, self._future, self._outcome = func, None, None, None
        if workers(jobs) <= 1:
            return
        key = id(self)
        _background[key] = func
        try:  # the worker is forked at this submit: it inherits func
            self._pool = _forked_pool(1)
            self._future = self._pool.submit(_run_background, key)
        finally:
            _background.pop(key, None)
        self._func = None
        _running += 1

    def result(self):
        """The value of ``func()`` (waits for the worker); an exception in it is raised here, every time."""
        if self._future is not None:
            try:
                self._outcome = (True, self._future.result())
            except Exception as exc:  # noqa: BLE001 - raised below, and again on a second call
                self._outcome = (False, exc)
            finally:
                self._release(wait=True)
        elif self._outcome is None:
            try:
                self._outcome = (True, self._func())
            except Exception as exc:  # noqa: BLE001 - raised below, and again on a second call
                self._outcome = (False, exc)
            self._func = None
        ok, value = self._outcome
        if not ok:
            raise value
        return value

    def _release(self, wait: bool) -> None:
        global _running
        if self._future is not None:
            _running -= 1
            self._future = None
            self._pool.shutdown(wait=wait, cancel_futures=True)

    def __del__(self):  # a job whose result is never taken gives its core back
        self._release(wait=False)
