"""``simulate`` says when its replay stops representing the vehicle (issue 58.4), and starts the channels its first
row lacks as the diagnoser does (issue 58.5c).

Runs are flown by the plant itself (noise free), so the replay with the same model reproduces them: where the
written replay is above the surface, rolled over or holds a thruster at its limit is known from the truth alone.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.udrobot_ctrl.gap.field_dive import pilot_plan
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.domain import ABOVE_SURFACE, THRUST_SATURATED
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.gap.data import START_VELOCITY_WITHIN_S
from udrobot_ctrl.io.runlog import read_run, write_run
from udrobot_ctrl.vehicle import load_model

RATE = 20.0
MODEL = "pendulum:chin"  # thrusters 0, 1 surge (and yaw), 2, 3 heave (and roll)
P = plant_parameters(load_model(MODEL))


def _flown(path, f, z0=1.0, channels=None):
    """Fly ``MODEL`` open loop with the thrusts ``f`` (n, 4) from rest at depth ``z0``; write it; return the truth."""
    t = np.arange(f.shape[0]) / RATE
    x0 = np.zeros(12)
    x0[2] = z0
    res = simulate(load_model(MODEL), x0, t[-1] + 1.0 / RATE, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    xs = res.x[::5][: t.size]
    ch = channels or {c: xs[:, i] for i, c in enumerate(STATE_NAMES)}
    write_run(path, t, ch, "thrust", f)
    return t, xs


def _sidecar(path):
    return json.loads(path.with_suffix(".json").read_text())


def test_a_replay_that_climbs_out_of_the_water_warns_with_the_span_and_writes_it_in_the_sidecar(tmp_path, capsys):
    n = int(8 * RATE)
    f = np.zeros((n, 4))
    f[:, 2:] = -15.0  # both heave thrusters up (NED: -z) from 1 m depth
    t, xs = _flown(tmp_path / "climb.csv", f)
    above = np.flatnonzero(xs[:, 2] < 0)
    assert above.size and above[-1] == n - 1  # the truth itself breaks the surface and stays above it
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", MODEL, "--input", str(tmp_path / "climb.csv"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if ABOVE_SURFACE in x)
    assert "leaves the plant's domain" in line and "above the surface" in line
    sim = read_run(out)
    first = np.flatnonzero(sim.channels["z"] < 0)[0]
    assert first == pytest.approx(above[0], abs=1)  # the replay reproduces the truth to a sample
    dom = _sidecar(out)["replay_domain"]
    assert dom["codes"] == [ABOVE_SURFACE]
    (span,) = dom["spans"]
    assert span["t0"] == pytest.approx(sim.t[first], abs=1e-3) and span["t1"] == pytest.approx(t[-1], abs=1e-3)


def test_a_thruster_held_at_its_limit_for_5_s_is_named_and_one_held_for_3_s_is_not(tmp_path, capsys):
    n = int(16 * RATE)
    t = np.arange(n) / RATE
    f = np.zeros((n, 4))
    f[(t >= 1.0) & (t < 6.0), 0] = P.f_max[0]  # 5 s at the forward limit, then
    f[(t >= 9.0) & (t < 12.0), 1] = P.f_min[1]  # 3 s at the reverse limit: below half the 8 s window
    f[:, 2:] = 2.0  # a little down thrust against the buoyancy: stays in the water
    _, xs = _flown(tmp_path / "surge.csv", f, z0=2.0)
    assert np.all(xs[:, 2] > 0)
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", MODEL, "--input", str(tmp_path / "surge.csv"), "--out", str(out)]) == 0
    dom = _sidecar(out)["replay_domain"]
    assert dom["codes"] == [THRUST_SATURATED] and dom["saturation_s"] == pytest.approx(4.0)
    (span,) = dom["spans"]
    assert span["thruster"] == 0 and span["t0"] == pytest.approx(1.0) and span["t1"] == pytest.approx(5.95)
    assert "thrust_saturated (thruster 0) 1.00-5.95 s" in capsys.readouterr().err


def test_a_replay_in_the_domain_writes_an_empty_replay_domain_and_no_warning(tmp_path, capsys):
    n = int(6 * RATE)
    f = np.zeros((n, 4))
    f[:, 0] = f[:, 1] = 10.0
    f[:, 2:] = 2.0
    _flown(tmp_path / "calm.csv", f, z0=2.0)
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", MODEL, "--input", str(tmp_path / "calm.csv"), "--out", str(out)]) == 0
    assert _sidecar(out)["replay_domain"]["codes"] == [] and "domain" not in capsys.readouterr().err


def test_channels_the_first_row_lacks_start_from_their_first_sample_or_at_rest(tmp_path, capsys):
    """Issue 58.5c: z missing for the first 1 s starts from its first sample (as the diagnoser's pose fill), not
    from the surface; u first logged after 2 s (later than the 0.8 s a velocity may lead) starts at rest, v within
    0.2 s from its first sample. Each is named in the warning and the sidecar."""
    n = int(6 * RATE)
    t = np.arange(n) / RATE
    f = np.zeros((n, 4))
    f[:, 2:] = 2.0
    x0 = np.zeros(12)
    x0[2], x0[7] = 2.0, 0.05
    res = simulate(load_model(MODEL), x0, t[-1] + 1.0 / RATE, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    xs = res.x[::5][: t.size]
    ch = {c: xs[:, i].copy() for i, c in enumerate(STATE_NAMES)}
    ch["z"][t < 1.0] = np.nan
    ch["u"][t < 2.0] = np.nan
    ch["v"][t < 0.2] = np.nan
    write_run(tmp_path / "late.csv", t, ch, "thrust", f)
    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", MODEL, "--input", str(tmp_path / "late.csv"), "--out", str(out)]) == 0
    sim = read_run(out)
    assert sim.channels["z"][0] == pytest.approx(ch["z"][t >= 1.0][0])  # not 0: the surface
    assert sim.channels["u"][0] == 0.0 and sim.channels["v"][0] == pytest.approx(ch["v"][t >= 0.2][0])
    err = capsys.readouterr().err
    assert "z from its first sample (1 s in)" in err and "v from its first sample (0.2 s in)" in err
    assert f"u at rest (0: first logged 2 s in, later than {START_VELOCITY_WITHIN_S:g} s)" in err
    fills = {e["channel"]: e for e in _sidecar(out)["start_state"]}
    assert fills["z"]["how"] == "first_sample" and fills["u"]["how"] == "rest"
    assert fills["u"]["t_first"] == pytest.approx(2.0) and set(fills) == {"z", "u", "v"}


@pytest.mark.slow
def test_the_closed_loop_replay_of_a_full_throttle_climb_warns_when_it_breaks_the_surface(tmp_path, capsys):
    """The emulated ArduSub flies bluerov2-heavy from 3 m up at a full throttle stick in STABILIZE (the motors take
    the throttle as it is): it leaves the water, and the closed-loop replay says where."""
    plan = pilot_plan(duration=24.0, alt_hold_from=1e9)
    rc3 = plan.extra["rcin_3"].copy()
    rc3[plan.t >= 2.0] = 1900.0
    ch = dict(plan.channels)
    ch["z"] = np.full(plan.t.size, 3.0)
    src = write_run(tmp_path / "pilot.csv", plan.t, ch, "pwm", plan.inputs,
                    extra={**plan.extra, "rcin_3": rc3}, metadata={"vehicle": "bluerov2-heavy"})
    out = tmp_path / "flown.csv"
    assert main(["simulate", "--model", "bluerov2-heavy", "--closed-loop", "--input", str(src),
                 "--out", str(out)]) == 0
    flown = read_run(out)
    above = np.flatnonzero(flown.channels["z"] < 0)
    assert above.size
    dom = _sidecar(out)["replay_domain"]
    assert ABOVE_SURFACE in dom["codes"]
    first = next(s for s in dom["spans"] if s["code"] == ABOVE_SURFACE)
    assert first["t0"] == pytest.approx(flown.t[above[0]], abs=1e-3)
    assert "above_surface" in capsys.readouterr().err


def test_the_windowed_replay_names_its_windows_above_the_surface_in_the_console_and_the_json(tmp_path, capsys):
    n = int(24 * RATE)
    t = np.arange(n) / RATE
    f = np.zeros((n, 4))
    f[:, 0] = f[:, 1] = 8.0 * np.sin(2 * np.pi * t / 6.0)
    f[t >= 12.0, 2:] = -15.0  # up from 2 m at 12 s: through the surface in the last window
    _, xs = _flown(tmp_path / "climb.csv", f, z0=2.0)
    gap = tmp_path / "gap.json"
    assert main(["simulate", "--model", MODEL, "--windows", "8", "--input", str(tmp_path / "climb.csv"),
                 "--json", str(gap)]) == 0
    entries = json.loads(gap.read_text())["replay_domain"]
    above = {k + 1 for k in range(3) if np.any(xs[k * 160:(k + 1) * 160, 2] < 0)}
    assert above and {e["window"] for e in entries if ABOVE_SURFACE in e["codes"]} == above
    assert all(e["run"] == "climb.csv" for e in entries)
    out = capsys.readouterr().out
    assert f"warning: climb.csv window {min(above)} (" in out and "(scored, not a finding)" in out
