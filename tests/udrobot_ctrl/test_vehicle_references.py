"""Issue 62: a file a model names (its thruster curve) is read only from the package or next to the model, only
a regular file of bounded size; anything else is refused in one line naming the model and the field."""
from __future__ import annotations

import os
import re
import shutil
from importlib import resources

import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.vehicle import load_model

SHIPPED = resources.files("udrobot_ctrl.models")


def _scaled_curve(path, factor):
    """The shipped T200 curve with every thrust coefficient times ``factor`` (a curve that changes the limits)."""
    text = (SHIPPED / "t200.toml").read_text()

    def scale(match):
        return "coeffs = [" + ", ".join(repr(float(v) * factor) for v in match.group(1).split(",")
                                      if v.strip()) + "]"

    path.write_text(re.sub(r"coeffs = \[([^\]]*)\]", scale, text))
    return path


def _model_naming(folder, name):
    """The shipped BlueROV2 description, in ``folder``, whose thruster curve is ``name``."""
    folder.mkdir(parents=True, exist_ok=True)
    text = (SHIPPED / "bluerov2.toml").read_text()
    assert '[thruster_model]\nname = "t200"' in text
    path = folder / "rov.toml"
    path.write_text(text.replace('[thruster_model]\nname = "t200"', f"[thruster_model]\nname = {name!r}"))
    return path


def _refused(model, capsys, *words):
    capsys.readouterr()
    assert main(["model", "show", "--model", str(model)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for w in (str(model), "thruster_model.name", *words):
        assert w in err, err
    return err


def test_a_curve_next_to_the_model_is_used_and_the_shipped_name_still_works(tmp_path):
    nominal = load_model("bluerov2").thrusters[0].max_forward_N
    (tmp_path / "m").mkdir()
    _scaled_curve(tmp_path / "m" / "strong.toml", 2.0)
    strong = load_model(str(_model_naming(tmp_path / "m", "strong")))
    assert strong.thrusters[0].max_forward_N == pytest.approx(2.0 * nominal, rel=1e-9)
    assert strong.extras["thruster_model"] == os.path.realpath(tmp_path / "m" / "strong.toml")
    assert load_model(str(_model_naming(tmp_path / "n", "t200"))).thrusters[0].max_forward_N == nominal


@pytest.mark.parametrize("how", ["dotdot", "absolute", "working_folder", "link_out"])
def test_a_curve_from_elsewhere_is_refused(tmp_path, capsys, monkeypatch, how):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    evil = _scaled_curve(elsewhere / "evil.toml", 100.0)  # limits 47 -> 4721 N
    folder = tmp_path / "a" / "b" / "c"
    if how == "dotdot":
        model = _model_naming(folder, "../../../elsewhere/evil")
    elif how == "absolute":
        model = _model_naming(folder, str(evil))
    elif how == "working_folder":
        monkeypatch.chdir(elsewhere)  # evil.toml in the working folder, not next to the model
        model = _model_naming(folder, "evil")
    else:
        folder.mkdir(parents=True)
        (folder / "evil.toml").symlink_to(evil)
        model = _model_naming(folder, "evil")
    err = _refused(model, capsys)
    assert ("neither a shipped curve" in err) if how == "working_folder" else ("outside" in err), err


@pytest.mark.parametrize("node", ["fifo", "dev_zero", "huge", "folder"])
def test_a_curve_that_is_not_a_small_regular_file_is_refused_at_once(tmp_path, capsys, node):
    folder = tmp_path / "m"
    folder.mkdir()
    target = folder / "c.toml"
    if node == "fifo":
        os.mkfifo(target)  # opening it for reading would block for ever
    elif node == "dev_zero":
        target.symlink_to("/dev/zero")  # outside the folders too; refused either way, never read
    elif node == "huge":
        shutil.copyfile(SHIPPED / "t200.toml", target)
        with open(target, "ab") as fh:
            fh.write(b"#" * (1 << 20))
    else:
        target.mkdir()
    err = _refused(_model_naming(folder, "c"), capsys)
    expected = {"fifo": "named pipe", "dev_zero": "outside", "huge": "bytes, more than", "folder": "a folder"}[node]
    assert expected in err, err


@pytest.mark.parametrize("suffix", [".json", ".toml"])
def test_a_model_file_that_is_a_pipe_is_refused_at_once(tmp_path, capsys, suffix):
    model = tmp_path / f"m{suffix}"
    os.mkfifo(model)  # reading it would block for ever
    capsys.readouterr()
    assert main(["model", "show", "--model", str(model)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(model) in err and "named pipe" in err, err
