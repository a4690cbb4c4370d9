"""Independent pieces of work spread over the machine's cores: :func:`fork_map`, :class:`Background` and
:class:`Helper`.

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

A :class:`Helper` is a forked worker that serves method calls on one object for as long as the caller keeps it:
it keeps what it computes (an effect's cached regressors), so that the work on some of the object's parts can stay
there, beside the caller's work on the others (the searches of the effects the runs cannot identify, fitted for the
record and as look-alikes, while the caller fits the others). It holds one of the cores while calls sent to it are
not yet collected.

BLAS threads: the work is spread over processes, one per core, so a multithreaded BLAS (numpy's OpenBLAS starts a
thread per core) would only oversubscribe the cores: a threaded dot product of a long series, waiting on a thread
the other processes hold off its core, costs a thousand times its arithmetic on a loaded machine. So every worker
forked here runs its BLAS on one thread, and so does the caller while a :class:`Background` job or a
:class:`Helper` call holds a core beside it (its BLAS threads are restored when none does). A whole computation
spread this way (a diagnosis) runs in :func:`one_blas_thread`, so that its BLAS does not depend on the number of
workers: OpenBLAS splits a long dot product (from 2e4 terms) over its threads, which sums it in another order (the
last bits) and, on a machine whose cores are busy, costs a thousand times its arithmetic (measured: 1.3 s of CPU
for the 200 lags of one integrated autocorrelation time of 3e4 samples on two threads, 5 ms on one).

Killed runs: every worker ignores SIGINT (a Ctrl-C reaches the whole process group; the caller decides), dies
at SIGTERM without cleanup, and dies with its parent (:func:`worker_signals`, installed in every worker forked
here; :func:`die_with_parent`: a caller killed by SIGKILL leaves no orphan); the caller stops them all with
:func:`stop_workers` (``udrobot-ctrl`` does so at SIGINT and SIGTERM, see :mod:`udrobot_ctrl.cli.main`).
"""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import process as _cf_process
from contextlib import contextmanager

from threadpoolctl import ThreadpoolController

JOBS_ENV = "UDROBOT_JOBS"

_task = None  # (func, items) of the running fork_map, inherited by its workers
_in_worker = False
_background = {}  # id -> func of the Background jobs being started (inherited by their worker)
_running = 0  # Background jobs computing and Helpers with calls not collected: each takes a core fork_map would use
_blas_before = None  # the caller's BLAS threads (blas_threads()) while _running > 0, restored when it returns to 0


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
    jobs = _jobs(jobs) - _running
    return jobs if jobs > 1 and _may_fork() else 1


def shares(n: int, parts: int) -> list:
    """range(n) cut into at most ``parts`` contiguous, non-empty shares of near-equal size."""
    parts = max(1, min(parts, n))
    cuts = [round(i * n / parts) for i in range(parts + 1)]
    return [tuple(range(a, b)) for a, b in zip(cuts, cuts[1:]) if b > a]


def _jobs(jobs: int | None) -> int:
    return default_jobs() if jobs is None else int(jobs)


def _may_fork() -> bool:
    """Whether a worker may be forked from here (not inside a worker or a running fork_map; :func:`can_fork`)."""
    return not _in_worker and _task is None and can_fork()


def in_worker() -> bool:
    """True inside a worker process of :func:`fork_map`, :class:`Background` or :class:`Helper`."""
    return _in_worker


def _mark_worker() -> None:
    global _in_worker
    _in_worker = True
    worker_signals()
    blas_threads(1)  # one core per worker (module docstring)


def blas_threads(n=None) -> dict:
    """Set the threads of every BLAS library loaded in this process (numpy's and scipy's own copies, found by
    threadpoolctl) to ``n`` (an int for all, or a dict as returned here, per library file) and return their previous
    counts ({} when none is found: nothing is changed). The thread count changes how fast BLAS runs, not what it
    computes, except for the order of a long dot product's sum (:func:`one_blas_thread`)."""
    before = {}
    for lib in ThreadpoolController().select(user_api="blas").lib_controllers:
        before[lib.filepath] = int(lib.num_threads)
        want = n.get(lib.filepath) if isinstance(n, dict) else n
        if want is not None and want != before[lib.filepath]:
            lib.set_num_threads(int(want))
    return before


@contextmanager
def one_blas_thread():
    """Run the body with every BLAS library on one thread (:func:`blas_threads`), restoring their threads after:
    the work is spread over processes (module docstring), and the body computes what it would in a worker."""
    before = blas_threads(1)
    try:
        yield
    finally:
        blas_threads(before)


def _take_core() -> None:
    """A Background job or a Helper call now holds a core beside the caller: one BLAS thread here meanwhile."""
    global _running, _blas_before
    _running += 1
    if _running == 1 and not _in_worker:
        _blas_before = blas_threads(1)


def _give_core() -> None:
    """The core taken by :func:`_take_core` is given back (the caller's BLAS threads restored with the last)."""
    global _running, _blas_before
    _running -= 1
    if _running == 0 and _blas_before is not None:
        blas_threads(_blas_before)
        _blas_before = None


_forker = {"pid": os.getpid()}  # the process that forked this one, recorded just before each fork


def _record_forker() -> None:
    _forker["pid"] = os.getpid()


os.register_at_fork(before=_record_forker)

#: prctl option "signal me when my parent dies" (linux/prctl.h PR_SET_PDEATHSIG)
PR_SET_PDEATHSIG = 1
#: how often a worker without prctl checks that its parent is alive, s (assumed: a second keeps an orphan's
#: life short at no measurable cost)
PARENT_POLL_S = 1.0


def die_with_parent() -> None:
    """In a worker process: end when the process that forked it ends, even by SIGKILL (which no handler sees, so
    the parent cannot stop its workers itself; its workers would otherwise wait for tasks for ever).

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` through ``ctypes`` (the kernel kills the worker when the thread
    that forked it ends), then a check that the parent did not die before the call. Elsewhere, or if prctl
    fails: a daemon thread that polls ``os.getppid()`` every :data:`PARENT_POLL_S` s and ends the worker when it
    changes. The pools here fork their workers from the caller's thread (``ProcessPoolExecutor`` re-forks from its
    manager thread only with ``max_tasks_per_child``, which no pool here uses), so a worker lives as long as the
    caller.
    """
    parent = _forker["pid"]
    armed = False
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent is already gone (we were re-parented)
        os._exit(1)
    if not armed:
        def watch():
            while os.getppid() == parent:
                time.sleep(PARENT_POLL_S)
            os._exit(1)

        threading.Thread(target=watch, name="udrobot-parent-watch", daemon=True).start()


def worker_signals() -> None:
    """In a worker process: ignore SIGINT (a Ctrl-C at the terminal reaches every process of the group; the caller
    stops its workers, and a worker's KeyboardInterrupt would only print a traceback), die at SIGTERM (the
    default action, whatever handler the caller had installed before forking), and die with the parent
    (:func:`die_with_parent`: a caller killed by SIGKILL leaves no worker behind).

    Used as the initializer of every pool forked here and of the sensitivity executor's local pool.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent()


def stop_workers(timeout: float = 2.0) -> int:
    """Stop every worker process this process started (:mod:`multiprocessing` children: the pools and helpers of
    this module, the sensitivity executor's pool): SIGTERM, then SIGKILL for those still alive after ``timeout``
    seconds; each is reaped, so none is left behind.

    Parameters
    ----------
    timeout : float
        Seconds to wait for the workers to end after SIGTERM.

    Returns
    -------
    int
        The number of workers that were still running.
    """
    children = multiprocessing.active_children()
    for child in children:
        try:
            child.terminate()
        except (OSError, AttributeError, ValueError):  # already reaped, or closed
            pass
    deadline = time.monotonic() + timeout
    for child in children:
        try:
            child.join(max(0.0, deadline - time.monotonic()))
            if child.is_alive():
                child.kill()
                child.join(1.0)
        except (OSError, AttributeError, ValueError):
            pass
    _join_pool_managers(max(0.0, deadline - time.monotonic()) + 1.0)
    return len(children)


def _join_pool_managers(timeout: float) -> None:
    """Wait (up to ``timeout`` s in all) for the manager threads of process pools whose workers were stopped: each
    sees its pool broken and closes its wake-up pipe. Python 3.11's exit handler (``concurrent.futures.process.
    _python_exit``) writes to every pool's pipe that is not closed yet; a manager closing it at that moment made the
    interpreter print a traceback (``OSError: [Errno 9] Bad file descriptor``) after a command stopped by SIGTERM."""
    deadline = time.monotonic() + timeout
    for thread in list(getattr(_cf_process, "_threads_wakeups", {})):
        if thread is not threading.current_thread():
            thread.join(max(0.0, deadline - time.monotonic()))


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
        _take_core()

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
        if self._future is not None:
            _give_core()
            self._future = None
            self._pool.shutdown(wait=wait, cancel_futures=True)

    def __del__(self):  # a job whose result is never taken gives its core back
        self._release(wait=False)


def _serve(obj, conn) -> None:
    """A :class:`Helper`'s worker: ``(method, args)`` received -> ``(True, value)`` or ``(False, exception)`` sent
    back, in order, until ``None`` or the caller's end closes."""
    _mark_worker()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        method, args = msg
        try:
            out = (True, getattr(obj, method)(*args))
        except Exception as exc:  # noqa: BLE001 - raised in the caller
            out = (False, exc)
        try:
            conn.send(out)
        except OSError:  # the caller closed its end
            return
        except Exception as exc:  # noqa: BLE001 - a value or an exception that does not pickle
            conn.send((False, RuntimeError(f"helper: the result of {method} could not be sent back: {exc!r}")))


class Helper:
    """A forked worker serving method calls on ``obj``: :meth:`submit` sends ``getattr(obj, method)(*args)`` to it
    and returns at once, :meth:`result` waits for that call's value (or raises its exception, in the caller).

    The worker inherits ``obj`` as it is when the helper starts and keeps what it computes since (its caches); the
    caller's ``obj`` is not touched, so calls must not depend on changes the caller makes later. Calls are computed
    one at a time in the order submitted; their arguments and values must pickle. The worker holds one of the cores
    while calls sent to it are not yet collected (:func:`fork_map` meanwhile uses one worker fewer), and stops at
    :meth:`close` (or when the helper is dropped).

    Where :func:`fork_map` could not fork (one job, no fork, inside a worker) -- whatever :class:`Background` jobs
    run -- each call is computed in the caller when its result is asked for: the same values.

    Parameters
    ----------
    obj : object
        The object whose methods are called.
    jobs : int, optional
        As :func:`fork_map`'s: the worker is forked only when at least two are allowed.
    """

    def __init__(self, obj, jobs: int | None = None):
        self._obj, self._conn, self._proc, self._pid = obj, None, None, os.getpid()
        self._sent, self._got, self._replies, self._calls = 0, 0, {}, {}  # calls: token -> (method, args)
        if _jobs(jobs) > 1 and _may_fork():
            ctx = multiprocessing.get_context("fork")
            ours, theirs = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, args=(obj, theirs), daemon=True)  # _serve: worker_signals
            self._proc.start()
            theirs.close()
            self._conn = ours

    @property
    def forked(self) -> bool:
        """Whether the calls run in a worker (else in the caller, when their results are asked for)."""
        return self._conn is not None

    def submit(self, method: str, *args) -> int:
        """Send ``getattr(obj, method)(*args)`` to the worker; returns the call's token for :meth:`result`."""
        token = self._sent
        self._sent += 1
        self._calls[token] = (method, args)
        if self._conn is not None:
            if self._sent - self._got == 1:  # the first call not collected: the worker now holds a core
                _take_core()
            self._conn.send((method, args))
        return token

    def result(self, token: int):
        """The value of the call ``token`` (waits for the worker; the replies before it are kept). A call the worker
        did not answer (closed, or its process ended) is computed in the caller."""
        while self._conn is not None and token in self._calls and token not in self._replies:
            try:
                reply = self._conn.recv()
            except (EOFError, OSError):
                self.close()  # the worker died: what it did not answer is computed here
                break
            self._replies[self._got] = reply
            self._got += 1
            if self._got == self._sent:
                _give_core()
        if token not in self._calls:
            raise KeyError(f"helper: no call {token} pending")
        method, args = self._calls.pop(token)
        if token not in self._replies:
            return getattr(self._obj, method)(*args)
        ok, value = self._replies.pop(token)
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop the worker and give its core back; calls it has not answered are computed in the caller if their
        results are asked for."""
        if self._conn is None or os.getpid() != self._pid:  # a forked child never stops its parent's helper
            return
        busy = self._got < self._sent
        if busy:
            _give_core()
        conn, self._conn = self._conn, None
        if busy:  # calls still running: not waited for
            self._proc.terminate()
        else:
            try:
                conn.send(None)
            except OSError:
                self._proc.terminate()
        conn.close()
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()

    def __del__(self):
        self.close()
