"""Crash-safe, resumable result tables for sweeps.

Layout of a study directory::

    OUT/.lock               held (``fcntl.flock``, exclusive) by the one run using the folder; holds its pid
    OUT/study.json          what the study is (method, parameters, design hash); written atomically once
    OUT/design.npy          the full sample matrix (n_samples, d), so a resume evaluates the same points
    OUT/chunks/c########-####.csv   one file per finished chunk of samples (tmp file + atomic rename)
    OUT/results.csv         the tidy table (one row per sample), consolidated atomically
    OUT/results.parquet     the same table when pyarrow is installed

The chunk files *are* the manifest of finished sample ids: a chunk either exists complete (the rename is
atomic) or not at all, so an interrupted sweep loses at most the chunks in flight and a resume evaluates
only the missing sample ids. Tidy table columns: ``sample_id``, one column per parameter, one per
metric, and ``error`` (empty when the evaluation succeeded; metrics are NaN otherwise).

One run at a time: a :class:`ResultStore` (and the CLI, for the whole run) holds an exclusive lock on
``OUT/.lock``; a second run on the same folder fails at once with :class:`StudyLockedError` naming the folder
and the holder's pid, so two runs can never mix their samples. A resume must request the same study
(method, seed, sample size, parameters and ranges, controller, mission: everything in ``study.json``);
otherwise :class:`StudyMismatchError` names the fields that differ. Temporary files are named after their
writer's pid plus a random token (``.NAME.PID.TOKEN.tmp``, created exclusively, never through a symlink) and
only the writer, or a later run once that pid is gone, removes them.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import stat
from pathlib import Path

import numpy as np

from udrobot_files.locks import FileLock, LockedError
from udrobot_files.nesting import loads_json
from udrobot_files.output import atomic_write

STUDY_FILE = "study.json"
DESIGN_FILE = "design.npy"
CHUNK_DIR = "chunks"
LOCK_FILE = ".lock"
#: the name of a temporary file this module writes, ``.NAME.PID.TOKEN.tmp`` (TOKEN: 12 hex digits); any other
#: ``.*.tmp`` in a study folder is the user's and never removed
TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.(?P<pid>[0-9]+)\.(?P<token>[0-9a-f]{12})\.tmp$")


class StudyMismatchError(ValueError):
    """The output directory holds a different study than the one requested."""


class StudyLockedError(RuntimeError):
    """Another run holds the study folder's lock."""


class StudyLock:
    """Exclusive, re-entrant (within one process) lock of a study folder: ``flock`` on ``OUT/.lock``
    (:class:`udrobot_files.locks.FileLock`, the lock of every output).

    Held from :meth:`acquire` to the matching :meth:`release` (or the ``with`` block); the lock file holds the
    holder's pid. The kernel drops the lock when the holder dies, so a killed run never blocks a resume. A lock
    file that is a symbolic link (or not a regular file of this user) is refused, never followed.

    Raises
    ------
    StudyLockedError
        From :meth:`acquire`, at once, if another process holds the lock or the lock file is unsafe.
    """

    def __init__(self, out):
        self.out = Path(out)
        self._lock = None

    def acquire(self) -> StudyLock:
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StudyLockedError(f"{self.out}: the study folder cannot be created ({exc.strerror})") from None
        lock = FileLock(self.out.resolve() / LOCK_FILE, f"the study folder {self.out}")
        try:
            lock.acquire()
        except LockedError as exc:
            raise StudyLockedError(f"{exc}".replace("choose another output", "choose another --out")) from None
        self._lock = lock
        return self

    def release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def remove_stale_temp_files(folder) -> list:
    """Remove the temporary files this module left in ``folder`` whose writer (PID) is gone.

    Only files named as :func:`atomic_write_bytes` names them (:data:`TEMP_NAME`: ``.NAME.PID.TOKEN.tmp``, a
    12-hex-digit token), regular files (not links) owned by this user, are candidates; a temporary file of a live
    writer is never touched (only its owner removes it), and any other ``.*.tmp`` (the user's) stays.

    Returns
    -------
    list of Path
        The removed files.
    """
    removed = []
    for tmp in Path(folder).glob(".*.tmp"):
        match = TEMP_NAME.match(tmp.name)
        if match is None:
            continue
        pid = int(match["pid"])
        if pid == os.getpid() or _pid_alive(pid):
            continue
        try:
            st = os.lstat(tmp)
        except FileNotFoundError:
            continue
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid():
            continue
        tmp.unlink(missing_ok=True)
        removed.append(tmp)
    return removed


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and an atomic rename: the one
    writer of every output (:func:`udrobot_files.output.atomic_write`; temporary ``.NAME.PID.TOKEN.tmp``,
    created exclusively, never through a symlink, removed if the write fails; a full disk or a size limit is an
    :class:`~udrobot_files.output.OutputError` naming the file)."""
    atomic_write(path, data)


def atomic_write_text(path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def design_hash(X) -> str:
    """SHA-256 of the sample matrix (identifies a design across runs)."""
    X = np.ascontiguousarray(np.asarray(X, dtype=np.float64))
    return hashlib.sha256(X.tobytes() + str(X.shape).encode()).hexdigest()[:16]


def _fmt(v) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return "" if v is None else str(v)


def table_to_csv(columns: dict) -> str:
    """CSV text of a column table ``{name: sequence}`` (floats written exactly with repr)."""
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 0
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for i in range(n):
        w.writerow([_fmt(columns[k][i]) for k in names])
    return buf.getvalue()


def read_csv_table(path) -> dict:
    """Read a CSV written by :func:`table_to_csv` into ``{name: ndarray}`` (numeric columns as float,
    ``sample_id`` as int, other columns as str)."""
    path = Path(path)
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty table (expected a header row)")
    header, body = rows[0], rows[1:]
    for i, r in enumerate(body, start=2):
        if len(r) != len(header):
            raise ValueError(f"{path}: row {i} has {len(r)} fields, expected {len(header)}")
    out = {}
    for j, name in enumerate(header):
        col = [r[j] for r in body]
        if name == "sample_id":
            out[name] = np.array([int(c) for c in col], dtype=np.int64)
            continue
        if name == "error":
            out[name] = np.array(col, dtype=object)
            continue
        try:
            out[name] = np.array([float(c) if c != "" else np.nan for c in col], dtype=float)
        except ValueError:
            out[name] = np.array(col, dtype=object)
    return out


def concat_tables(tables) -> dict:
    tables = [t for t in tables if t and len(t.get("sample_id", [])) > 0]
    if not tables:
        return {}
    names = list(tables[0])
    return {k: np.concatenate([np.asarray(t[k]) for t in tables]) for k in names}


class ResultStore:
    """A study directory (see module docstring).

    Parameters
    ----------
    out : path
        Study directory (created).
    study : dict
        JSON-able description of the study; on resume it must match the stored one (except ``created``).
    design : (n, d) ndarray
        The sample matrix (one row per sample id 0..n-1).
    param_names : list of str
        Column names of the design.
    resume : bool
        Continue an existing study; without it an existing non-empty study directory is an error
        (results are never overwritten).

    The store holds the folder's :class:`StudyLock` from construction to :meth:`close` (or the end of a
    ``with`` block).

    Raises
    ------
    StudyLockedError
        Another run uses the folder.
    StudyMismatchError
        ``resume`` of a folder holding another study (the message names the differing fields).
    FileExistsError
        The folder holds a study and ``resume`` is False.
    """

    def __init__(self, out, study: dict, design, param_names, resume: bool = False):
        self.out = Path(out)
        self.lock = StudyLock(self.out).acquire()
        try:
            self._open(study, design, param_names, resume)
        except BaseException:  # cleanup, re-raised
            self.lock.release()
            raise

    def close(self) -> None:
        """Release the folder's lock (the results stay on disk)."""
        self.lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def _open(self, study, design, param_names, resume):
        self.design = np.asarray(design, dtype=float)
        self.param_names = list(param_names)
        if self.design.ndim != 2 or self.design.shape[1] != len(self.param_names):
            raise ValueError(f"design has shape {self.design.shape}, expected (n, {len(self.param_names)})")
        self.study = dict(study, design_hash=design_hash(self.design), n_samples=int(self.design.shape[0]),
                          parameters=self.param_names if "parameters" not in study else study["parameters"])
        self.chunk_dir = self.out / CHUNK_DIR
        study_path = self.out / STUDY_FILE
        if study_path.exists():
            if not resume:
                raise FileExistsError(f"{self.out} already holds a study ({STUDY_FILE}); pass --resume to continue it "
                                      "or choose another --out (results are never overwritten)")
            old = loads_json(study_path.read_text(), study_path)
            diff = study_differences(old, self.study)
            if diff:
                raise StudyMismatchError(f"{study_path}: the stored study differs from the requested one in "
                                         f"{'; '.join(diff)}; resume with the same settings or use another --out")
            stored = np.load(self.out / DESIGN_FILE)
            if stored.shape != self.design.shape or not np.array_equal(stored, self.design):
                raise StudyMismatchError(f"{self.out / DESIGN_FILE}: stored design differs from the requested one")
        else:
            self.out.mkdir(parents=True, exist_ok=True)
            buf = io.BytesIO()
            np.save(buf, self.design)
            atomic_write_bytes(self.out / DESIGN_FILE, buf.getvalue())
            atomic_write_text(study_path, json.dumps(self.study, indent=2, default=_json_default))
        self.chunk_dir.mkdir(exist_ok=True)
        for folder in (self.out, self.chunk_dir):  # leftovers of writers killed mid-write (never a live one's)
            remove_stale_temp_files(folder)

    # -------------------------------------------------------------- chunks
    def chunk_files(self):
        return sorted(self.chunk_dir.glob("c*.csv"))

    def finished_ids(self) -> np.ndarray:
        """Sorted ids of the samples whose results are on disk."""
        ids = [read_csv_table(f)["sample_id"] for f in self.chunk_files()]
        return np.unique(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int64)

    def missing_ids(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.design.shape[0]), self.finished_ids())

    def write_chunk(self, ids, metrics: dict, errors=None) -> Path:
        """Atomically write the results of the samples ``ids``: ``metrics`` ``{name: (len(ids),)}``."""
        ids = np.asarray(ids, dtype=np.int64)
        cols = {"sample_id": ids}
        for j, name in enumerate(self.param_names):
            cols[name] = self.design[ids, j]
        for name, val in metrics.items():
            val = np.asarray(val, dtype=float)
            if val.shape != ids.shape:
                raise ValueError(f"metric {name!r} has shape {val.shape}, expected {ids.shape}")
            cols[name] = val
        cols["error"] = list(errors) if errors is not None else [""] * len(ids)
        path = self.chunk_dir / f"c{int(ids[0]):08d}-{len(ids):04d}.csv"
        atomic_write_text(path, table_to_csv(cols))
        return path

    # -------------------------------------------------------------- table
    def table(self) -> dict:
        """All finished rows, sorted by sample id, duplicates (a chunk written twice) removed."""
        t = concat_tables(read_csv_table(f) for f in self.chunk_files())
        if not t:
            return {}
        _, first = np.unique(t["sample_id"], return_index=True)
        order = first[np.argsort(t["sample_id"][first])]
        return {k: np.asarray(v)[order] for k, v in t.items()}

    def consolidate(self) -> dict:
        """Write ``results.csv`` (and ``results.parquet`` with pyarrow) atomically; returns the table."""
        t = self.table()
        if not t:
            return t
        atomic_write_text(self.out / "results.csv", table_to_csv(t))
        write_parquet(self.out / "results.parquet", t)
        return t


def write_parquet(path, table: dict) -> bool:
    """Write a column table as Parquet atomically if pyarrow is installed; returns whether it did."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    cols = {k: (list(map(str, v)) if np.asarray(v).dtype == object else np.asarray(v)) for k, v in table.items()}
    buf = pa.BufferOutputStream()
    pq.write_table(pa.table(cols), buf)
    atomic_write_bytes(path, buf.getvalue().to_pybytes())
    return True


def write_table(path_stem, table: dict) -> list:
    """Write ``STEM.csv`` (and ``STEM.parquet``) atomically; returns the written paths."""
    stem = Path(path_stem)
    paths = [stem.with_suffix(".csv")]
    atomic_write_text(paths[0], table_to_csv(table))
    if write_parquet(stem.with_suffix(".parquet"), table):
        paths.append(stem.with_suffix(".parquet"))
    return paths


def study_differences(old: dict, new: dict) -> list:
    """``["seed: stored 0, requested 3", ...]`` for every field of two study descriptions that differs."""
    a, b = _strip(old), _strip(new)
    return [f"{k}: stored {_short(a.get(k))}, requested {_short(b.get(k))}"
            for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def _short(v, n: int = 120) -> str:
    text = json.dumps(v, default=_json_default)
    return text if len(text) <= n else text[: n - 3] + "..."


def _strip(study: dict) -> dict:
    return json.loads(json.dumps({k: v for k, v in study.items() if k not in ("created", "workers", "scheduler")},
                                 default=_json_default))


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
