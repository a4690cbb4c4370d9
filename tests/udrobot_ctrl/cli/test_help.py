"""The command line explains itself: every command has a description, every option a help text, ``--version``
works, argument order is free where users expect it, only expected errors lose their traceback, and a closed
pipe ends quietly."""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl import __version__
from udrobot_ctrl.cli.main import COMMANDS, build_parser, main
from udrobot_ctrl.gap.plots import file_label
from udrobot_ctrl.gap.report import split_runs
from udrobot_ctrl.io.runlog import Run

ROOT = Path(__file__).resolve().parents[3]
cli_main = sys.modules["udrobot_ctrl.cli.main"]


def _subparsers(parser):
    """name -> sub-parser, recursively (``model export`` and ``model show`` included)."""
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[name] = sub
                out.update({f"{name} {k}": v for k, v in _subparsers(sub).items()})
    return out


PARSERS = _subparsers(build_parser())


def test_every_command_is_registered():
    assert set(COMMANDS) <= set(PARSERS)
    assert {"model export", "model show"} <= set(PARSERS)


@pytest.mark.parametrize("name", sorted(PARSERS))
def test_every_command_has_a_description_and_every_option_help(name):
    parser = PARSERS[name]
    assert parser.description and len(parser.description.split()) >= 8, f"{name}: no description"
    missing = [a.dest for a in parser._actions
               if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and not (a.help or "").strip()]
    assert not missing, f"udrobot-ctrl {name}: options without help: {missing}"


@pytest.mark.parametrize("name", sorted(PARSERS))
def test_help_runs_and_exits_zero(name, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*name.split(), "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: udrobot-ctrl " + name)


def test_top_level_help_is_for_users(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for name in COMMANDS:  # every command named with what it is for
        assert f"\n  {name} " in text, name
    assert "example" in text and "udrobot-ctrl demo --out" in text


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"udrobot-ctrl {__version__}"


@pytest.mark.parametrize("argv", [
    ["--model", "M", "--json", "R.json", "--holdout", "h.csv", "fit.csv"],
    ["--model", "M", "--json", "R.json", "fit.csv", "--holdout", "h.csv"],
    ["fit.csv", "--model", "M", "--holdout", "h.csv", "--json", "R.json"],
])
def test_diagnose_holdout_before_or_after_the_runs(argv):
    args = build_parser("diagnose").parse_args(["diagnose", *argv])
    assert args.runs == ["fit.csv"] and args.holdout == ["h.csv"]


def test_diagnose_several_holdouts_repeat_the_option():
    args = build_parser("diagnose").parse_args(["diagnose", "--model", "M", "--json", "R", "--holdout", "a.csv",
                                                "--holdout", "b.csv", "f1.csv", "f2.csv"])
    assert args.holdout == ["a.csv", "b.csv"] and args.runs == ["f1.csv", "f2.csv"]


def test_single_run_split_has_distinct_file_safe_names():
    t = np.linspace(0.0, 30.0, 301)
    run = Run(path="/data/pool.csv", t=t, channels={"z": np.ones_like(t)}, input_kind="thrust",
              inputs=np.zeros((t.size, 2)), extra={}, metadata={})
    fit, hold, _note = split_runs([run], None)
    names = [Path(fit[0].path).name, Path(hold[0].path).name]
    labels = [file_label(n) for n in names]
    assert len(set(names)) == 2 and len(set(labels)) == 2, (names, labels)
    assert all(lab.startswith("pool_") and "/" not in lab and " " not in lab for lab in labels), labels
    assert fit[0].t[-1] < hold[0].t[0]  # the holdout part follows the fit part, no overlap


def _fail_with(monkeypatch, exc):
    """Register a fake command ``model`` whose run raises ``exc``."""
    def fake_register(sub):
        p = sub.add_parser("model", help="x", description="a fake command that fails for the test")
        p.set_defaults(func=lambda args: (_ for _ in ()).throw(exc))
    fake = types.ModuleType("udrobot_test_fake_command")
    fake.register = fake_register
    monkeypatch.setitem(sys.modules, fake.__name__, fake)
    monkeypatch.setitem(cli_main.COMMANDS, "model", fake.__name__)


def test_expected_error_is_one_line(monkeypatch, capsys):
    _fail_with(monkeypatch, ValueError("run.csv, data row 3, column 'z': 'abc' is not a number"))
    assert main(["model"]) == 2
    err = capsys.readouterr().err
    assert err == "udrobot-ctrl model: error: run.csv, data row 3, column 'z': 'abc' is not a number\n"


def test_a_bug_keeps_its_traceback(monkeypatch):
    _fail_with(monkeypatch, KeyError("selected"))
    with pytest.raises(KeyError, match="selected"):
        main(["model"])


@pytest.mark.slow
@pytest.mark.parametrize("argv", [["--help"], ["model", "show", "--model", "pendulum:chin"]])
def test_closed_pipe_ends_quietly(argv):
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "udrobot_ctrl.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=ROOT, env=env)
    proc.stdout.close()  # the reader goes away before the command writes (like `| head -0`)
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode in (0, 1)
