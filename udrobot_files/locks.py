"""Exclusive locks of files and folders between ``udrobot-ctrl`` runs: one mechanism for every writer.

Two uses, one primitive (:class:`FileLock`, ``fcntl.flock`` on a lock file, never through a symbolic link):

- a sensitivity study folder is locked by ``OUT/.lock`` for the whole study
  (:class:`udrobot_ctrl.sensitivity.results.StudyLock`);
- every output file of a command is *claimed* before any work (:func:`claim_outputs`, called by
  :func:`udrobot_files.output.check_command`): a second run that names the same output (the same path, through
  another spelling or a link) while the first still runs is refused at once, naming the file and the first run's
  pid, instead of both writing and both printing "wrote". Claims are lock files named by the SHA-256 of the
  output's resolved path in the user's private folder ``$XDG_CACHE_HOME/udrobot_ctrl/locks``
  (:func:`udrobot_files.caches.private_dir`), so no lock file is left next to the user's data and a report
  folder that does not exist yet need not be created to be claimed.

The kernel drops a ``flock`` when its holder dies (also by SIGKILL), so a killed run never blocks the next one;
its lock file stays behind and is reused. Locks are per open file: a forked child (a pool worker) closes the
descriptors it inherited (:func:`os.register_at_fork`), so a lock ends with its holder's release.
"""
from __future__ import annotations

import atexit
import errno
import fcntl
import hashlib
import os
import stat
from pathlib import Path

from udrobot_files.caches import private_dir, user_cache_root


class LockedError(ValueError):
    """Another process holds the lock; the message names the file and the holder's pid."""


_HELD: dict = {}  # lock file (str) -> [fd, depth]: the locks this process holds (re-entrant within a process)


def _forget_locks_in_child() -> None:
    """In a forked child: close the inherited lock descriptors (the parent keeps its locks)."""
    for fd, _ in _HELD.values():
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD.clear()


os.register_at_fork(after_in_child=_forget_locks_in_child)


class FileLock:
    """Exclusive, non-blocking, re-entrant (within one process) ``flock`` on the lock file ``path``.

    The lock file is opened with ``O_NOFOLLOW`` and must be a regular file of this user: a symbolic link, a
    folder, a pipe or another user's file planted at its name is refused with :class:`LockedError` naming it
    (never followed, never a traceback). It holds the holder's pid and what it holds.

    Parameters
    ----------
    path : str or Path
        The lock file (created if missing).
    what : str
        What the lock protects, for messages (e.g. ``"the study folder OUT"``).
    """

    def __init__(self, path, what: str):
        self.path = Path(path)
        self.what = what
        self._key = None

    def acquire(self) -> FileLock:
        """Take the lock at once or raise :class:`LockedError` (held by another process, or an unsafe lock file)."""
        key = str(self.path)
        held = _HELD.get(key)
        if held is not None:
            held[1] += 1
            self._key = key
            return self
        for _ in range(8):  # the holder may remove the file between our open and our flock: retry on a new one
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").split("\n")[0].strip() or "unknown"
                os.close(fd)
                raise LockedError(f"{self.what} is in use by another udrobot-ctrl run (pid {holder}); wait for it "
                                  f"to finish or choose another output") from None
            try:
                same = os.fstat(fd).st_ino == os.lstat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n{self.what}\n".encode(errors="replace"), 0)
                _HELD[key] = [fd, 1]
                self._key = key
                return self
            os.close(fd)
        raise LockedError(f"{self.what}: its lock file {self.path} keeps being replaced; another run is racing "
                          f"for it")

    def _open(self) -> int:
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, 0o600)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise LockedError(f"{self.what}: its lock file {self.path} is a symbolic link; refusing to follow "
                                  f"it (remove it if you made it)") from None
            raise LockedError(f"{self.what}: its lock file {self.path} cannot be opened "
                              f"({exc.strerror or exc})") from None
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid():
            os.close(fd)
            kind = "not a regular file" if not stat.S_ISREG(st.st_mode) else f"owned by uid {st.st_uid}"
            raise LockedError(f"{self.what}: its lock file {self.path} is {kind}; refusing to use it")
        return fd

    def release(self, remove: bool = False) -> None:
        """Drop the lock (the last release of a re-entrant lock); ``remove``: delete the lock file first."""
        if self._key is None:
            return
        key, self._key = self._key, None
        held = _HELD.get(key)
        if held is None:
            return
        held[1] -= 1
        if held[1] == 0:
            del _HELD[key]
            if remove:
                try:
                    os.unlink(key)
                except OSError:
                    pass
            else:
                os.ftruncate(held[0], 0)
            os.close(held[0])  # closing the descriptor drops the flock

    @property
    def held(self) -> bool:
        return self._key is not None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False


#: the claims of this process: resolved output path (str) -> FileLock
_CLAIMS: dict = {}


def claim_path(path) -> str:
    """The key of an output in the claims: its absolute path with every existing link resolved."""
    return str(Path(os.path.abspath(path)).resolve())


def lock_folder() -> Path:
    """The private folder of the output claims, ``$XDG_CACHE_HOME/udrobot_ctrl/locks`` (0700, checked)."""
    return private_dir(user_cache_root() / "locks", "locks")


def claim_outputs(paths, labels=None) -> list:
    """Claim output files for this run until :func:`release_claims` (or the process ends).

    Parameters
    ----------
    paths : iterable of str or Path
        Every file the command will write.
    labels : iterable of str, optional
        The option naming each path (``--json``), for messages.

    Returns
    -------
    list of str
        The claimed paths (resolved).

    Raises
    ------
    LockedError
        Naming the option, the file and the pid of the run that already claims it; nothing is claimed then.
    """
    paths = [Path(p) for p in paths]
    labels = list(labels) if labels is not None else ["output"] * len(paths)
    folder = lock_folder()
    taken, done = [], []
    try:
        for label, path in zip(labels, paths):
            key = claim_path(path)
            if key in _CLAIMS or key in done:
                continue
            name = hashlib.sha256(key.encode(errors="surrogateescape")).hexdigest()[:32] + ".lock"
            lock = FileLock(folder / name, f"{label} {path}")
            lock.acquire()
            taken.append((key, lock))
            done.append(key)
    except BaseException:
        for _, lock in taken:
            lock.release(remove=True)
        raise
    _CLAIMS.update(taken)
    return done


def release_claims() -> None:
    """Release every output claim of this process (``udrobot-ctrl`` does so when a command ends)."""
    for key in list(_CLAIMS):
        _CLAIMS.pop(key).release(remove=True)


atexit.register(release_claims)  # a library user's claims end with the process, their lock files removed


def _forget_claims_in_child() -> None:
    _CLAIMS.clear()  # the descriptors were closed by _forget_locks_in_child


os.register_at_fork(after_in_child=_forget_claims_in_child)
