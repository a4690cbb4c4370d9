"""Reading a file an input names: a regular file of bounded size, never a pipe, a device or an endless stream.

A model file may name another file (a vehicle TOML's ``thruster_model.name``: a thruster curve). Such a
reference must never make a command block on a named pipe, read ``/dev/zero`` until memory runs out, or load a
file from wherever the name points: :func:`inside` says whether a resolved path lies in one of the allowed
folders, and :func:`read_regular` opens it without blocking (``O_NONBLOCK``, so opening a FIFO returns at once),
checks that what it opened is a regular file, and reads at most ``max_bytes``.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path


class InputFileError(ValueError):
    """A file named by an input that is not a readable regular file of bounded size; names the file."""


def read_regular(path, max_bytes: int, what: str) -> bytes:
    """The bytes of the regular file ``path``, refusing anything else.

    Parameters
    ----------
    path : str or Path
        The file (links are followed: the caller checks where they lead, :func:`inside`).
    max_bytes : int
        The largest size accepted, bytes.
    what : str
        What the file is, for messages (``"thruster curve of model.toml"``).

    Raises
    ------
    InputFileError
        Naming the file: missing, unreadable, not a regular file (a pipe, a device, a folder), or larger than
        ``max_bytes``.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise InputFileError(f"{what} {path}: cannot be read ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a named pipe" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                    or stat.S_ISBLK(st.st_mode) else "a folder" if stat.S_ISDIR(st.st_mode) else "not a file")
            raise InputFileError(f"{what} {path}: is {kind}, expected a regular file")
        if st.st_size > max_bytes:
            raise InputFileError(f"{what} {path}: {st.st_size} bytes, more than the {max_bytes} accepted; expected "
                                 f"a small text file")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)
        if len(data) > max_bytes:  # grew while read
            raise InputFileError(f"{what} {path}: more than the {max_bytes} bytes accepted")
        return data
    finally:
        os.close(fd)


def inside(path, folders) -> bool:
    """True if ``path``, with every link resolved, lies in one of ``folders`` (also resolved)."""
    real = Path(os.path.realpath(path))
    for folder in folders:
        root = Path(os.path.realpath(folder))
        if real == root or root in real.parents:
            return True
    return False
