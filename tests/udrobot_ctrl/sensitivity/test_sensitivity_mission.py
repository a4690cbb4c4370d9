"""Closed-loop mission evaluator: the same controllers and metrics as ``compare``, physics of the sensitivities,
and the CLI end to end."""
import json
import math

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.control.compare import DETAIL_KEYS, RESULT_KEYS, run_design
from udrobot_ctrl.control.missions import Mission, ReferenceStep, standard_mission
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator
from udrobot_ctrl.sensitivity.executor import SweepExecutor
from udrobot_ctrl.sensitivity.local import local_sensitivity
from udrobot_ctrl.sensitivity.parameters import default_space

# starts cruising at 0.5 m/s and ends cruising, long enough for the PID's surge integrator to settle:
# final_error_u is the steady cruise-speed error
CRUISE = Mission("sens-cruise", 30.0, initial={"z": 0.5, "psi": 0.0, "u": 0.5},
                 steps=(ReferenceStep("z", 0.5, 1.5), ReferenceStep("psi", 4.0, math.pi / 2)))
SURGE_CD = np.array([[1.4015], [1.7021], [2.3432]])  # free decay, CFD, pendulum (Cely 2019)


@pytest.mark.parametrize("kind", ["lqr", "pid", pytest.param("lmpc", marks=pytest.mark.slow)])
def test_nominal_sample_gives_compare_metrics(kind):
    # the sensitivity study flies compare's controller on compare's mission and scores it with compare's
    # metrics: the nominal sample must reproduce compare's row (same keys, same values)
    model = "cfd:morison"
    space = default_space(model)
    out = MissionEvaluator(space, kind, mission=standard_mission(quick=True))(space.nominal[None])
    rows, _ = run_design(kind, model, [model], quick=True, keep_trajectory=False)
    row = rows[0]
    assert out["error"] == [""] and row["status"] == "ok"
    for k in RESULT_KEYS[3:] + DETAIL_KEYS:
        assert k in out, k
        ref = row[k]
        if ref is None:  # not settled: censored at the mission duration, and counted
            assert out[k][0] == standard_mission(quick=True).t_final and out["unsettled"][0] >= 1
        else:
            assert out[k][0] == pytest.approx(ref, rel=1e-9, abs=1e-12), (k, out[k][0], ref)


def test_lqr_mission_settles_on_the_nominal_model_and_batches_are_independent():
    space = default_space("pendulum:chin")
    ev = MissionEvaluator(space, "lqr", mission=CRUISE)
    rng = np.random.default_rng(1)
    lo, hi = space.bounds.T
    X = np.vstack([space.nominal, lo + rng.random((3, len(space))) * (hi - lo)])
    out = ev(X)
    assert out["error"] == [""] * 4
    assert out["settling_z_s"][0] < 3.5 and out["settling_psi_s"][0] < 5.0  # within their windows
    assert out["unsettled"][0] == 0
    assert abs(out["final_error_u"][0]) < 5e-3  # trim feed-forward from the same model: no speed error
    assert out["lost_control"][0] == 0 and out["max_pitch_deg"][0] < 30
    # a sample evaluated alone gives the same metrics as inside the batch (a sample that loses pitch
    # tumbles chaotically, where rounding differences grow: compare one that keeps control)
    assert out["lost_control"][1] == 0
    alone = ev(X[1:2])
    for m in ("iae_z", "energy_J", "settling_z_s"):
        assert alone[m][0] == pytest.approx(out[m][1], rel=1e-9)


def test_wrong_surge_drag_slows_the_cruise_unless_redesigned():
    space = default_space("cfd:morison").subset(["surge.CD"])
    nominal_design = MissionEvaluator(space, "lqr", mission=CRUISE)(SURGE_CD)
    redesigned = MissionEvaluator(space, "lqr", mission=CRUISE, redesign=True)(SURGE_CD)
    # the speed offset the drag mismatch causes, relative to the matched design (which removes the common
    # residual transient of the 4 s turn): less drag, faster; more drag, slower (no integral action)
    offset = nominal_design["final_error_u"] - redesigned["final_error_u"]
    assert offset[0] > 0.005 and offset[2] < -0.01 and offset[1] == pytest.approx(0.0, abs=1e-12)
    assert np.ptp(redesigned["final_error_u"]) < 1e-3 and np.all(np.abs(redesigned["final_error_u"]) < 5e-3)
    # holding the speed against more drag costs energy: monotone in C_D
    assert np.all(np.diff(redesigned["energy_J"]) > 0)


def test_pid_integral_action_removes_the_speed_error_a_wrong_drag_causes():
    space = default_space("cfd:morison").subset(["surge.CD"])
    X = SURGE_CD[[0, 2]]
    lqr = MissionEvaluator(space, "lqr", mission=CRUISE)(X)
    pid = MissionEvaluator(space, "pid", mission=CRUISE)(X)
    assert pid["error"] == ["", ""]
    assert np.all(np.abs(pid["final_error_u"]) < 0.3 * np.abs(lqr["final_error_u"]))
    assert pid["energy_J"][1] > pid["energy_J"][0]  # same speed against more drag costs more energy
    with pytest.raises(ValueError, match="controller must be one of"):
        MissionEvaluator(space, "fuzzy")


def test_local_sensitivity_of_the_mission_is_physical():
    # (heave.added_mass is not used here: at the high end of its range compare's LQR loses pitch on this plant,
    # and that failure, not the speed physics, would dominate its one-at-a-time swing)
    space = default_space("cfd:morison", rotational=False).subset(["surge.CD", "sway.CD", "surge.added_mass"])
    res = local_sensitivity(MissionEvaluator(space, "lqr", mission=CRUISE), space,
                            executor=SweepExecutor(workers=1), progress=False)
    j = res.names.index("surge.CD")
    assert res.derivative["final_error_u"][j] < 0 and res.reliable("final_error_u")[j]
    assert res.derivative["energy_J"][j] > 0
    assert res.ranking("final_error_u")[0] == "surge.CD"
    assert np.isnan(res.elasticity["final_error_u"]).all()  # ~0 at nominal: elasticity undefined


def test_cli_morris_writes_tables_and_resume_runs_nothing_new(tmp_path, capsys):
    out = tmp_path / "study"
    argv = ["sensitivity", "--method", "morris", "--samples", "2", "--params", "surge.CD,heave.added_mass",
            "--workers", "1", "--out", str(out), "--quiet"]
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
    assert main(argv + ["--resume", "--seed", "3"]) == 2  # another design: refused, naming what differs
    assert "seed" in capsys.readouterr().err
    assert main(["sensitivity", "--range", "surge.CD=2:1", "--workers", "1"]) == 2


def test_linear_mpc_runs_per_sample_with_its_own_solver():
    short = Mission("sens-test", 6.0, initial={"z": 0.5, "psi": 0.0, "u": 0.0},
                    steps=(ReferenceStep("u", 0.5, 0.5), ReferenceStep("z", 3.0, 1.0)))
    space = default_space("cfd:morison").subset(["surge.CD"])
    X = SURGE_CD[[0, 2]]
    ev = MissionEvaluator(space, "lmpc", mission=short, sim_dt=0.05, control_dt=0.1)
    assert ev.max_chunk == 4
    out = ev(X)
    assert out["error"] == ["", ""], out["error"]
    assert {"iae", "iae_u", "energy_J", "max_speed", "settling_z_s", "fallbacks"} <= set(out)
    assert np.all(out["fallbacks"] == 0)
    assert out["energy_J"][1] > out["energy_J"][0]  # more drag, more thrust for the same transit
    assert out["max_speed"][1] < out["max_speed"][0]
    np.testing.assert_allclose(ev(X[:1])["iae"], out["iae"][:1], rtol=1e-9)  # fresh solver per sample
