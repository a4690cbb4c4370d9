"""BlueROV2 (6 thrusters) and BlueROV2 Heavy (8): the plant, allocation, trims, LQR/PID and the CLI take the
layout from the model (issue 12 item 5: vehicles are data, no four-thruster assumption)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import brentq

from udrobot_ctrl.cli import main
from udrobot_ctrl.control.linearize import (
    REDUCED_STATES,
    held_rows,
    hover_trim,
    linearize,
    max_surge_speed,
    operating_points,
    structure_report,
)
from udrobot_ctrl.control.lqr import design_lqr
from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import Mission, ReferenceStep, make_controller, run_mission
from udrobot_ctrl.dynamics.plant import generalized_forces, plant_parameters
from udrobot_ctrl.dynamics.thrusters import ThrustAllocator, pwm_to_thrust
from udrobot_ctrl.io import runlog
from udrobot_ctrl.vehicle import load_model

N_THR = {"bluerov2": 6, "bluerov2-heavy": 8}


@pytest.fixture(scope="module")
def params():
    return {n: plant_parameters(load_model(n)) for n in N_THR}


def test_heavy_allocates_every_pure_wrench(params):
    """Heavy: each unit wrench (10 N / 1 N m) is produced exactly within the thrust limits."""
    p = params["bluerov2-heavy"]
    alloc = ThrustAllocator.from_parameters(p)
    for i in range(6):
        tau = np.zeros(6)
        tau[i] = 10.0 if i < 3 else 1.0
        res = alloc(tau)
        assert res.ok and res.f.shape == (8,)
        np.testing.assert_allclose(p.T @ res.f, tau, atol=1e-4)  # the eps = 1e-6 thrust regulariser biases ~1e-5


def test_bluerov2_cannot_pitch_alone_but_surges_with_its_pitch_moment(params):
    p = params["bluerov2"]
    alloc = ThrustAllocator.from_parameters(p)
    res = alloc(np.array([0, 0, 0, 0, 1.0, 0]))  # pure pitch moment: not in range(T)
    assert np.abs(res.unachieved[4]) > 0.5
    # surge 20 N comes with the moment of the horizontals 0.0725 m below CO: achievable exactly
    res = alloc(np.array([20.0, 0, 0, 0, 0.0725 * 20.0, 0]))
    np.testing.assert_allclose(res.unachieved, 0.0, atol=1e-5)


def test_surge_lp_holds_only_rows_independent_of_surge(params):
    assert held_rows(params["bluerov2-heavy"].T) == [1, 2, 3, 4, 5]
    assert held_rows(params["bluerov2"].T) == [1, 2, 3, 5]  # pitch follows surge and heave
    assert held_rows(plant_parameters(load_model("cfd:chin")).T) == [2, 3, 5]  # UDrobot: Y, M rows are zero


@pytest.mark.parametrize("name", sorted(N_THR))
def test_top_speed_balances_four_horizontals_against_drag(params, name):
    """All four 45 deg horizontals at their limit: X = 2 sqrt(2) ... = surge drag 13.7 u + 141 u^2."""
    p = params[name]
    f_fwd, f_rev = p.f_max[0], -p.f_min[0]
    # thrusters 1, 2 push aft for a positive command (ArduSub forward factor -1): they run in reverse
    X = 2 * np.sqrt(0.5) * (f_fwd + f_rev)
    u = brentq(lambda s: 13.7 * s + 141.0 * s * s - X, 0, 5)
    assert max_surge_speed(p) == pytest.approx(u, rel=1e-6)
    assert 0.8 < u < 0.95  # m/s, vB2022 drag at 14.8 V


def test_hover_trims(params):
    h = hover_trim(params["bluerov2-heavy"])
    assert h.is_equilibrium
    net = params["bluerov2-heavy"].weight - params["bluerov2-heavy"].buoyancy  # 0.98 N heavy: verticals lift
    np.testing.assert_allclose(h.u0[4:], -net / 4, rtol=1e-6)
    np.testing.assert_allclose(h.u0[:4], 0.0, atol=1e-9)
    h6 = hover_trim(params["bluerov2"])
    p6 = params["bluerov2"]
    # 1.96 N light: the verticals push down; least squares trades ~1e-5 N of heave for the coupled pitch row
    np.testing.assert_allclose(h6.u0[4:].sum(), p6.buoyancy - p6.weight, rtol=1e-4)
    # the only residual is the small pitch moment of the verticals at x = 0.0025 m, left to the restoring moment
    assert 1e-3 < abs(h6.residual[4]) < 0.05  # rad/s^2: 0.0025 m x ~1 N over I_yy + M_qdot
    assert np.all(np.abs(h6.residual[[0, 1, 2, 3, 5]]) < 1e-2 * abs(h6.residual[4]))


@pytest.mark.parametrize("name", sorted(N_THR))
def test_linearisation_and_structure(params, name):
    p = params[name]
    pts = operating_points(p)
    lin = linearize(p, pts[0])
    assert lin.B.shape == (12, N_THR[name])
    assert list(lin.sys.input_labels) == [f"T{i + 1}" for i in range(N_THR[name])]
    np.testing.assert_allclose(lin.f0, 0.0, atol=0.05)  # hover: at most the bluerov2's small pitch residual
    Ar, Br = lin.reduced()
    rep = structure_report(Ar, Br, states=REDUCED_STATES)
    assert rep.controllable_rank == len(REDUCED_STATES)  # every design state reachable (pitch of the 6: via surge)
    if name == "bluerov2-heavy":  # all six body DOF directly actuated: B's velocity block has rank 6
        assert np.linalg.matrix_rank(lin.B[6:]) == 6
    else:
        assert np.linalg.matrix_rank(lin.B[6:]) == 5


@pytest.mark.parametrize("name", sorted(N_THR))
@pytest.mark.parametrize("kind", ["lqr", "pid"])
def test_depth_step_settles(params, name, kind):
    """0.5 m -> 1.5 m depth step at hover: settles inside the 2 % band, level, no yaw, thrusts within limits."""
    p = params[name]
    mission = Mission("depth step", 20.0, steps=(ReferenceStep("z", 0.5, 1.5),))
    ctrl = make_controller(kind, p, mission)
    res = run_mission(ctrl, p, mission)
    met = mission_metrics(res, mission, p.f_min, p.f_max)
    assert res.u.shape[1] == N_THR[name]
    assert met["settling_z_s"] is not None and met["settling_z_s"] < 15.0
    assert abs(res.x[-1, 2] - 1.5) < 0.02
    assert np.all(res.u >= p.f_min - 1e-9) and np.all(res.u <= p.f_max + 1e-9)
    assert met["max_roll_deg"] < 1.0 and np.abs(res.x[:, 5]).max() < 1e-3
    # the Heavy holds pitch with its verticals; the 6-thruster vehicle pitches on its small (1 cm) BG
    assert met["max_pitch_deg"] < (1.0 if name == "bluerov2-heavy" else 25.0)


def test_pid_levels_pitch_only_where_the_layout_actuates_it(params):
    from udrobot_ctrl.control.pid import LOOPS, design_loops

    assert set(design_loops(params["bluerov2-heavy"])) == set(LOOPS) | {"pitch"}
    assert set(design_loops(params["bluerov2"])) == set(LOOPS)  # pitch coupled to surge/heave: not alone
    assert set(design_loops(plant_parameters(load_model("cfd:chin")))) == set(LOOPS)


@pytest.mark.parametrize("name", sorted(N_THR))
def test_lqr_design_at_every_operating_point(params, name):
    """One gain row per thruster; continuous closed loop A - B K stable at hover, cruise and top speed."""
    p = params[name]
    for op in operating_points(p):
        d = design_lqr(p, op)
        assert d.K.shape == (N_THR[name], len(REDUCED_STATES))
        Ar, Br = d.lin.reduced()
        assert np.all(np.linalg.eigvals(Ar - Br @ d.K).real < 0), op.name


def _pwm_run(tmp_path, n_thr, pwm_row, seconds=6.0, dt=0.1):
    t = np.arange(0.0, seconds + 1e-9, dt)
    channels = {c: np.zeros_like(t) for c in ("z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    channels["z"][:] = 1.0
    pwm = np.tile(np.asarray(pwm_row, float), (t.size, 1))
    assert pwm.shape[1] == n_thr
    path = tmp_path / "run.csv"
    runlog.write_run(path, t, channels, "pwm", pwm)
    return path


def test_simulate_heavy_replays_eight_pwm_columns(tmp_path, params):
    """Verticals at 1600 us push the Heavy down (ArduSub throttle -1) to the heave terminal speed."""
    src = _pwm_run(tmp_path, 8, [1500] * 4 + [1600] * 4, seconds=8.0)
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", "bluerov2-heavy", "--input", str(src), "--out", str(out)]) == 0
    sim = runlog.read_run(out)
    assert sim.input_names == tuple(f"pwm_{i}" for i in range(1, 9))
    p = params["bluerov2-heavy"]
    Z = 4 * float(pwm_to_thrust(1600.0, 14.8)) + (p.weight - p.buoyancy)  # no voltage column: the model's 14.8 V
    w_term = brentq(lambda w: 33.0 * w + 190.0 * w * w - Z, 0, 5)
    assert sim.channels["w"][-1] == pytest.approx(w_term, rel=1e-3)
    assert sim.channels["z"][-1] > 1.0 + 0.8 * w_term * 8.0 - 0.5
    assert np.abs(sim.channels["phi"]).max() < 1e-9 and np.abs(sim.channels["psi"]).max() < 1e-9


def test_simulate_bluerov2_yaws_positive_for_ardusub_yaw_pattern(tmp_path):
    """ArduSub VECTORED yaw factors (+1, -1, -1, +1) on motors 1-4: positive command = positive yaw rate."""
    src = _pwm_run(tmp_path, 6, [1560, 1440, 1440, 1560, 1500, 1500], seconds=3.0)
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", "bluerov2", "--input", str(src), "--out", str(out)]) == 0
    sim = runlog.read_run(out)
    assert sim.channels["r"][-1] > 0.1 and abs(sim.channels["u"][-1]) < 1e-6 and abs(sim.channels["v"][-1]) < 1e-3


def test_simulate_refuses_a_run_with_the_wrong_thruster_count(tmp_path, capsys):
    src = _pwm_run(tmp_path, 6, [1500] * 6, seconds=1.0)
    assert main(["simulate", "--model", "bluerov2-heavy", "--input", str(src), "--out", str(tmp_path / "s.csv")]) == 2
    assert "6 pwm columns but the model has 8 thrusters" in capsys.readouterr().err


@pytest.mark.parametrize("name", sorted(N_THR))
def test_model_show_and_export(tmp_path, capsys, name):
    assert main(["model", "show", "--model", name]) == 0
    text = capsys.readouterr().out
    if name == "bluerov2-heavy":
        assert "actuated DOFs: X, Y, Z, K, M, N" in text and "passive: none" in text
    else:
        assert "rank 5" in text
    out = tmp_path / "m.json"
    assert main(["model", "export", "--model", name, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert len(doc["thrusters"]) == N_THR[name]
    a, b = plant_parameters(load_model(name)), plant_parameters(load_model(str(out)))
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 12)) * 0.3
    np.testing.assert_array_equal(generalized_forces(x, a), generalized_forces(x, b))
    np.testing.assert_array_equal(a.T, b.T)


# ArduSub VECTORED_6DOF factors (roll, pitch, yaw, throttle, forward, lateral) per motor: pilot commands -> pwm_i
HEAVY_FACTORS = np.array([(0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
                          (1, -1, 0, -1, 0, 0), (-1, -1, 0, -1, 0, 0), (1, 1, 0, -1, 0, 0), (-1, 1, 0, -1, 0, 0)],
                         float)


@pytest.mark.slow
def test_diagnose_runs_on_a_heavy_run_with_its_own_model(tmp_path):
    """A Heavy run replayed by the model itself (pwm_1..8, 60 s of mixed manoeuvres): the diagnoser runs with the
    8-thruster matrix and finds almost no gap (it is the model's own trajectory)."""
    t = np.arange(0.0, 60.0, 0.1)
    rng = np.random.default_rng(0)
    pwm = np.full((t.size, 8), 1500.0)
    for k in range(0, t.size, 30):  # a new pilot command every 3 s
        cmd = rng.uniform(-1, 1, 6) * np.array([0.1, 0.1, 0.4, 0.5, 0.6, 0.4])
        pwm[k:k + 30] = 1500 + 300 * np.clip(HEAVY_FACTORS @ cmd, -1, 1)
    ch = {c: np.zeros_like(t) for c in ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    ch["z"][:] = 2.0
    runlog.write_run(tmp_path / "cmd.csv", t, ch, "pwm", pwm)
    assert main(["simulate", "--model", "bluerov2-heavy", "--input", str(tmp_path / "cmd.csv"),
                 "--out", str(tmp_path / "sim.csv")]) == 0
    assert main(["diagnose", str(tmp_path / "sim.csv"), "--model", "bluerov2-heavy", "--json",
                 str(tmp_path / "rep.json"), "--quiet"]) == 0
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["model"] == "bluerov2-heavy"
    # NRMSE of the model's own trajectory: only the diagnoser's resampling / smoothing separates them (~0.02)
    assert rep["gap_before"]["metric"] == "nrmse" and rep["gap_before"]["value"] < 0.05
