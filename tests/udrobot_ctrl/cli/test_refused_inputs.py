"""Refused before any work, in one line (issue 40, items 3 and 7): a holdout that is the fit run, two outputs that
are one file, and input files nested too deeply to parse."""
from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.io.runlog import write_run


@pytest.fixture
def run(tmp_path):
    t = np.arange(0.0, 10.0, 0.05)
    states = {c: np.zeros_like(t) for c in STATE_NAMES}
    states["z"] = 1.0 + 0.01 * t
    return write_run(tmp_path / "run.csv", t, states, "thrust", np.ones((t.size, 4)))


def _refused(argv, capsys, *words):
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("how", ["same", "dotted", "symlink", "hardlink", "copy"])
def test_a_holdout_that_is_the_fit_run_is_refused_naming_both(run, tmp_path, capsys, how):
    other = {"same": run, "dotted": tmp_path / "." / "run.csv"}.get(how, tmp_path / f"{how}.csv")
    if how == "symlink":
        other.symlink_to(run)
    elif how == "hardlink":
        os.link(run, other)
    elif how == "copy":
        shutil.copy(run, other)
    what = "is a copy (identical content) of" if how == "copy" else "is the same file as"
    _refused(["diagnose", "--model", "pendulum:chin", "--json", tmp_path / "r.json", run, "--holdout", other], capsys,
             f"holdout run {other} {what} the fit run {run}")
    assert not (tmp_path / "r.json").exists()


def test_without_holdout_the_last_run_may_not_repeat_a_fit_run(run, tmp_path, capsys):
    shutil.copy(run, tmp_path / "again.csv")
    _refused(["diagnose", "--model", "pendulum:chin", "--json", tmp_path / "r.json", run, tmp_path / "again.csv"],
             capsys, "holdout run", "again.csv", "is a copy")


def test_a_different_holdout_is_accepted_by_the_check(run, tmp_path):
    from udrobot_ctrl.cli.diagnose import check_holdout_not_fit

    other = tmp_path / "other.csv"
    other.write_bytes(run.read_bytes().replace(b"1.0", b"1.5", 1))
    check_holdout_not_fit([run], [other])


@pytest.mark.parametrize("argv, words", [
    (["diagnose", "--model", "pendulum:chin", "--json", "{d}/x.json", "--out-model", "{d}/./x.json", "{run}"],
     "--json and --out-model name the same file"),
    (["simulate", "--windows", "--model", "pendulum:chin", "--input", "{run}", "--json", "{d}/s.csv", "--out",
      "{d}/s.csv"], "--json and --out name the same file"),
    (["simulate", "--windows", "--model", "pendulum:chin", "--input", "{run}", "--json", "{d}/s.json", "--out",
      "{d}/s.csv"], "--json and --out's sidecar name the same file"),
    (["compare", "--models", "pendulum:chin", "--controllers", "pid", "--quick", "--out", "{d}/cmp", "--json",
      "{d}/cmp/compare_full.json"], "--out and --json name the same file"),
])
@pytest.mark.parametrize("force", [False, True])
def test_two_outputs_naming_one_file_are_refused(run, tmp_path, capsys, argv, words, force):
    argv = [a.format(d=tmp_path, run=run) for a in argv] + (["--force"] if force else [])
    _refused(argv, capsys, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


DEEP = "[" * 100_000 + "]" * 100_000


def test_deeply_nested_inputs_are_one_line_errors_naming_the_file(run, tmp_path, capsys):
    model = tmp_path / "deep.json"
    model.write_text(DEEP)
    _refused(["model", "show", "--model", model], capsys, f"{model}: JSON nested too deeply")
    toml = tmp_path / "deep.toml"
    toml.write_text("a = " + DEEP + "\n")
    _refused(["model", "show", "--model", toml], capsys, f"{toml}: TOML nested too deeply")
    _refused(["convert", run, "--mapping", toml, "--out", tmp_path / "o.csv"], capsys, "TOML nested too deeply",
             str(toml))
    run.with_suffix(".json").write_text('{"a":' * 50_000 + "1" + "}" * 50_000)
    _refused(["simulate", "--model", "pendulum:chin", "--input", run, "--out", tmp_path / "o.csv"], capsys,
             f"{run.with_suffix('.json')}: JSON nested too deeply")
    _refused(["sensitivity", "--ranges", toml, "--workers", "1"], capsys, f"{toml}: TOML nested too deeply")


@pytest.mark.parametrize("argv, words", [
    (["identify", "spring", "{run}", "--json", "{d}/x.toml", "--out", "{d}/x.toml"], "--json and --out name"),
    (["convert", "{run}", "--out", "{d}/o.csv", "--segment-dir", "{d}/o.csv"], "--out and --segment-dir name"),
    (["convert", "{run}", "--out", "{d}/o.csv", "--segment-dir", "{d}/o.json"], "--out's sidecar and --segment-dir"),
    (["compare", "--out", "{d}/c", "--json", "{d}/c"], "--json and --out name"),
])
def test_every_command_refuses_two_options_naming_one_file(run, tmp_path, capsys, argv, words):
    """The check in udrobot_ctrl.cli.main, before any command starts (the commands' own checks come after)."""
    _refused([a.format(d=tmp_path, run=run) for a in argv], capsys, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


@pytest.mark.parametrize("digit", ["٣", "３"])
def test_a_non_ascii_digit_in_a_model_file_is_never_a_number(tmp_path, capsys, digit):
    """JSON and TOML parsers read only 0-9 as digits, and a string is not a number: the file and the place are
    named."""
    assert main(["model", "export", "--model", "pendulum:chin", "--out", str(tmp_path / "m.json")]) == 0
    text = (tmp_path / "m.json").read_text()
    assert '"mass": 9.36' in text
    bare = tmp_path / "bare.json"
    bare.write_text(text.replace('"mass": 9.36', f'"mass": {digit}.36'), encoding="utf-8")
    _refused(["model", "show", "--model", bare], capsys, f"{bare}: not a model file: not valid JSON (line")
    quoted = tmp_path / "quoted.json"
    quoted.write_text(text.replace('"mass": 9.36', f'"mass": "{digit}.36"'), encoding="utf-8")
    _refused(["model", "show", "--model", quoted], capsys, f"{quoted}: field 'mass' must be a number")
