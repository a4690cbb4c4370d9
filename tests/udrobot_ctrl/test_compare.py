"""udrobot-ctrl compare: every (design, plant, controller) pair, and controllers that settle."""
import json

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.compare import compare

MODELS = ("cfd:chin", "free_decay:morison")


@pytest.fixture(scope="module")
def result():
    return compare(MODELS, ("lqr", "pid", "lmpc"), t_final=20.0, keep_trajectories=True)


def test_every_pair_for_every_controller(result):
    got = {(r["design"], r["plant"], r["controller"]) for r in result["results"]}
    want = {(a, b, c) for a in MODELS for b in MODELS for c in ("lqr", "pid", "lmpc")}
    assert got == want
    assert set(result["skipped"]) == {"nmpc", "ekf"}


@pytest.mark.parametrize("kind,designs", [("lqr", MODELS), ("lmpc", MODELS), ("pid", MODELS[:1])])
def test_matched_design_settles_depth_and_heading(result, kind, designs):
    # The decoupled PID ignores the heave-pitch coupling; on free_decay:morison (Z_wdot > X_udot, the Munk
    # moment removes ~58 % of the pitch stiffness at 0.5 m/s) its depth loop does not settle: a finding
    # reported by compare, not asserted away here.
    for design in designs:
        res = result["trajectories"][(kind, design)]
        j = MODELS.index(design)
        z, psi = res.x[:, j, 2], res.x[:, j, 5]
        last = res.t > res.t[-1] - 3.0
        assert np.all(np.abs(z[last] - 1.0) < 0.05), (kind, design)
        assert np.all(np.abs(psi[last] - np.pi / 2) < np.radians(3)), (kind, design)
        # applied thrust always within each thruster's asymmetric limits
        assert np.all(res.tau[..., 0] <= 2 * 36.42 + 1e-6) and np.all(res.tau[..., 0] >= -2 * 28.61 - 1e-6)


def test_mismatched_drag_shows_as_speed_error_without_integral_action(result):
    rows = {(r["design"], r["plant"], r["controller"]): r for r in result["results"]}
    # free-decay surge drag is lower than CFD's: an LQR designed on CFD drives the free-decay plant faster
    assert rows[("cfd:chin", "free_decay:morison", "lqr")]["speed_error"] > 0.01
    assert abs(rows[("cfd:chin", "cfd:chin", "lqr")]["speed_error"]) < 0.01
    # PID's integral action removes it
    assert abs(rows[("cfd:chin", "free_decay:morison", "pid")]["speed_error"]) < 0.01


def test_cli_writes_json_and_tables(tmp_path):
    js = tmp_path / "r.json"
    rc = main(["compare", "--quick", "--models", "cfd:chin", "--controllers", "lqr", "--json", str(js),
               "--out", str(tmp_path / "o")])
    assert rc == 0
    doc = json.loads(js.read_text())
    assert doc["models"] == ["cfd:chin"] and len(doc["results"]) == 1
    assert {"design", "plant", "controller", "iae", "overshoot", "settling_s", "energy_J", "saturation_s"} <= set(
        doc["results"][0])
    assert (tmp_path / "o" / "compare.csv").exists() and (tmp_path / "o" / "compare_iae_lqr.png").exists()


def test_cli_rejects_unknown_controller(capsys):
    assert main(["compare", "--controllers", "nmpc"]) == 2
    assert "not implemented" in capsys.readouterr().err
