"""Issue 62: a diagnosis refuses, before any work, a holdout that repeats fit data (shifted in time, written
again, or a stretch of a fit run) and runs whose sidecar names another vehicle than --model."""
from __future__ import annotations

import numpy as np
import pytest

from tests.udrobot_ctrl.cli.test_output_policy import _snapshot
from udrobot_ctrl.cli import main
from udrobot_ctrl.cli.diagnose import check_run_vehicles
from udrobot_ctrl.io.overlap import MIN_REPEATED_ROWS, check_unseen, repeated_stretch
from udrobot_ctrl.io.runlog import read_run, write_run

RATE = 20.0  # Hz


def _measured(seed, n=600, t0=0.0):
    """(t, channels, thrust) of a pool run: slow motions plus sensor noise (each seed its own noise)."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / RATE
    s = t - t0
    channels = {"z": 0.5 + 0.1 * np.sin(0.3 * s) + 0.002 * rng.standard_normal(n),
                "u": 0.05 * np.cos(0.2 * s) + 0.003 * rng.standard_normal(n),
                "psi": 0.2 * np.sin(0.1 * s) + 0.001 * rng.standard_normal(n)}
    thrust = np.column_stack([2.0 + 0.5 * np.sin(0.3 * s + k) for k in range(4)])
    return t, channels, thrust


def _write(path, t, channels, thrust, vehicle=None):
    return write_run(path, t, channels, "thrust", thrust, metadata={"vehicle": vehicle} if vehicle else None)


def _rewritten(src, dst, shift=0.0):
    """``src`` written again with 6 significant digits (``%g``) and its clock shifted by ``shift`` s."""
    run = read_run(src)
    cols = {"t": run.t + shift, **run.channels, **{f"thrust_{k + 1}": run.inputs[:, k] for k in range(4)}}
    lines = [",".join(cols)] + [",".join(f"{v[i]:g}" for v in cols.values()) for i in range(run.t.size)]
    dst.write_text("\n".join(lines) + "\n")
    return dst


def _stretch(src, dst, start, stop, shift=0.0):
    run = read_run(src)
    return write_run(dst, run.t[start:stop] + shift, {c: v[start:stop] for c, v in run.channels.items()}, "thrust",
                     run.inputs[start:stop])


@pytest.fixture
def fit(tmp_path):
    return _write(tmp_path / "fit.csv", *_measured(1))


@pytest.mark.parametrize("how", ["shifted_1000s", "rewritten", "own_last_20s", "overlapping"])
def test_a_holdout_repeating_fit_data_is_refused_before_any_work(tmp_path, capsys, fit, how):
    hold = tmp_path / "hold.csv"
    if how == "shifted_1000s":
        _stretch(fit, hold, 0, None, shift=1000.0)
    elif how == "rewritten":
        _rewritten(fit, hold, shift=0.5)
    elif how == "own_last_20s":
        _stretch(fit, hold, -int(20 * RATE), None)
    else:  # its last 100 rows are the fit run's first 100, then new data
        t, ch, thr = _measured(2, n=300, t0=-300 / RATE + 100 / RATE)
        run = read_run(fit)
        for c in ch:
            ch[c][-100:] = run.channels[c][:100]
        thr[-100:] = run.inputs[:100]
        _write(hold, t + 50.0, ch, thr)
    capsys.readouterr()
    before = _snapshot(tmp_path)
    assert main(["diagnose", "--model", "cfd:chin", "--json", str(tmp_path / "gap.json"), "--holdout", str(hold),
                 str(fit)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"holdout run {hold}" in err and f"repeat the fit run {fit}" in err, err
    assert "every row of it" in err if how != "overlapping" else "data rows 201..300" in err, err
    assert _snapshot(tmp_path) == before


def test_independent_runs_and_runs_alike_only_at_rest_are_not_repeats(tmp_path, fit):
    other = read_run(_write(tmp_path / "other.csv", *_measured(2)))
    check_unseen([read_run(fit)], ["fit.csv"], [other], ["other.csv"])  # no error
    # two runs started alike at rest (identical rows, nothing changing) then moving differently
    rest = 3 * MIN_REPEATED_ROWS
    a_t, a, a_u = _measured(3)
    b_t, b, b_u = _measured(4)
    for c in a:
        a[c][:rest] = b[c][:rest] = 0.5
    a_u[:rest] = b_u[:rest] = 0.0
    ra = read_run(_write(tmp_path / "a.csv", a_t, a, a_u))
    rb = read_run(_write(tmp_path / "b.csv", b_t, b, b_u))
    assert repeated_stretch(ra, rb) is None
    # the control: the moving part of a shared with b is found, whatever the shift
    for c in b:
        b[c][200:260] = a[c][400:460]
    b_u[200:260] = a_u[400:460]
    found = repeated_stretch(ra, read_run(_write(tmp_path / "c.csv", b_t + 7.0, b, b_u)))
    assert found is not None and (found.rows, found.start_a, found.start_b) == (60, 400, 200)


@pytest.mark.parametrize("vehicle, model, refused", [("bluerov2-heavy", "cfd:chin", True),
                                                      ("bluerov2", "bluerov2-heavy", True),
                                                      ("udrobot", "cfd:chin", False),
                                                      ("bluerov2-heavy", "bluerov2-heavy", False),
                                                      ("tartan-auv", "cfd:chin", False)])  # unknown: not compared
def test_a_run_of_another_vehicle_is_refused(tmp_path, capsys, vehicle, model, refused):
    run = _write(tmp_path / "run.csv", *_measured(5), vehicle=vehicle)
    if not refused:
        check_run_vehicles(model, [read_run(run)], [str(run)])
        return
    capsys.readouterr()
    before = _snapshot(tmp_path)
    assert main(["diagnose", "--model", model, "--json", str(tmp_path / "gap.json"), str(run)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and f"run {run}" in err and repr(vehicle) in err, err
    assert _snapshot(tmp_path) == before
