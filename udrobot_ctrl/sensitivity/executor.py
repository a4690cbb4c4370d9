"""One executor interface for every sweep: in-process, local processes, or a dask.distributed cluster.

:class:`SweepExecutor` wraps

* ``workers=1`` -> in-process serial execution (no process start-up; used by small studies and tests);
* ``workers=N`` (default: the CPU count) -> :class:`concurrent.futures.ProcessPoolExecutor` (the platform's
  default start method: fork on Linux, so workers inherit the parent's caches and a script needs no
  ``__main__`` guard). The evaluators run numba's *serial* kernel, so they start no OpenMP threads; a parent
  that already ran the threaded kernel (:func:`udrobot_ctrl.dynamics.sim.simulate` of >= 16 vehicles) must
  not fork (OpenMP aborts the child): pass ``executor=ProcessPoolExecutor(mp_context=get_context("forkserver"))``;
* ``scheduler="tcp://host:8786"`` or ``client=distributed.Client(...)`` -> dask.distributed; ``submit``
  returns dask futures and completion uses ``distributed.as_completed``;
* ``executor=`` any :class:`concurrent.futures.Executor` you already have.

:func:`run_sweep` evaluates a sample matrix in chunks through such an executor, writes every finished
chunk to a :class:`~udrobot_ctrl.sensitivity.results.ResultStore` as it completes (so an interruption
loses only the chunks in flight) and shows a tqdm bar when the sweep lasts more than ~2 s on a TTY.

An *evaluator* is any picklable callable ``evaluator(X) -> dict`` mapping metric names to ``(n,)``
arrays for the ``(n, d)`` samples ``X``, with an optional ``"error"`` entry (list of str, empty when the
sample succeeded). It runs in the worker; keep it small (specs, not designed controllers).
"""
from __future__ import annotations

import concurrent.futures as cf
import math
import os
import sys
import time

import numpy as np

from udrobot_ctrl.parallel import worker_signals


class _ImmediateExecutor(cf.Executor):
    """Runs each task at submit time in this process (a concurrent.futures Executor)."""

    def submit(self, fn, /, *args, **kwargs):
        fut = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future like any executor
            if isinstance(exc, KeyboardInterrupt):
                raise
            fut.set_exception(exc)
        return fut


#: dask comm protocols that encrypt the link (TLS); any other (tcp://, ws://, a bare HOST:PORT) is plain text
ENCRYPTED_PROTOCOLS = ("tls", "wss")


def scheduler_warning(address: str | None) -> str | None:
    """Why a dask scheduler address is unsafe, or None: a plain (unencrypted, unauthenticated) link.

    dask runs whatever pickled code a client sends; over ``tcp://`` (dask's default when the address has no
    ``PROTOCOL://``) anyone who reaches the port can send code to every worker and read the traffic. Only
    ``tls://`` (or ``wss://``) with certificates encrypts and authenticates the link; ``inproc://`` stays inside
    this process.

    Parameters
    ----------
    address : str or None
        The ``--scheduler`` address.

    Returns
    -------
    str or None
        The warning to print, naming the address and suggesting ``tls://``.
    """
    if not address:
        return None
    text = str(address).strip()
    protocol, sep, rest = text.partition("://")
    if not sep:
        protocol, rest = "tcp", text
    protocol = protocol.lower()
    if protocol in ENCRYPTED_PROTOCOLS or protocol == "inproc":
        return None
    host = rest.rsplit(":", 1)[0].strip("[]").lower() if ":" in rest else rest.lower()
    local = host in ("localhost", "::1") or host.startswith("127.")
    who = ("every user of this machine who reaches the port (fine behind an SSH tunnel on a machine of your own)"
           if local else "anyone on the network who reaches the port")
    return (f"scheduler {text}: {protocol}:// is unencrypted and unauthenticated: the study's traffic can be read, and "
            f"{who} can run code on every dask worker; use tls://{rest} with certificates (README, \"Distributed "
            f"sensitivity studies\")")


class SweepExecutor:
    """Context manager giving ``submit``, ``as_completed`` and ``workers`` over any backend.

    Parameters
    ----------
    workers : int, optional
        Local worker processes (default ``os.cpu_count()``); 1 runs in-process.
    scheduler : str, optional
        Address of a dask scheduler; a ``distributed.Client`` is opened (and closed on exit).
    client : distributed.Client, optional
        An existing dask client (left open on exit).
    executor : concurrent.futures.Executor, optional
        An existing executor (left open on exit).
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None, client=None, executor=None):
        self._own = False
        self.client = None
        self.executor = None
        if client is not None or scheduler is not None:
            if client is None:
                from distributed import Client

                try:
                    client = Client(scheduler, timeout="20s")
                except OSError as exc:
                    raise ValueError(f"cannot connect to dask scheduler {scheduler!r}: {exc}") from exc
                self._own = True
            self.client = client
            self.kind = "dask"
            info = client.scheduler_info()
            self.workers = max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))
        elif executor is not None:
            self.executor = executor
            self.kind = "custom"
            self.workers = getattr(executor, "_max_workers", 1) or 1
        else:
            workers = (os.cpu_count() or 1) if workers is None else int(workers)
            if workers < 1:
                raise ValueError(f"workers must be >= 1, got {workers}")
            self.workers = workers
            if workers == 1:
                self.executor, self.kind = _ImmediateExecutor(), "serial"
            else:
                # workers ignore Ctrl-C and die at SIGTERM: the caller stops them (parallel.stop_workers)
                self.executor = cf.ProcessPoolExecutor(max_workers=workers, initializer=worker_signals)
                self.kind = "process"
            self._own = True

    def submit(self, fn, *args, **kwargs):
        if self.client is not None:
            return self.client.submit(fn, *args, pure=False, **kwargs)
        return self.executor.submit(fn, *args, **kwargs)

    def as_completed(self, futures):
        if self.client is not None:
            from distributed import as_completed

            return as_completed(futures)
        return cf.as_completed(futures)

    def cancel(self, futures):
        for f in futures:
            f.cancel()

    def close(self):
        if not self._own:
            return
        if self.client is not None:
            self.client.close()
        elif self.executor is not None:
            self.executor.shutdown(wait=True, cancel_futures=True)
        self._own = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def describe(self) -> str:
        return f"{self.kind} ({self.workers} worker{'s' if self.workers != 1 else ''})"


def as_executor(executor=None, workers=None, scheduler=None, client=None) -> SweepExecutor:
    """Normalise the user's choice into a :class:`SweepExecutor` (an existing one is returned as is)."""
    if isinstance(executor, SweepExecutor):
        return executor
    if executor is not None and type(executor).__module__.startswith("distributed"):
        return SweepExecutor(client=executor)
    return SweepExecutor(workers=workers, scheduler=scheduler, client=client, executor=executor)


def progress_bar(total: int, desc: str = "", enabled: bool = True):
    """tqdm bar that appears only after 2 s and only on a TTY (quiet in CI, logs and pipes)."""
    from tqdm.auto import tqdm

    disable = (not enabled) or not sys.stderr.isatty()
    return tqdm(total=total, desc=desc, unit="run", delay=2.0, disable=disable, leave=False, file=sys.stderr)


def _run_chunk(evaluator, ids, X):
    """Worker side: evaluate one chunk; a failure of the whole chunk becomes per-sample errors."""
    t0 = time.perf_counter()
    try:
        out = dict(evaluator(X))
    except Exception as exc:  # noqa: BLE001 - reported per sample, the sweep continues
        return ids, {}, [f"{type(exc).__name__}: {exc}"] * len(ids), time.perf_counter() - t0
    errors = out.pop("error", None)
    if errors is None:
        errors = [""] * len(ids)
    metrics = {k: np.asarray(v, dtype=float).reshape(len(ids)) for k, v in out.items()}
    return ids, metrics, list(errors), time.perf_counter() - t0


def default_chunk_size(n: int, workers: int, max_chunk: int = 64) -> int:
    """Enough chunks to balance the load (>= 4 per worker) but at most ``max_chunk`` samples each."""
    return max(1, min(max_chunk, math.ceil(n / (4 * max(1, workers)))))


def run_sweep(evaluator, X, executor=None, store=None, chunk_size: int | None = None, progress: bool = True,
              desc: str = "sweep", max_chunk: int = 64) -> dict:
    """Evaluate ``evaluator`` on every row of ``X`` and return the tidy table ``{column: (n,)}``.

    Parameters
    ----------
    evaluator : callable
        ``evaluator(X_chunk) -> {metric: (m,) array, "error": [str]*m}``; picklable.
    X : (n, d) ndarray
        Samples; row i has sample id i. With a ``store`` it must be the store's design.
    executor : SweepExecutor, concurrent.futures.Executor or distributed.Client, optional
        Default: local processes on every CPU.
    store : ResultStore, optional
        Finished chunks are written to it as they complete, and samples already on disk are skipped
        (resume). Without a store results are only kept in memory.
    chunk_size : int, optional
        Samples per task (default :func:`default_chunk_size`, capped by ``evaluator.max_chunk`` when the
        evaluator has one, else by ``max_chunk``).

    Returns
    -------
    dict
        Columns ``sample_id``, metrics and ``error`` for all n samples, sorted by id (parameter columns too
        when a store is used).
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2:
        raise ValueError(f"samples must be a 2-D array (n, d), got shape {X.shape}")
    if store is not None and (store.design.shape != X.shape or not np.array_equal(store.design, X)):
        raise ValueError("the samples differ from the result store's design")
    todo = store.missing_ids() if store is not None else np.arange(X.shape[0])
    ex = as_executor(executor)
    own = ex is not executor
    mem = []
    try:
        max_chunk = getattr(evaluator, "max_chunk", None) or max_chunk  # batched evaluators like big chunks
        size = chunk_size or default_chunk_size(len(todo), ex.workers, max_chunk)
        chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
        bar = progress_bar(len(todo), desc, progress)
        try:
            for ids, metrics, errors, _ in _completed(ex, evaluator, chunks, X):
                if store is not None:
                    store.write_chunk(ids, metrics, errors)
                else:
                    mem.append((ids, metrics, errors))
                bar.update(len(ids))
        finally:
            bar.close()
    finally:
        if own:
            ex.close()
    if store is not None:
        return store.table()
    return _assemble(mem)


def _completed(ex: SweepExecutor, evaluator, chunks, X):
    """Yield chunk results as they finish (in order for the serial executor, so each is saved at once)."""
    if ex.kind == "serial":
        for ids in chunks:
            yield _run_chunk(evaluator, ids, X[ids])
        return
    futures = [ex.submit(_run_chunk, evaluator, ids, X[ids]) for ids in chunks]
    try:
        for fut in ex.as_completed(futures):
            yield fut.result()
    except BaseException:  # cleanup, re-raised
        ex.cancel(futures)
        raise


def _assemble(parts) -> dict:
    if not parts:
        return {"sample_id": np.zeros(0, dtype=np.int64), "error": np.zeros(0, dtype=object)}
    names = sorted({k for _, m, _ in parts for k in m})
    ids = np.concatenate([p[0] for p in parts])
    cols = {"sample_id": ids}
    for k in names:
        cols[k] = np.concatenate([m.get(k, np.full(len(i), np.nan)) for i, m, _ in parts])
    cols["error"] = np.array([e for _, _, errs in parts for e in errs], dtype=object)
    order = np.argsort(ids, kind="stable")
    return {k: np.asarray(v)[order] for k, v in cols.items()}
