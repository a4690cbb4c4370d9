"""``diagnose --plot`` on runs without a DVL (issue 37) and the located windows shaded (issue 42.5).

Without a DVL the accelerometer channels ``ax ay az`` are scored; the overlay figure drew them from the state
columns and stopped with ``KeyError: 'ax'``. The residual figures said "located windows shaded" and shaded nothing
for the DOFs located by their residual force (no replayed channel, hence no window).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.gap import plots
from udrobot_ctrl.gap.plots import COLUMN, located_windows, replayed
from udrobot_ctrl.gap.report import DiagnosisContext, diagnose
from udrobot_ctrl.gap.shrink import ACCEL
from udrobot_ctrl.io.runlog import write_run

from .truth import generate


@pytest.fixture(scope="module")
def stock_runs():
    """Two 60 s pool runs of UDrobot whose thrusters have a dead band (a quarter of the command range), logged by
    stock sensors (depth, attitude, gyro, accelerometer; no DVL, no positioning)."""
    return generate({"thruster_deadband": {"delta": 0.25}}, n_runs=2, duration=60.0, rate=20.0, seed=3,
                    sensors="stock")


@pytest.mark.slow
def test_plot_writes_its_figures_on_runs_without_a_dvl(stock_runs, tmp_path):
    paths = []
    for i, r in enumerate(stock_runs):
        assert "u" not in r.channels and "ax" in r.channels
        paths.append(str(write_run(tmp_path / f"stock_{i}.csv", r.t, r.channels, r.input_kind, r.inputs,
                                   metadata=r.metadata)))
    out = tmp_path / "plots"
    assert main(["diagnose", "--model", "pendulum:chin", "--json", str(tmp_path / "r.json"), "--quiet",
                 "--plot", str(out), *paths]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["overlay_stock_1.png", "residuals_stock_0.png",
                                                     "residuals_stock_1.png"]
    assert all(p.stat().st_size > 10_000 for p in out.iterdir())


@pytest.mark.slow
def test_the_overlay_draws_the_accelerometer_and_the_residuals_shade_the_located_windows(stock_runs, tmp_path,
                                                                                          monkeypatch):
    report, ctx = diagnose("pendulum:chin", stock_runs[:1], stock_runs[1:])
    assert set(ACCEL) & set(report["gap_before"]["scored"])  # at least one accelerometer channel moved
    spans = located_windows(report)
    assert spans, "a dead band acts in the transients: its located channels have worst windows"
    figures = {}
    real_save = plots.save_figure

    def keep(fig, path, **kw):
        figures[path.name] = fig
        return real_save(fig, path, **kw)
    monkeypatch.setattr(plots, "save_figure", keep)
    plots.write_plots(ctx, report, tmp_path)
    overlay = figures["overlay_truth_1.png"]
    labels = [ax.get_ylabel() for ax in overlay.axes]
    assert any(lb.split()[0] in ACCEL for lb in labels) and len(labels) == len(report["gap_before"]["scored"])
    # the accelerometer panel holds the replay's specific force, not a state column
    sim = ctx.nominal_sims[1]
    c = next(c for c in report["gap_before"]["scored"] if c in ACCEL)
    drawn = overlay.axes[report["gap_before"]["scored"].index(c)].lines[1].get_ydata()
    assert np.array_equal(drawn, sim[:, COLUMN[c]], equal_nan=True)
    for run, windows in spans.items():
        fig = figures[f"residuals_{plots.file_label(run)}.png"]
        shaded = [pa for pa in fig.axes[0].patches]
        assert len(shaded) == len(windows)
        assert "shaded" in fig.texts[0].get_text() and "no located window" not in fig.texts[0].get_text()
    for run in {pr.name for pr in ctx.preps} - set(spans):
        fig = figures[f"residuals_{plots.file_label(run)}.png"]
        assert not fig.axes[0].patches and "no located window in this run" in fig.texts[0].get_text()


def test_write_plots_with_nothing_diagnosed_writes_nothing(tmp_path):
    report = {"location": [], "gap_before": {"scored": []}}
    assert plots.write_plots(DiagnosisContext([], 0, [], [], [], []), report, tmp_path) == []


def test_the_overlay_marks_where_a_replay_window_diverges(tmp_path, monkeypatch):
    """Issue 42.5: a replay that runs away is marked (an X at the first diverged sample of each window)."""
    from types import SimpleNamespace

    from udrobot_ctrl.gap.shrink import WINDOW

    t = np.arange(100) * 0.1
    nominal = np.zeros((100, 16))
    nominal[:, WINDOW] = np.repeat([1.0, 2.0], 50)
    nominal[70:, WINDOW] = -2.0  # the second window diverges at t = 7.0 s
    nominal[70:, COLUMN["u"]] = 1e6
    after = nominal.copy()
    after[:, WINDOW] = np.repeat([1.0, 2.0], 50)  # with the effects, nothing diverges
    assert list(plots.divergence_starts(nominal)) == [70] and plots.divergence_starts(after).size == 0
    prep = SimpleNamespace(t=t, meas={"u": np.zeros(100)}, name="run.csv", smoothed=None)
    ctx = SimpleNamespace(preps=[prep], nominal_sims=[nominal], after_sims=[after], n_fit=0)
    report = {"location": [], "gap_before": {"scored": ["u"]}}
    figures = {}
    monkeypatch.setattr(plots, "errors", lambda prep, sim: {})  # no residual figure: only the overlay
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, **kw: figures.setdefault(path.name, fig) and path)
    plots.write_plots(ctx, report, tmp_path)
    ax = figures["overlay_run.png"].axes[0]
    marks = [line for line in ax.get_lines() if "replay diverges" in line.get_label()]
    assert len(marks) == 1 and marks[0].get_label().startswith("nominal")
    assert list(np.ravel(marks[0].get_xdata())) == [7.0]
    assert "diverges" in figures["overlay_run.png"]._suptitle.get_text()


def test_the_overlay_draws_a_replayed_angle_on_the_measurement_branch():
    """A heading logged wrapped to (-pi, pi] and a replay that turned through pi: drawn 2 pi apart before, the replay
    is drawn on the logged branch, its error (what the gap scores) unchanged."""
    t = np.linspace(0.0, 4.0, 201)
    psi_true = 2.9 + 0.1 * t  # through pi at t = 2.4 s
    logged = np.angle(np.exp(1j * psi_true))  # wrapped as a log has it
    sim = np.zeros((t.size, COLUMN["psi"] + 1))
    sim[:, COLUMN["psi"]] = psi_true + 0.02  # the replay integrates on, 0.02 rad ahead
    prep = SimpleNamespace(meas={"psi": logged}, smoothed=None)
    drawn = replayed(prep, sim, "psi")
    assert np.max(np.abs(drawn - logged - 0.02)) < 1e-12
    assert np.max(np.abs(sim[:, COLUMN["psi"]] - logged)) > 6.0  # what was drawn before
