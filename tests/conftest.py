"""Test-session settings shared by every test module.

The default run (``python -m pytest -q``) is spread over the machine's cores by pytest-xdist (``-n auto`` in
``pyproject.toml``). Each xdist worker then runs ``fork_map`` / ``Background`` / ``Helper`` work in its own process
(``UDROBOT_JOBS=1``) instead of forking one worker per core as well: the xdist workers already keep every core busy,
and a second level of workers would only oversubscribe them. The results are the serial loop's either way
(:mod:`udrobot_ctrl.parallel`). Tests that need forked workers set ``UDROBOT_JOBS`` themselves (``test_parallel``,
``test_signals``, ``test_attribute``), which overrides this default. A serial run (``-n 0``) keeps the usual
default (one worker per core).
"""
from __future__ import annotations

import os

if os.environ.get("PYTEST_XDIST_WORKER"):  # set by xdist in its workers before this file is imported
    os.environ.setdefault("UDROBOT_JOBS", "1")
