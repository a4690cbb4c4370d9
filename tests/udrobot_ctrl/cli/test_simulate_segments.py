"""A run of several segments (a field log cut at its surface visits, issue 58) is replayed segment by segment: open
loop, ``--closed-loop`` and ``--windows`` restart at each segment's first row, and diagnose counts each segment as a
run of its own. The run: two stretches flown by the model itself, the second starting 40 s after the first ended,
3 m deeper, turned and moving, so that a replay carried across the cut would start the second far from the log."""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.replay import windowed_gap
from udrobot_ctrl.gap.report import split_runs
from udrobot_ctrl.gap.screen import run_label
from udrobot_ctrl.gap.shrink import WINDOW
from udrobot_ctrl.io.runlog import SEGMENT, read_run, split_segments, write_run
from udrobot_ctrl.vehicle import load_model

RATE = 20.0  # Hz
MODEL = "pendulum:chin"
STARTS = (0.0, 60.0)  # s: the second segment starts 40 s after the first (20 s long) ended


def _flown(model, t0, x0, phase):
    """20 s of thrust sweeps flown open loop by ``model`` from ``x0``, logged at RATE from t0 (no noise)."""
    t = t0 + np.arange(0.0, 20.0, 1.0 / RATE)
    tt = t - t0
    s = np.sin(2 * np.pi * tt / 9.0 + phase)
    f = np.column_stack([20 * s + 10, 20 * s + 8, 6 * np.cos(2 * np.pi * tt / 7.0), 6 * np.cos(2 * np.pi * tt / 7.0)])
    res = simulate(model, x0, 20.0, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    return t, res.x[::5][: t.size], f


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    d = tmp_path_factory.mktemp("segments")
    model = load_model(MODEL)
    x1, x2 = np.zeros(12), np.zeros(12)
    x1[2] = 1.0
    x2[[2, 5, 6]] = 4.0, 2.0, 0.3  # 3 m deeper, heading 2 rad, surging at 0.3 m/s
    parts = [_flown(model, STARTS[0], x1, 0.0), _flown(model, STARTS[1], x2, 1.0)]
    t = np.concatenate([p[0] for p in parts])
    xs = np.concatenate([p[1] for p in parts])
    f = np.concatenate([p[2] for p in parts])
    seg = np.repeat([1, 2], [p[0].size for p in parts])
    channels = {c: xs[:, i] for i, c in enumerate(STATE_NAMES)}
    path = write_run(d / "two.csv", t, channels, "thrust", f, extra={SEGMENT: seg})
    b = seg == 2
    alone = write_run(d / "second.csv", t[b], {c: v[b] for c, v in channels.items()}, "thrust", f[b])
    return {"run": path, "second": alone, "dir": d}


def test_open_loop_replay_restarts_at_each_segment(two, tmp_path):
    assert main(["simulate", "--model", MODEL, "--input", str(two["run"]), "--out", str(tmp_path / "s.csv")]) == 0
    sim, run = read_run(tmp_path / "s.csv"), read_run(two["run"])
    np.testing.assert_array_equal(sim.segment, run.segment)
    k = int(np.flatnonzero(run.segment == 2)[0])
    np.testing.assert_array_equal(sim.state_matrix()[k], run.state_matrix()[k])  # the logged state, not a carry-over
    # the second segment replays exactly as a run of its own, and (the model flew it) follows its log
    assert main(["simulate", "--model", MODEL, "--input", str(two["second"]), "--out", str(tmp_path / "a.csv")]) == 0
    np.testing.assert_array_equal(read_run(tmp_path / "a.csv").state_matrix(), sim.state_matrix()[k:])
    assert np.max(np.abs(sim.channels["z"] - run.channels["z"])) < 1e-3


def test_windows_never_cross_a_segment_and_start_from_its_first_row(two, tmp_path):
    run = read_run(two["run"])
    g = windowed_gap(MODEL, [run], 4.0)
    assert g.runs == ("two.csv[segment 1]", "two.csv[segment 2]")
    assert [pr.t[0] for pr in g.preps] == list(STARTS) and all(pr.t[-1] - pr.t[0] < 20.0 for pr in g.preps)
    assert g.windows == {"two.csv[segment 1]": 5, "two.csv[segment 2]": 5}  # 20 s each / 4 s; none over the cut
    first = g.sims[1][0]
    assert first[WINDOW] == 1 and np.allclose(first[:6], g.preps[1].eta[0])  # segment 2's first window: its row 0
    assert first[2] == pytest.approx(4.0) and first[5] == pytest.approx(2.0)
    assert g.value < 0.05  # the model that flew the run replays it (only the smoothing of the start velocities)
    # the command line: the same windows, the written replay carries the segments
    out, sim = tmp_path / "g.json", tmp_path / "w.csv"
    assert main(["simulate", "--model", MODEL, "--windows", "4", "--input", str(two["run"]), "--json", str(out),
                 "--out", str(sim)]) == 0
    assert json.loads(out.read_text())["windows"] == g.windows
    w = read_run(sim)
    k = int(np.flatnonzero(w.segment == 2)[0])
    assert w.t[k] == STARTS[1] and w.channels["z"][k] == pytest.approx(4.0)


def test_diagnose_counts_each_segment_as_a_run(two):
    """split_runs is where diagnose (and its --plot names) get their runs: one per segment, the last held out; a
    segmented run is never prepared across its cut."""
    run = read_run(two["run"])
    fit, hold, note = split_runs([run], None)
    assert [run_label(r) for r in fit] == ["two.csv[segment 1]"] and [run_label(r) for r in hold] == \
        ["two.csv[segment 2]"]
    assert hold[0].t[0] == STARTS[1] and "two.csv[segment 2]" in note
    with pytest.raises(ValueError, match="2 segments; prepare each on its own"):
        prepare(run, plant_parameters(load_model(MODEL)))


def _ardusub_run(t0, z, psi):
    """10 s of a BlueROV2 Heavy held in STABILIZE, sticks centred, at depth z (m) and heading psi (rad)."""
    t = t0 + np.arange(0.0, 10.0, 0.02)
    x = np.zeros((t.size, 12))
    x[:, 2], x[:, 5] = z, psi
    extra = {"mode": np.full(t.size, float(Mode.STABILIZE)), "armed": np.ones(t.size),
             **{f"rcin_{i}": np.full(t.size, 1500.0) for i in range(1, 9)}}
    return t, x, extra


def test_closed_loop_flies_each_segment_from_its_first_row_with_a_new_autopilot(tmp_path):
    parts = [_ardusub_run(0.0, 2.0, 0.0), _ardusub_run(30.0, 6.0, 1.0)]
    t = np.concatenate([p[0] for p in parts])
    x = np.concatenate([p[1] for p in parts])
    extra = {c: np.concatenate([p[2][c] for p in parts]) for c in parts[0][2]}
    seg = np.repeat([1, 2], [p[0].size for p in parts])
    channels = {c: x[:, i] for i, c in enumerate(STATE_NAMES)}
    meta = {"vehicle": "bluerov2-heavy"}
    src = write_run(tmp_path / "dive.csv", t, channels, "pwm", np.full((t.size, 8), 1500.0), metadata=meta,
                    extra={**extra, SEGMENT: seg})
    b = seg == 2
    alone = write_run(tmp_path / "second.csv", t[b], {c: v[b] for c, v in channels.items()}, "pwm",
                      np.full((b.sum(), 8), 1500.0), metadata=meta, extra={c: v[b] for c, v in extra.items()})
    args = ["simulate", "--model", "bluerov2-heavy", "--closed-loop", "--loop-rate", "50"]
    assert main([*args, "--input", str(src), "--out", str(tmp_path / "f.csv")]) == 0
    assert main([*args, "--input", str(alone), "--out", str(tmp_path / "g.csv")]) == 0
    flown, second = read_run(tmp_path / "f.csv"), read_run(tmp_path / "g.csv")
    two = flown.segment == 2
    k = int(np.flatnonzero(two)[0])
    assert flown.t[k] == pytest.approx(30.0) and flown.t[k - 1] <= 10.0  # in the run's t: nothing flown in the cut
    np.testing.assert_array_equal(flown.state_matrix()[k], x[np.flatnonzero(b)[0]])  # its logged first row
    # the second segment is flown as a run of its own (a fresh autopilot: integrators and targets restart)
    np.testing.assert_array_equal(flown.state_matrix()[two], second.state_matrix())
    np.testing.assert_array_equal(flown.inputs[two], second.inputs)
    assert [p.n for p in split_segments(read_run(src))] == [500, 500]
