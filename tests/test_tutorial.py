"""docs/tutorial.md shows what its commands print now (issue 42: a tutorial whose figures cannot go stale).

The outputs in the tutorial are written by ``docs/tutorial_run.py`` between ``<!-- tutorial-output: KEY -->``
markers. The slow test reruns the commands in a temporary folder and compares every block: run times masked,
numbers to one unit in their last printed digit (the commands are deterministic; see the script's docstring),
text exactly. It checks the groups in ``tutorial_run.FAST_GROUPS`` (the Tartan AUV walk-through and the sea dive,
about 2-3 min on 2 shared cores); the ``design ardusub`` steps and ``examples/diagnose_tartan.py`` take another
5-7 min and are checked with ``UDROBOT_TUTORIAL_FULL=1`` or ``python docs/tutorial_run.py --check``.
It skips when the shared data (``../shared/data``, not shipped with the repository) are absent.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
_spec = importlib.util.spec_from_file_location("tutorial_run", ROOT / "docs" / "tutorial_run.py")
tutorial_run = sys.modules.setdefault("tutorial_run", importlib.util.module_from_spec(_spec))
_spec.loader.exec_module(tutorial_run)  # registered first: its dataclass looks its module up


def test_every_block_has_a_step_and_every_step_a_block():
    text = TUTORIAL.read_text(encoding="utf-8")
    assert set(tutorial_run.blocks(text)) == {step.key for step in tutorial_run.STEPS}
    files = tutorial_run.tutorial_files(text)
    for step in tutorial_run.STEPS:  # a script the tutorial runs is printed in the tutorial
        for cmd in step.commands:
            if cmd.startswith("python ") and cmd.split()[1].endswith(".py") and step.cwd == "work":
                assert cmd.split()[1] in files, cmd
    assert {"add_thrusters.py", "drop_lag.py"} <= set(files)


def test_comparison_masks_run_times_and_allows_one_unit_in_the_last_digit():
    diff = tutorial_run.differences
    assert diff("gap 8.032 (7.6 s)\nin 6.1 s", "gap 8.033 (19.0 s)\nin 12.4 s") == []
    assert diff("Diagnosis took 49.4 s.", "Diagnosis took 51.2 s.") == []
    assert diff("shrink +0.66 dBIC -945", "shrink +0.67 dBIC -944") == []
    assert diff("gap 8.032", "gap 8.034")  # two units: stale
    assert diff("dBIC -945", "dBIC -947")
    assert diff("cg_cb_offset SIGNIFICANT", "cg_cb_offset AT BOUND")  # text: exactly
    assert diff("a\nb", "a\nb\nc")  # a new line


def test_excerpts_mark_what_they_leave_out():
    step = tutorial_run.Step("k", "tartan", ["x"], drop=r"^wrote ")
    lines = ["a", "wrote 1", "wrote 2", "wrote 3", "b"]
    assert tutorial_run.excerpt(lines, step) == ["a", "wrote 1", "...", "wrote 3", "b"]
    step = tutorial_run.Step("k", "tartan", ["x"], keep=r"^gap")
    assert tutorial_run.excerpt(["x", "gap 1", "y", "z", "gap 2"], step) == ["...", "gap 1", "...", "gap 2"]
    assert tutorial_run._terminal("a\rprogress 50%\rdone\nb\r\n") == ["done", "b", ""]


@pytest.mark.slow
def test_tutorial_outputs_are_what_the_commands_print_now(tmp_path):
    full = os.environ.get("UDROBOT_TUTORIAL_FULL") == "1"
    groups = tutorial_run.with_needs(tutorial_run.GROUPS if full else tutorial_run.FAST_GROUPS)
    missing = tutorial_run.data_ok(tutorial_run.DATA, groups)
    if missing:
        pytest.skip(f"{missing}: the tutorial's commands run on the shared data beside the repository "
                    f"(../shared/data, read-only, not shipped)")
    text = TUTORIAL.read_text(encoding="utf-8")
    new = tutorial_run.run_steps(groups, tmp_path, tutorial_run.DATA.resolve(), text, log=lambda line: None)
    assert {s.key for s in tutorial_run.STEPS if s.group in groups} == set(new)
    failed = [k for k, body in new.items() if "(exit status " in body]
    assert not failed, f"tutorial commands failed: {failed}"
    old = tutorial_run.blocks(text)
    stale = {k: tutorial_run.differences(old[k], body) for k, body in new.items()}
    stale = {k: d for k, d in stale.items() if d}
    assert not stale, ("docs/tutorial.md is stale; regenerate it with `python docs/tutorial_run.py`:\n"
                       + "\n".join(f"{k}:\n" + "\n".join(d[:5]) for k, d in stale.items()))
