"""The output-file policy of every writer (docs/files.md), defined in :mod:`udrobot_files.output`.

Re-exported here under its historical path for the ``udrobot_ctrl`` modules and users that import it from
``udrobot_ctrl.io``; the definition lives in the neutral package so that ``identification`` can write files
by the same rules without importing ``udrobot_ctrl``.
"""
from udrobot_files.output import (
    OutputError,
    atomic_write,
    check_command,
    check_distinct_outputs,
    check_output_dir,
    check_outputs,
    current_umask,
    is_private_dir,
    not_regular,
    open_atomic,
    run_files,
    save_figure,
    sidecar,
    spec_files,
)

__all__ = ["OutputError", "atomic_write", "check_command", "check_distinct_outputs", "check_output_dir",
           "check_outputs", "current_umask", "is_private_dir", "not_regular", "open_atomic", "run_files",
           "save_figure", "sidecar", "spec_files"]
