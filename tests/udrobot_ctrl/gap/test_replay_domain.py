"""The diagnoser names the replay windows that leave the plant's domain (issue 58.4), bins a regime family over the
runs that have it (58.5a: ``KeyError: 'distance to the nearest wall/seabed'`` when the altitude is valid in one part
and not the other), and writes no corrected model when nothing was diagnosed (58.5b).

Runs are flown open loop by the nominal UDrobot (the model that is replayed), with a little sensor noise: the windows
that are above the surface or hold a thruster at its limit are known from the truth.
"""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.domain import ABOVE_SURFACE, THRUST_SATURATED
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.gap import plots
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.locate import _regime_condition, bin_label
from udrobot_ctrl.gap.replay import window_domains
from udrobot_ctrl.gap.report import diagnose, summary
from udrobot_ctrl.gap.shrink import WINDOW, simulate_windows, window_starts
from udrobot_ctrl.io.runlog import Run, write_run
from udrobot_ctrl.vehicle import load_model

RATE = 20.0
WINDOW_S = 8.0
MODEL = "pendulum:chin"
P = plant_parameters(load_model(MODEL))
SEABED = 4.0  # m, the altitude's seabed
NOISE = {"z": 0.005, "phi": 0.003, "theta": 0.003, "psi": 0.005, "u": 0.008, "v": 0.008, "w": 0.008, "p": 0.005,
         "q": 0.005, "r": 0.005, "x": 0.03, "y": 0.03}  # assumed, as tests/udrobot_ctrl/gap/stock_sim.py


def _fly(name, f, z0, seed, altitude=True, effects=()):
    """(Run, truth (n, 12)) of UDrobot (with the plant ``effects``) flown open loop by the thrusts ``f`` (n, 4) from
    rest at depth ``z0``."""
    t = np.arange(f.shape[0]) / RATE
    x0 = np.zeros(12)
    x0[2] = z0
    res = simulate(load_model(MODEL).with_changes(effects=tuple(effects)), x0, t[-1] + 1.0 / RATE,
                   inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    xs = res.x[::5][: t.size]
    rng = np.random.default_rng(seed)
    ch = {c: xs[:, i] + rng.normal(0, NOISE[c], t.size) for i, c in enumerate(STATE_NAMES)}
    ch["altitude"] = SEABED - xs[:, 2] + rng.normal(0, 0.01, t.size) if altitude else np.full(t.size, np.nan)
    return Run(path=name, t=t, channels=ch, input_kind="thrust", inputs=f, extra={},
               metadata={"format": "udrobot-run/1"}), xs


def _commands(t, seed):
    """Surge sweeps both ways and heave pulses about hover, within 60% of the thrusters' range."""
    rng = np.random.default_rng(seed)
    f = np.zeros((t.size, 4))
    s = np.sin(2 * np.pi * t / rng.uniform(7, 10))
    f[:, 0], f[:, 1] = 12 * s + 4, 12 * s + 3
    f[:, 2] = f[:, 3] = 4.0 * np.sign(np.sin(2 * np.pi * t / rng.uniform(5, 7)))
    return f


@pytest.fixture(scope="module")
def climb():
    """A 40 s run: surge and heave manoeuvres at 2 m, thruster 0 held at its forward limit for 6 s (window 1) and for
    3 s (window 2), then from 24 s both heave thrusters push up until the vehicle breaks the surface."""
    t = np.arange(0.0, 40.0, 1.0 / RATE)
    f = _commands(t, 1)
    f[(t >= 1.0) & (t < 7.0), 0] = P.f_max[0]
    f[(t >= 10.0) & (t < 13.0), 0] = P.f_max[0]
    f[t >= 24.0, 2:] = -20.0
    return _fly("climb.csv", f, 2.0, seed=1)


def test_the_windows_above_the_surface_and_at_a_thrusters_limit_are_named(climb):
    run, truth = climb
    prep = prepare(run, P, "climb.csv")
    sim = simulate_windows(prep, P, (), WINDOW_S)
    flagged = {w.window: w for w in window_domains(prep, sim, P, WINDOW_S)}
    starts, w = window_starts(prep, WINDOW_S)
    above = {k + 1 for k, a in enumerate(starts) if np.any(truth[a:a + w, 2] < -0.05)}  # clearly above the surface
    below = {k + 1 for k, a in enumerate(starts) if np.all(truth[a:a + w, 2] > 0.05)}  # clearly under water
    assert above and below
    named = {k for k, x in flagged.items() if ABOVE_SURFACE in x.check.codes}
    assert above <= named and not (named & below)
    sat = {k for k, x in flagged.items() if THRUST_SATURATED in x.check.codes}
    assert 1 in sat and 2 not in sat  # 6 s of the 8 s window at the limit; 3 s is less than half the window
    (span,) = [s for s in flagged[1].check.spans if s.code == THRUST_SATURATED]
    assert span.thruster == 0 and span.t0 == pytest.approx(1.0) and span.t1 == pytest.approx(6.95)
    k = min(above)
    entry = flagged[k].to_json()
    assert entry["window"] == k and entry["t"][0] == pytest.approx(prep.t[starts[k - 1]])
    assert ABOVE_SURFACE in entry["codes"] and all(s["t0"] >= entry["t"][0] for s in entry["spans"])


def test_a_holdout_that_leaves_the_water_is_flagged_in_the_report_its_verdict_and_its_summary(climb):
    t = np.arange(0.0, 40.0, 1.0 / RATE)
    fit, _ = _fly("deep.csv", _commands(t, 2), 2.0, seed=2)
    report, _ = diagnose(MODEL, [fit], [climb[0]], window_s=WINDOW_S, effects=["buoyancy_offset"])
    dom = report["replay_domain"]
    assert dom["scored"] is True and dom["criteria"]["saturation_s"] == pytest.approx(WINDOW_S / 2)
    hold = [w for w in dom["nominal"] if w["part"] == "holdout"]
    assert hold and all(w["run"] == "climb.csv" for w in hold)
    assert ABOVE_SURFACE in {c for w in hold for c in w["codes"]}
    assert not [w for w in dom["nominal"] if w["run"] == "deep.csv" and ABOVE_SURFACE in w["codes"]]
    assert dom["holdout_flagged"]["nominal"] == len(hold)
    assert "leave the plant's domain" in report["verdict"] and "not a finding" in report["verdict"]
    text = summary(report)
    assert "windows outside the plant's domain (scored, not a finding): climb.csv (holdout) window" in text
    assert sum(report["gap_before"]["windows"].values()) >= len(hold)  # the flagged windows stay scored


def test_a_regime_family_only_some_runs_have_is_binned_over_those_runs():
    """58.5a: the run holding most of a channel's error has the seabed distance (valid altitude), the other does
    not: the family is binned over the first alone (it stopped with KeyError)."""
    t = np.arange(0.0, 20.0, 1.0 / RATE)
    with_alt, _ = _fly("alt.csv", _commands(t, 3), 2.0, seed=3)
    without, _ = _fly("noalt.csv", _commands(t, 4), 2.0, seed=4, altitude=False)
    pa, pb = prepare(with_alt, P, "alt.csv"), prepare(without, P, "noalt.csv")
    assert pa.surfaces and not pb.surfaces
    e2 = np.linspace(0.0, 1.0, pa.n) ** 2
    regimes, _ = _regime_condition("u", [(10.0, pa, e2), (1.0, pb, np.full(pb.n, 0.01))])
    dist = regimes["distance to the nearest wall/seabed"]
    assert sum(v["time_share"] for v in dist.values()) == pytest.approx(1.0, abs=0.01)
    d = np.min(np.column_stack([s[0] for s in pa.surfaces]), axis=1)
    near = (d >= 2.0) & (d < np.inf)  # the "above 2 m" bin: the time of alt.csv alone
    assert dist["above 2 m"]["time_share"] == pytest.approx(near.mean(), abs=1e-3)
    depth = np.concatenate([pa.eta[:, 2], pb.eta[:, 2]])  # a family both runs have still pools them
    edges = (-np.inf, 0.5, 1.0, 2.0, 4.0, np.inf)
    pooled = {bin_label(lo, hi, "m"): np.mean((depth >= lo) & (depth < hi)) for lo, hi in zip(edges[:-1], edges[1:])}
    assert {k: v["time_share"] for k, v in regimes["depth"].items()} == pytest.approx(
        {k: v for k, v in pooled.items() if v > 0}, abs=1e-3)


@pytest.mark.slow
def test_diagnose_plot_on_runs_whose_altitude_is_valid_in_one_part_only(tmp_path):
    """The vehicle is 3 N lighter than the model: the heave gap is located, and its regimes binned over both runs;
    the run with the valid altitude flies twice as long, so it holds most of the error (the run the families were
    read from)."""
    light = [PlantEffect("buoyancy_offset", {"dB_N": 3.0})]
    paths = []
    for name, seed, alt, duration in (("alt.csv", 5, True, 40.0), ("noalt.csv", 6, False, 20.0)):
        t = np.arange(0.0, duration, 1.0 / RATE)
        r, _ = _fly(name, _commands(t, seed), 2.5, seed=seed, altitude=alt, effects=light)
        paths.append(str(write_run(tmp_path / name, r.t, r.channels, r.input_kind, r.inputs)))
    out = tmp_path / "plots"
    for fit, hold in ((paths[0], paths[1]), (paths[1], paths[0])):
        assert main(["diagnose", "--model", MODEL, "--json", str(tmp_path / "r.json"), "--quiet", "--force",
                     "--effects", "buoyancy_offset", "--holdout", hold, "--plot", str(out), fit]) == 0
        report = json.loads((tmp_path / "r.json").read_text())
        assert report["location"] and any("distance to the nearest wall/seabed" in loc["regimes"]
                                          for loc in report["location"] if loc.get("regimes"))
    assert sorted(p.name for p in out.iterdir()) == ["overlay_alt.png", "overlay_noalt.png", "residuals_alt.png",
                                                     "residuals_noalt.png"]


def test_out_model_is_not_written_when_no_run_was_diagnosed(tmp_path, capsys):
    """58.5b: every run unexcited (all commands at neutral): the report says not diagnosed, and no corrected model
    (the nominal model, under a corrected model's name) is written."""
    t = np.arange(0.0, 30.0, 0.05)
    rng = np.random.default_rng(0)
    ch = {"z": 1.0 + rng.normal(0, 0.002, t.size), **{c: np.zeros(t.size) for c in ("phi", "theta", "psi")}}
    run = write_run(tmp_path / "idle.csv", t, ch, "pwm", np.full((t.size, 4), 1500.0))
    model = tmp_path / "corrected.json"
    assert main(["diagnose", "--model", MODEL, "--json", str(tmp_path / "r.json"), "--quiet",
                 "--out-model", str(model), str(run)]) == 0
    assert not model.exists()
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["verdict"].startswith("not diagnosed") and report["replay_domain"] is None
    assert f"{model} not written: no run was diagnosed" in capsys.readouterr().err


def test_the_figures_hatch_the_windows_the_report_names_outside_the_domain(tmp_path, monkeypatch):
    t = np.arange(200) * 0.05
    sim = np.zeros((200, 16))
    sim[:, WINDOW] = np.repeat([1.0, 2.0], 100)
    prep = SimpleNamespace(t=t, meas={"u": np.zeros(200)}, name="run.csv", smoothed=None)
    ctx = SimpleNamespace(preps=[prep], nominal_sims=[sim], after_sims=[sim], n_fit=0)
    entry = {"run": "run.csv", "part": "holdout", "window": 2, "t": [5.0, 9.95], "codes": [ABOVE_SURFACE],
             "spans": [{"code": ABOVE_SURFACE, "t0": 7.0, "t1": 9.95}]}
    report = {"location": [], "gap_before": {"scored": ["u"]}, "replay_domain": {"nominal": [entry], "after": []}}
    figures = {}
    monkeypatch.setattr(plots, "errors", lambda prep, sim: {"u": np.zeros(200)})
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, **kw: figures.setdefault(path.name, fig) and path)
    plots.write_plots(ctx, report, tmp_path)
    for name in ("residuals_run.png", "overlay_run.png"):
        fig = figures[name]
        hatched = [pa for pa in fig.axes[0].patches if pa.get_hatch() == "//"]
        assert len(hatched) == 1 and hatched[0].get_x() == pytest.approx(5.0)
        assert any(tx.get_text() == ABOVE_SURFACE for tx in fig.axes[0].texts)
        assert "outside the plant's domain" in fig._suptitle.get_text()
    report["replay_domain"] = {"nominal": [], "after": []}
    figures.clear()
    plots.write_plots(ctx, report, tmp_path)
    assert not [pa for pa in figures["residuals_run.png"].axes[0].patches if pa.get_hatch() == "//"]
    assert "domain" not in figures["overlay_run.png"]._suptitle.get_text()
