"""One output-file policy for every writer: never destroy an input, never overwrite without ``--force``.

Rules (the same for every command, see docs/files.md):

- An output may not be an input, nor the sidecar (``NAME.json``) of an input run (``NAME.csv``), nor may an
  output run's sidecar be an input. Paths are compared after resolving symbolic links, and by inode when both
  exist (hard links).
- An existing output (or the sidecar a run output would write) is replaced only with ``force=True``; a device,
  named pipe or socket at an output path is never replaced (:func:`not_regular`).
- The destination folder is checked for writability *before* the computation (:func:`check_outputs`).
- A missing folder is created only for an option whose documented value is a folder (``demo --out DIR``,
  ``compare --out DIR``, ``--plot DIR``, :func:`check_output_dir`). A file option (``simulate --out SIM.csv``)
  whose folder does not exist is refused with ``create_folders=False``, naming the folder: a mistyped path should
  not grow a tree of folders silently.
- Files are written atomically (:func:`atomic_write`, :func:`open_atomic`): into an unpredictable temporary
  file ``.NAME.PID.TOKEN.tmp`` created exclusively (``O_EXCL | O_NOFOLLOW``, so never through a planted symlink)
  in the destination folder, then renamed over the target (``os.replace``); the temporary file is removed on any
  failure. The final mode is ``0o666 & ~umask``, as for a file created by ``open()``.
- A write that fails (a full disk ``ENOSPC``, a file-size limit ``EFBIG`` from ``ulimit -f``, a quota, an I/O
  error) raises :class:`OutputError` naming the file and the reason: no traceback, no partial file, the previous
  file (if any) intact.
- One check per command (:func:`check_command`), before any work: every output file and report folder (with the
  files it will hold) against every input and every other output, then claimed for the run
  (:func:`udrobot_files.locks.claim_outputs`) so that a second run naming the same output at the same time is
  refused instead of both writing.
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from pathlib import Path

from udrobot_files.locks import claim_outputs


class OutputError(ValueError):
    """An output path that would destroy user data or cannot be written; the message names the file."""


#: temporary files of :func:`open_atomic` not yet renamed into place or removed, in this process
_TEMPORARIES: set = set()


def remove_temporaries() -> list:
    """Remove the temporary files :func:`open_atomic` has created in this process and not yet renamed or removed
    (a run stopped by a signal mid-write: ``udrobot-ctrl`` calls this before it exits).

    Returns
    -------
    list of str
        The files removed.
    """
    removed = []
    for tmp in list(_TEMPORARIES):
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
            removed.append(tmp)
        _TEMPORARIES.discard(tmp)
    return removed


def sidecar(path) -> Path:
    """The ``udrobot-run/1`` sidecar of a run CSV: ``NAME.csv`` -> ``NAME.json``."""
    return Path(path).with_suffix(".json")


def run_files(path) -> list:
    """Files a run output writes: the CSV and its sidecar (the sidecar may or may not be written)."""
    return [Path(path), sidecar(path)]


def _input_family(path) -> list:
    """(file, description) for an input and, for a run CSV, its sidecar (which belongs to the input)."""
    p = Path(path)
    fam = [(p, f"the input {p}")]
    if p.suffix.lower() == ".csv":
        fam.append((sidecar(p), f"the sidecar of the input {p}"))
    return fam


def spec_files(*specs) -> list:
    """The existing files named by command-line specs: a path, or ``PATH:FORM`` (a coefficient set with a form)."""
    out = []
    for spec in specs:
        if spec is None:
            continue
        text = str(spec)
        for cand in (text, text.rsplit(":", 1)[0] if ":" in text else None):
            if cand and Path(cand).is_file():
                out.append(Path(cand))
                break
    return out


def _collides(out: Path, inp: Path) -> bool:
    if out.resolve() == inp.resolve():
        return True
    return (out.exists() or out.is_symlink()) and (inp.exists() or inp.is_symlink()) and _same_file(out, inp)


def _same_file(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def current_umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux /proc), else by a swap."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _check_folder(path: Path, option: str, create: bool = True) -> None:
    """The folder that will hold ``path`` exists (or, with ``create``, can be created) and is writable."""
    parent = path.parent if str(path.parent) else Path(".")
    if not create and not parent.is_dir():
        what = "is not a folder" if parent.exists() else "does not exist"
        raise OutputError(f"{option} {path}: folder {parent} {what}; create it first or choose another path "
                          f"({option} names a file and creates no folder)")
    probe = parent
    while not probe.exists():
        if probe.is_symlink():
            raise OutputError(f"{option} {path}: folder {probe} is a dangling symbolic link")
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{option} {path}: {probe} is not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: folder {probe} is not writable")


def not_regular(path) -> str | None:
    """What ``path`` is if it exists and is neither a regular file nor a symbolic link (a device, a named pipe, a
    socket), else None: such a node is never replaced by an output, ``--force`` or not."""
    try:
        mode = os.lstat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    if stat.S_ISREG(mode) or stat.S_ISLNK(mode) or stat.S_ISDIR(mode):
        return None
    kinds = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a named pipe"),
             (stat.S_ISSOCK, "a socket"))
    return next((what for test, what in kinds if test(mode)), "not a regular file")


def check_outputs(outputs, inputs=(), *, force: bool = False, option: str = "--out",
                  create_folders: bool = True) -> list:
    """Refuse outputs that would destroy an input or replace a file without ``force``; check the folders.

    Parameters
    ----------
    outputs : iterable of str or Path (None entries ignored)
        Every file the command will write, including sidecars (use :func:`run_files` for runs).
    inputs : iterable of str or Path (None entries ignored)
        Every file the command reads; a run CSV brings its sidecar along.
    force : bool
        Allow replacing existing outputs (never inputs).
    option : str
        The option naming the outputs, for messages (e.g. ``--json``).
    create_folders : bool
        True: a missing folder of an output is created when it is written (an output inside a folder option,
        ``--plot DIR``). False, for an option whose value is a file: a missing folder is refused, naming it.

    Returns
    -------
    list of Path
        The outputs, as given.

    Raises
    ------
    OutputError
        Naming the output and the input it would destroy, the existing file (without ``force``), a device, pipe
        or socket at the output path (whatever ``force``), the unwritable folder, or (``create_folders`` False)
        the missing folder.
    """
    outs = [Path(o) for o in outputs if o is not None]
    ins = [fam for i in inputs if i is not None for fam in _input_family(i)]
    for o in outs:
        for i, what in ins:
            if _collides(o, i):
                raise OutputError(f"{option} {o}: is {what}; refusing to overwrite input data, choose another output")
    for a, o in enumerate(outs):
        for b in outs[a + 1:]:
            if o.resolve() == b.resolve():
                raise OutputError(f"{option} {o}: given twice as an output ({b})")
    for o in outs:
        if o.is_dir():
            raise OutputError(f"{option} {o}: is a folder, expected a file name")
        kind = not_regular(o)
        if kind:
            raise OutputError(f"{option} {o}: is {kind}, not a regular file; refusing to replace it (--force only "
                              f"replaces files), choose a file name")
        if (o.exists() or o.is_symlink()) and not force:
            raise OutputError(f"{option} {o}: exists; pass --force to replace it")
        _check_folder(o, option, create_folders)
    return outs


def check_distinct_outputs(outputs) -> None:
    """Refuse two output options of one command that name the same file (``--json X --out-model X``).

    Every command passes all its outputs at once, before any computation: the same path given twice, through a
    different spelling, a symbolic link or a hard link, would have the second write destroy the first.

    Parameters
    ----------
    outputs : mapping or iterable of (option, paths)
        Each option (e.g. ``"--json"``) with the file or files it writes (a path, or a list of paths such as
        :func:`run_files`' CSV and sidecar); None entries and options are ignored.

    Raises
    ------
    OutputError
        Naming both options and the file they share.
    """
    items = outputs.items() if hasattr(outputs, "items") else outputs
    seen = []  # (option, given path, resolved path)
    for option, paths in items:
        if paths is None:
            continue
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        for k, path in enumerate(paths):
            if path is None:
                continue
            path = Path(path)
            resolved = path.resolve()
            label = option if k == 0 else f"{option}'s {'sidecar' if path.suffix == '.json' else 'companion file'}"
            for other_label, other, other_resolved in seen:
                if resolved == other_resolved or _same_file(path, other):
                    same = str(path) if str(path) == str(other) else f"{other} and {path}"
                    what = f"{other_label} and {label}" if other_label != label else f"{label} (twice)"
                    raise OutputError(f"{what} name the same file ({same}); the second write would destroy the "
                                      f"first: give each output its own file")
            seen.append((label, path, resolved))


def check_output_dir(folder, inputs=(), *, force: bool = False, option: str = "--out", names=()) -> Path:
    """Check an output folder: not a file, writable, and the listed file ``names`` in it obey :func:`check_outputs`.

    Files the command writes under other (data-dependent) names are protected by :func:`atomic_write`'s
    ``protect`` argument at write time.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{option} {folder}: exists and is not a folder")
    for i in inputs:
        if i is not None and Path(i).resolve() == folder.resolve():
            raise OutputError(f"{option} {folder}: is an input; choose another output folder")
    _check_folder(folder / "x", option)
    check_outputs([folder / n for n in names], inputs, force=force, option=option)
    return folder


def _protect(path: Path, protect) -> None:
    for i in protect or ():
        for p, what in _input_family(i):
            if _collides(path, p):
                raise OutputError(f"{path}: is {what}; refusing to overwrite input data")


@contextlib.contextmanager
def open_atomic(path, mode: str = "w", *, force: bool = True, protect=(), encoding: str = "utf-8",
                newline: str | None = "", file_mode: int | None = None):
    """Open a temporary file next to ``path`` for writing; on success rename it over ``path``.

    Parameters
    ----------
    path : str or Path
        Destination. Its folder is created if missing.
    mode : {'w', 'wb'}
    force : bool
        If False, refuse to replace an existing ``path``. A device, pipe or socket is never replaced.
    protect : iterable of paths
        Inputs (and their sidecars) that ``path`` must not be.
    file_mode : int, optional
        Final permission bits (e.g. 0o600 for private caches); default ``0o666 & ~umask``.

    The temporary file has an unpredictable name, is created with ``O_EXCL`` (``mkstemp``, never following a
    symlink), is removed if anything fails, and ends with mode ``0o666 & ~umask``.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"open_atomic mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    _protect(path, protect)
    kind = not_regular(path)
    if kind:
        raise OutputError(f"{path}: is {kind}, not a regular file; refusing to replace it")
    if not force and (path.exists() or path.is_symlink()):
        raise OutputError(f"{path}: exists; pass --force to replace it")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = str(path.with_name(temporary_name(path.name)))
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    except OSError as exc:
        raise write_error(path, exc) from None
    _TEMPORARIES.add(tmp)  # until renamed or removed: remove_temporaries() at a signal
    try:
        os.fchmod(fd, (0o666 & ~current_umask()) if file_mode is None else file_mode)
        if mode == "wb":
            fh = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding=encoding, newline=newline)
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        if not force and (path.exists() or path.is_symlink()):
            raise OutputError(f"{path}: appeared while writing; pass --force to replace it")
        kind = not_regular(path)
        if kind:
            raise OutputError(f"{path}: became {kind} while writing; refusing to replace it")
        os.replace(tmp, path)
    except OSError as exc:  # a full disk, a size limit, an I/O error: one line naming the file
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if exc.errno not in WRITE_ERRNOS:
            raise
        raise write_error(path, exc) from None
    except BaseException:  # cleanup, re-raised
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    finally:
        _TEMPORARIES.discard(tmp)


def temporary_name(name: str) -> str:
    """The name of a temporary file for the output ``name``: ``.NAME.PID.TOKEN.tmp`` (TOKEN 12 hex digits,
    unpredictable), so that a later run can tell whose it is and whether that writer is gone."""
    return f".{name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"


#: why a write failed, for the errors a user can act on
_WRITE_REASONS = {errno.ENOSPC: "no space left on the device (ENOSPC)",
                  errno.EFBIG: "file too large: a file-size limit (ulimit -f) or the file system's (EFBIG)",
                  errno.EDQUOT: "disk quota exceeded (EDQUOT)",
                  errno.EROFS: "read-only file system (EROFS)",
                  errno.EIO: "input/output error of the device (EIO)"}
#: the errors of a write that mean "this file cannot be written here now", not a bug
WRITE_ERRNOS = frozenset(_WRITE_REASONS)


def write_error(path, exc: OSError) -> OutputError:
    """The :class:`OutputError` for an ``OSError`` raised while writing ``path``: the file and the reason."""
    reason = _WRITE_REASONS.get(exc.errno) or (exc.strerror or str(exc))
    return OutputError(f"{path}: cannot be written: {reason}; nothing was written to it (no partial file)")


def atomic_write(path, data, *, force: bool = True, protect=(), file_mode: int | None = None) -> Path:
    """Write ``data`` (str, UTF-8, or bytes) to ``path`` atomically; see :func:`open_atomic`."""
    with open_atomic(path, "wb" if isinstance(data, (bytes, bytearray)) else "w", force=force,
                     protect=protect, file_mode=file_mode) as fh:
        fh.write(data)
    return Path(path)


def save_figure(fig, path, *, protect=(), **kwargs) -> Path:
    """``fig.savefig`` through :func:`open_atomic` (format from the suffix)."""
    path = Path(path)
    with open_atomic(path, "wb", protect=protect) as fh:
        fig.savefig(fh, format=path.suffix.lstrip(".") or "png", **kwargs)
    return path


def is_private_dir(path) -> bool:
    """True if ``path`` is a real folder (not a symlink) owned by this user, not writable by group or others."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return (stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid()
            and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


def _label(option: str, path: Path, k: int) -> str:
    """The name of the k-th file of an output option in messages: the option, or ``--out's sidecar``."""
    if k == 0:
        return option
    return f"{option}'s {'sidecar' if path.suffix.lower() == '.json' else 'companion file'}"


def check_command(files=None, inputs=(), *, force: bool = False, folders=None, create_folders=(),
                  claim: bool = True) -> list:
    """The one output check of a command, before any work: every output against every input and every other
    output, then the outputs claimed for this run.

    Parameters
    ----------
    files : mapping of option -> path or list of paths, optional
        The file outputs (``{"--json": "gap.json", "--out": run_files("sim.csv")}``; None values ignored). The
        first path of a list is the option's own file, the others its companions (a run's sidecar).
    inputs : iterable of str or Path
        Every file the command reads (models, ``--spread`` models, runs, holdouts, mappings, ``--from``); a run
        CSV brings its sidecar.
    force : bool
        Allow replacing existing outputs (never an input).
    folders : mapping of option -> (folder, iterable of file names), optional
        Report folders (``--report DIR``, ``--plot DIR``) and the files each will hold (``design.json``, ...):
        the folder must be a folder (or not exist yet: it is created when written) and each of its files obeys
        the rules of a file output.
    create_folders : iterable of str
        File options whose missing folder is created when written (their value may be inside a report folder);
        any other file option refuses a missing folder, naming it.
    claim : bool
        Claim every output file for this run (:func:`udrobot_files.locks.claim_outputs`).

    Returns
    -------
    list of Path
        Every output file (the files of the folders included).

    Raises
    ------
    OutputError
        Naming the option and the file: an output that is an input (``--force`` never lifts it, and the message
        does not suggest it), two outputs on one file (through another spelling or a link), an existing output
        without ``force``, a device/pipe/socket, a folder where a file is expected (or the reverse), a missing
        or unwritable folder.
    udrobot_files.locks.LockedError
        An output another run claims at the same time (a ValueError too).
    """
    entries = []  # (label, path, option): the report folders' files first, then the file options'
    dirs = []  # (option, folder)
    for option, value in (folders or {}).items():
        if value is None or value[0] is None:
            continue
        folder, names = Path(value[0]), list(value[1])
        dirs.append((option, folder))
        entries += [(option, folder / n, option) for n in names]
    for option, paths in (files or {}).items():
        if paths is None:
            continue
        paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
        entries += [(_label(option, Path(p), k), Path(p), option) for k, p in enumerate(paths) if p is not None]
    ins = [fam for i in inputs if i is not None for fam in _input_family(i)]
    # 1. never an input (before anything else: the message must not suggest --force)
    for label, path, _ in entries:
        for i, what in ins:
            if _collides(path, i):
                raise OutputError(f"{label} {path}: is {what}; refusing to overwrite input data (--force never "
                                  f"does), choose another output")
    for option, folder in dirs:
        for i, what in ins:
            if _collides(folder, i):
                raise OutputError(f"{option} {folder}: is {what}, not a folder for outputs; choose another folder")
    # 2. never two outputs on one file, nor a file output on a report folder
    check_distinct_outputs([(label, [path]) for label, path, _ in entries])
    for option, folder in dirs:
        for label, path, owner in entries:
            if owner != option and (path.resolve() == folder.resolve() or _same_file(path, folder)):
                raise OutputError(f"{label} {path} is the folder of {option}; give each output its own path")
    # 3. each output writable, existing ones only with force
    for option, folder in dirs:
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{option} {folder}: exists and is not a folder")
        _check_folder(folder / "x", option)
    created = set(create_folders) | {option for option, _ in dirs}
    for label, path, option in entries:
        check_outputs([path], force=force, option=label, create_folders=option in created)
    outs = [path for _, path, _ in entries]
    if claim:
        claim_outputs(outs, [label for label, _, _ in entries])
    return outs
