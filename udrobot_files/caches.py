"""Private on-disk caches of compiled code: nothing is loaded from a folder other users can write.

Two caches hold code that is executed when loaded: casadi-generated C compiled by gcc
(:mod:`udrobot_ctrl.dynamics.fastsim`, ``$UDROBOT_CACHE`` or ``~/.cache/udrobot_ctrl/fastsim``) and numba's
cache of the simulation kernels (pickled index + object code; ``$NUMBA_CACHE_DIR`` if the user set it, else
``~/.cache/udrobot_ctrl/numba``, never the source tree). Both folders are created 0700 and used only if they
are real folders owned by this user and not writable by group or others; otherwise a warning is issued and a
private temporary folder (removed at exit) is used instead.
"""
from __future__ import annotations

import os
import stat
import tempfile
import warnings
from pathlib import Path

_FALLBACKS: dict = {}  # purpose -> TemporaryDirectory kept alive for the process


def user_cache_root() -> Path:
    """``$XDG_CACHE_HOME/udrobot_ctrl`` or ``~/.cache/udrobot_ctrl``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "udrobot_ctrl"


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


def private_dir(path, purpose: str) -> Path:
    """``path`` created 0700 if missing and returned if safe (:func:`unsafe_reason`); else, with a warning, a
    private temporary folder for this process (one per ``purpose``)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700, exist_ok=True)
    except OSError as exc:
        why = f"cannot be created ({exc.strerror})"
    else:
        why = unsafe_reason(path, want_dir=True)
    if why is None:
        return path
    if purpose not in _FALLBACKS:
        warnings.warn(f"{purpose} cache {path} {why}; not loading anything from it, using a private temporary "
                      f"folder for this process instead", RuntimeWarning, stacklevel=3)
        _FALLBACKS[purpose] = tempfile.TemporaryDirectory(prefix=f"udrobot_{purpose}_")  # 0700
    return Path(_FALLBACKS[purpose].name)


def configure_numba_cache() -> str:
    """Point numba's on-disk cache at a private folder: ``NUMBA_CACHE_DIR`` if set and safe, else our own.

    numba's cache holds pickled indexes and object code that are loaded (and so executed) by the next run, so a
    folder chosen by the user through ``NUMBA_CACHE_DIR`` gets the same checks as ``UDROBOT_CACHE``
    (:func:`private_dir`: created 0700 if missing; a symbolic link, a folder of another user, or one writable
    by group or others is refused with a warning and a private temporary folder is used for this process).
    Unset, the folder is ``$XDG_CACHE_HOME/udrobot_ctrl/numba``.

    Must run before the ``cache=True`` functions are decorated (numba picks the folder then).

    Returns
    -------
    str
        The folder in use (also left in ``NUMBA_CACHE_DIR`` and numba's ``config.CACHE_DIR``).
    """
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    folder = str(private_dir(Path(chosen) if chosen else user_cache_root() / "numba", "numba"))
    if folder == chosen:
        return chosen
    os.environ["NUMBA_CACHE_DIR"] = folder
    from numba.core import config  # third-party, imported here so that importing this module stays cheap

    config.CACHE_DIR = folder  # numba already imported: its config read the environment before we set it
    return folder
