"""Closed-loop LQR mission evaluator: physics of the sensitivities and the CLI end to end."""
import json

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator
from udrobot_ctrl.sensitivity.executor import SweepExecutor
from udrobot_ctrl.sensitivity.local import local_sensitivity
from udrobot_ctrl.sensitivity.mission import DepthHeadingMission
from udrobot_ctrl.sensitivity.parameters import default_space

SHORT = DepthHeadingMission(t_final=12.0, dt=0.04)


def test_lqr_mission_settles_on_the_nominal_model_and_batches_are_independent():
    space = default_space("pendulum:chin")
    ev = MissionEvaluator(space, "lqr", mission=SHORT)
    rng = np.random.default_rng(1)
    lo, hi = space.bounds.T
    X = np.vstack([space.nominal, lo + rng.random((3, len(space))) * (hi - lo)])
    out = ev(X)
    assert out["error"] == [""] * 4
    assert out["settling_depth"][0] < SHORT.t_final and out["settling_heading"][0] < 5.0
    assert abs(out["speed_error"][0]) < 5e-3  # trim feed-forward from the same model: no speed error
    assert out["lost_control"][0] == 0 and out["max_pitch"][0] < 30
    # a sample evaluated alone gives the same metrics as inside the batch
    alone = ev(X[2:3])
    for m in ("iae_depth", "energy", "settling_depth"):
        assert alone[m][0] == pytest.approx(out[m][2], rel=1e-12)


def test_wrong_surge_drag_slows_the_cruise_unless_redesigned():
    space = default_space("cfd:morison").subset(["surge.CD"])
    X = np.array([[1.4015], [1.7021], [2.3432]])  # free decay, CFD, pendulum (Cely 2019)
    nominal_design = MissionEvaluator(space, "lqr", mission=SHORT)(X)
    redesigned = MissionEvaluator(space, "lqr", mission=SHORT, redesign=True)(X)
    se = nominal_design["speed_error"]
    assert se[0] > 0.01 and se[2] < -0.02  # less drag: faster; more drag: slower (no integral action)
    assert np.all(np.abs(redesigned["speed_error"]) < 5e-3)
    # holding the speed against more drag costs energy: monotone in C_D
    assert np.all(np.diff(redesigned["energy"]) > 0)


def test_pid_integral_action_removes_the_speed_error_a_wrong_drag_causes():
    space = default_space("cfd:morison").subset(["surge.CD"])
    X = np.array([[1.4015], [2.3432]])
    lqr = MissionEvaluator(space, "lqr", mission=SHORT)(X)
    pid = MissionEvaluator(space, "pid", mission=SHORT)(X)
    assert pid["error"] == ["", ""]
    assert np.all(np.abs(pid["speed_error"]) < 0.3 * np.abs(lqr["speed_error"]))
    assert pid["energy"][1] > pid["energy"][0]  # same speed against more drag costs more energy
    with pytest.raises(ValueError, match="batch backend supports lqr, pid"):
        MissionEvaluator(space, "nmpc", backend="batch")


def test_local_sensitivity_of_the_mission_is_physical():
    space = default_space("cfd:morison", rotational=False).subset(["surge.CD", "sway.CD", "heave.added_mass"])
    res = local_sensitivity(MissionEvaluator(space, "lqr", mission=SHORT), space,
                            executor=SweepExecutor(workers=1), progress=False)
    j = res.names.index("surge.CD")
    assert res.derivative["speed_error"][j] < 0 and res.reliable("speed_error")[j]
    assert res.derivative["energy"][j] > 0
    assert res.ranking("speed_error")[0] == "surge.CD"
    assert np.isnan(res.elasticity["speed_error"]).all()  # ~0 at nominal: elasticity undefined


def test_cli_morris_writes_tables_and_resume_runs_nothing_new(tmp_path, capsys):
    out = tmp_path / "study"
    argv = ["sensitivity", "--method", "morris", "--samples", "2", "--params", "surge.CD,heave.added_mass",
            "--workers", "1", "--out", str(out), "--duration", "4", "--quiet"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "6 closed-loop runs" in text and "surge.CD" in text
    first = (out / "results.csv").read_text()
    chunks = sorted(p.name for p in (out / "chunks").iterdir())
    assert main(argv) == 2  # existing study, no --resume: refused, nothing overwritten
    assert "--resume" in capsys.readouterr().err
    assert main(argv + ["--resume"]) == 0
    assert sorted(p.name for p in (out / "chunks").iterdir()) == chunks
    assert (out / "results.csv").read_text() == first
    assert json.loads((out / "study.json").read_text())["method"] == "morris"
    assert main(["sensitivity", "--range", "surge.CD=2:1", "--workers", "1"]) == 2


def test_missions_backend_runs_the_toolbox_linear_mpc_per_sample():
    missions = pytest.importorskip("udrobot_ctrl.control.missions")
    pytest.importorskip("udrobot_ctrl.control.mpc")
    short = missions.Mission("sens-test", 6.0, initial={"z": 0.5, "psi": 0.0, "u": 0.0},
                             steps=(missions.ReferenceStep("u", 0.5, 0.5), missions.ReferenceStep("z", 3.0, 1.0)))
    space = default_space("cfd:morison").subset(["surge.CD"])
    X = np.array([[1.4015], [2.3432]])
    ev = MissionEvaluator(space, "lmpc", mission=short, backend="missions", sim_dt=0.05, control_dt=0.1)
    out = ev(X)
    assert out["error"] == ["", ""], out["error"]
    assert {"iae", "iae_u", "energy_J", "max_speed", "settling_z_s", "fallbacks"} <= set(out)
    assert np.all(out["fallbacks"] == 0)
    assert out["energy_J"][1] > out["energy_J"][0]  # more drag, more thrust for the same transit
    assert out["max_speed"][1] < out["max_speed"][0]
    np.testing.assert_allclose(ev(X[:1])["iae"], out["iae"][:1], rtol=1e-9)  # reset between samples


def test_batched_mpc_solves_its_qp_and_respects_thrust_limits():
    from scipy.optimize import lsq_linear

    from udrobot_ctrl.sensitivity.batch import batch_plant
    from udrobot_ctrl.sensitivity.mission import CONTROLLED, BatchMPC, MPCSettings, mpc_matrices

    space = default_space("cfd:morison")
    s = MPCSettings()
    qp = mpc_matrices(space.vehicle, SHORT, s)
    bp = batch_plant([space.vehicle])
    ctrl = BatchMPC(qp, SHORT, bp.f_min, bp.f_max, s)
    x0 = SHORT.x0()[None]
    f = ctrl(0.0, x0)[0]  # the 1 m / 90 deg step saturates the vertical thrusters
    e = x0[:, list(CONTROLLED)] - ctrl.ref
    g = (e @ qp["F"])[0]
    L = np.linalg.cholesky(qp["H"])
    lo = np.tile(bp.f_min - qp["trim"], s.horizon)
    hi = np.tile(bp.f_max - qp["trim"], s.horizon)
    exact = lsq_linear(L.T, -np.linalg.solve(L, g), bounds=(lo, hi), tol=1e-12).x[:4] + qp["trim"]
    assert np.any(np.isclose(exact, bp.f_max))  # a limit is active
    np.testing.assert_allclose(f, exact, atol=0.2)  # N; FISTA on an ill-conditioned QP: near-optimal
    out = MissionEvaluator(space.subset(["surge.CD"]), "mpc", mission=SHORT)(np.array([[1.4015], [2.3432]]))
    assert np.all(out["saturation"] == 0)  # MPC plans within the limits
    assert out["speed_error"][0] > 0.01 and out["speed_error"][1] < -0.02  # no integral action, like the LQR
