"""Private on-disk caches of compiled code, defined in :mod:`udrobot_files.caches`.

Re-exported here under its historical path; the definition lives in the neutral package so that
``identification`` (whose numba kernels need the same private cache) does not import ``udrobot_ctrl``.
"""
from udrobot_files.caches import configure_numba_cache, path_unsafe_reason, private_dir, unsafe_reason, user_cache_root

__all__ = ["configure_numba_cache", "path_unsafe_reason", "private_dir", "unsafe_reason", "user_cache_root"]
