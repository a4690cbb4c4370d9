"""Messages that name the mistake: a misspelt option, a run log given as the model, identification that found
nothing (issue 42.4 and 40.7)."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.io.runlog import write_run


@pytest.mark.parametrize("argv, wrong, suggestion", [
    (["simulate", "--modle", "bluerov2", "--input", "r.csv"], "--modle", "--model"),
    (["diagnose", "--model", "bluerov2", "--jsn", "r.json", "r.csv"], "--jsn", "--json"),
    (["identify", "spring", "a.csv", "--jsn", "r.json"], "--jsn", "--json"),
    (["model", "show", "--modle", "bluerov2"], "--modle", "--model"),
])
def test_unknown_option_is_named_before_missing_ones(argv, wrong, suggestion, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"unrecognized option {wrong}" in err and suggestion in err
    assert "required" not in err


def test_prefixes_and_negative_values_are_not_unknown(tmp_path, capsys):
    """A unique prefix of a known option (argparse accepts it) and a negative number are not reported."""
    status = main(["simulate", "--mod", "bluerov2", "--input", str(tmp_path / "missing.csv"),
                   "--out", str(tmp_path / "o.csv"), "--max-step", "-1"])
    assert status == 2
    assert "unrecognized" not in capsys.readouterr().err


def test_a_run_log_given_as_model_is_named(tmp_path, capsys):
    run = tmp_path / "dive.csv"
    t = np.arange(5) * 0.1
    write_run(run, t, {"z": np.ones(5)}, "pwm", np.full((5, 6), 1500.0))
    status = main(["simulate", "--model", str(run), "--input", str(run), "--out", str(tmp_path / "o.csv")])
    assert status == 2
    err = capsys.readouterr().err
    assert "this is a run log" in err and "bluerov2" in err


def test_identify_writes_no_coefficient_set_when_every_file_failed(tmp_path, capsys):
    out = tmp_path / "set.toml"
    status = main(["identify", "cfd", str(tmp_path / "missing.csv"), "--out", str(out)])
    assert status == 1
    assert not out.exists()
    assert "not written" in capsys.readouterr().err
