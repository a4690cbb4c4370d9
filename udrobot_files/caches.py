"""Private on-disk caches of compiled code: nothing is loaded from a folder other users can write.

Two caches hold code that is executed when loaded: casadi-generated C compiled by gcc
(:mod:`udrobot_ctrl.dynamics.fastsim`, ``$UDROBOT_CACHE`` or ``$XDG_CACHE_HOME/udrobot_ctrl/fastsim``) and
numba's cache of the simulation kernels (pickled index + object code; ``$NUMBA_CACHE_DIR`` if the user set it,
else ``$XDG_CACHE_HOME/udrobot_ctrl/numba``, never the source tree; ``~/.cache`` without ``XDG_CACHE_HOME``).
Both folders are created 0700 and used only if the whole path is safe (:func:`path_unsafe_reason`): the folder
a real folder (no symbolic link) owned by this user and not writable by group or others; every folder above it
owned by root or this user and not writable by others unless sticky (``/tmp``), every link above it owned by
root or this user (and its target checked the same way); and nothing inside it (numba's per-module subfolders,
index pickles, object code) a symbolic link or another user's, nor writable by group or others unless the
folder itself admits neither (mode ``0700``). Otherwise a warning is issued and a fresh private temporary
folder (removed at exit) is used instead: nothing planted is loaded.
"""
from __future__ import annotations

import errno
import os
import stat
import tempfile
import warnings
from pathlib import Path

_FALLBACKS: dict = {}  # purpose -> TemporaryDirectory kept alive for the process
_CONFIGURED: set = set()  # numba cache folders checked and configured in this process


def user_cache_root() -> Path:
    """``$XDG_CACHE_HOME/udrobot_ctrl`` or ``~/.cache/udrobot_ctrl``.

    A relative ``XDG_CACHE_HOME`` is ignored, as the XD Base Directory Specification requires ("all paths set
    in these environment variables must be absolute"): the cache would otherwise follow the working folder.
    """
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "udrobot_ctrl"


def unsafe_reason(path, want_dir: bool):
    """Why ``path`` may hold code others planted, or None if it is safe to load from.

    Unsafe: missing, a symbolic link, the wrong kind (folder / regular file), owned by another user, or
    writable by group or others.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return "missing"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if want_dir and not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    if not want_dir and not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    if st.st_uid != os.getuid():
        return f"is owned by uid {st.st_uid}, not by this user ({os.getuid()})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"is writable by group or others (mode {stat.S_IMODE(st.st_mode):o})"
    return None


def _ancestor_unsafe(path: Path):
    """Why a folder above a cache (``path``'s parents, from ``/`` down) lets another user replace what is below
    it, or None: a folder or link owned by another user than root or this one, or a folder writable by group or
    others without the sticky bit. A link is followed: its target's folders are checked the same way."""
    uid = os.getuid()
    absolute = Path(os.path.abspath(path))
    chains = [absolute.parents]
    real = Path(os.path.realpath(absolute.parent))
    if real != absolute.parent:
        chains.append([real, *real.parents])
    for chain in chains:
        for folder in reversed(list(chain)):
            try:
                st = os.lstat(folder)
            except OSError as exc:
                return f"has a parent folder {folder} that cannot be examined ({exc.strerror})"
            if st.st_uid not in (0, uid):
                kind = "link" if stat.S_ISLNK(st.st_mode) else "folder"
                return f"has a parent {kind} {folder} owned by uid {st.st_uid} (neither root nor this user)"
            if (stat.S_ISDIR(st.st_mode) and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
                    and not st.st_mode & stat.S_ISVTX):
                return (f"has a parent folder {folder} writable by group or others without the sticky bit "
                        f"(mode {stat.S_IMODE(st.st_mode):o})")
    return None


def _inside_unsafe(path: Path):
    """Why something inside the cache folder ``path`` may be planted, or None: a symbolic link, a file or folder
    owned by another user, or (unless ``path`` itself grants group and others nothing) writable by them."""
    closed = not os.lstat(path).st_mode & 0o077
    for top, dirs, files in os.walk(path, followlinks=False):
        for name in dirs + files:
            entry = os.path.join(top, name)
            try:
                st = os.lstat(entry)
            except FileNotFoundError:
                continue
            if stat.S_ISLNK(st.st_mode):
                return f"holds a symbolic link {entry}"
            if st.st_uid != os.getuid():
                return f"holds {entry} owned by uid {st.st_uid}, not by this user ({os.getuid()})"
            if not closed and st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
                return f"holds {entry} writable by group or others (mode {stat.S_IMODE(st.st_mode):o})"
    return None


def path_unsafe_reason(path):
    """Why the cache folder ``path`` may hold code others planted, or None: the folder itself
    (:func:`unsafe_reason`), every folder and link above it (:func:`_ancestor_unsafe`) and everything inside
    it (:func:`_inside_unsafe`)."""
    return (unsafe_reason(path, want_dir=True) or _ancestor_unsafe(Path(path))
            or _inside_unsafe(Path(path)))


def private_dir(path, purpose: str) -> Path:
    """``path`` created 0700 if missing and returned if safe along its whole path and inside
    (:func:`path_unsafe_reason`); else, with a warning, a fresh private temporary folder for this process (one
    per ``purpose``)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700, exist_ok=True)
    except OSError as exc:
        why = f"cannot be created ({exc.strerror})"
    else:
        why = path_unsafe_reason(path)
    if why is None:
        return path
    if purpose not in _FALLBACKS:
        warnings.warn(f"{purpose} cache {path} {why}; not loading anything from it, using a private temporary "
                      f"folder for this process instead", RuntimeWarning, stacklevel=3)
        _FALLBACKS[purpose] = tempfile.TemporaryDirectory(prefix=f"udrobot_{purpose}_")  # 0700
    return Path(_FALLBACKS[purpose].name)


#: errors of a cache write that mean "no room here now" (a full disk, ``ulimit -f``, a quota, a read-only disk)
UNSAVED_ERRNOS = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EROFS})


def _tolerate_unsaved_kernels() -> None:
    """Make numba's cache save (``numba.core.caching.Cache.save_overload``) survive a full disk or a file-size
    limit: the kernel is compiled and used all the same, only not kept for the next run (a warning says so).
    Without this, a cold cache under ``ulimit -f`` ended the command with numba's traceback."""
    from numba.core import caching  # third-party, imported here so that importing this module stays cheap

    original = caching.Cache.save_overload
    if getattr(original, "_tolerates_full_disk", False):
        return

    def save_overload(self, sig, data):
        try:
            original(self, sig, data)
        except OSError as exc:
            if exc.errno not in UNSAVED_ERRNOS:
                raise
            warnings.warn(f"numba cache {self._cache_path}: a compiled kernel was not saved "
                          f"({exc.strerror or exc}); it is compiled again by the next run", RuntimeWarning,
                          stacklevel=2)

    save_overload._tolerates_full_disk = True
    caching.Cache.save_overload = save_overload


def configure_numba_cache() -> str:
    """Point numba's on-disk cache at a private folder: ``NUMBA_CACHE_DIR`` if set and safe, else our own.

    numba's cache holds pickled indexes and object code that are loaded (and so executed) by the next run, so a
    folder chosen by the user through ``NUMBA_CACHE_DIR`` gets the same checks as ``UDROBOT_CACHE``
    (:func:`private_dir`: created 0700 if missing; a symbolic link, a folder of another user, or one writable
    by group or others, anywhere along its path or inside it, is refused with a warning and a private temporary
    folder is used for this process).
    Unset, the folder is ``$XDG_CACHE_HOME/udrobot_ctrl/numba``.

    Must run before the ``cache=True`` functions are decorated (numba picks the folder then).

    Returns
    -------
    str
        The folder in use (also left in ``NUMBA_CACHE_DIR`` and numba's ``config.CACHE_DIR``).
    """
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen and chosen in _CONFIGURED:  # checked by an earlier call of this process (each kernel module calls)
        return chosen
    folder = str(private_dir(Path(chosen) if chosen else user_cache_root() / "numba", "numba"))
    _tolerate_unsaved_kernels()
    _CONFIGURED.add(folder)
    if folder == chosen:
        return chosen
    os.environ["NUMBA_CACHE_DIR"] = folder
    from numba.core import config  # third-party, imported here so that importing this module stays cheap

    config.CACHE_DIR = folder  # numba already imported: its config read the environment before we set it
    return folder
