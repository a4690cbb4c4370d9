"""Identification plots: the measured points stay visible over the fitted curve (issue 42)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from identification import plots


def test_spring_fit_plot_draws_visible_measured_points_on_top_of_the_fit(tmp_path, monkeypatch):
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, **kw: figures.append(fig))
    t = np.linspace(0.0, 10.0, 2001)
    x = 0.02 * np.exp(-0.3 * t) * np.cos(7.0 * t)
    launch = {"ok": True, "used": True, "axis": "surge", "file": "spring_surge_L1_r1.csv",
              "_fit": SimpleNamespace(t=t, x=x + 1e-4, model=x)}
    assert plots.plot_fits([launch], "surge", tmp_path / "f.png", "spring") is not None
    ax = figures[0].axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    measured, fit = lines["measured"], lines["fit"]
    assert measured.get_zorder() > fit.get_zorder()  # the points are drawn over the line
    assert measured.get_marker() not in ("", "None", ",", ".") and measured.get_markersize() >= 2.0
    assert measured.get_linestyle() in ("None", "")  # markers only: the fit line stays readable between them
    assert measured.get_markerfacecolor() == "none"  # open markers: the line shows through
    assert measured.get_color() != fit.get_color()
    assert len(measured.get_xdata()) <= plots.MAX_MARKERS + 1 < len(t)
    assert "on top" in figures[0]._suptitle.get_text()
