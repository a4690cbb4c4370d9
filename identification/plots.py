"""Plots of an identification run: fits against measurements (paper Fig. 7), coefficients vs Reynolds
number (Figs. 17-19), CFD force-speed regressions (Fig. 16)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from udrobot_files.output import save_figure

# units of the per-launch coefficients (model scale): C_m and C_D are dimensionless
COEFF_LABELS = {"Cm": "C_m (-)", "CD": "C_D (-)", "KL": "K_L (N s/m)", "KQ": "K_Q (N s²/m²)"}
MAX_POINTS = 400  # measured samples drawn per launch: enough to see the trace, cheap to lay out


MAX_MARKERS = 120  # measured samples drawn as markers over a fit: few enough to see the line between them


def _every(n: int, most: int = MAX_POINTS) -> int:
    """Stride that keeps at most ``most`` of ``n`` samples."""
    return max(1, -(-n // most))


def plot_fits(launches, axis, path, kind, title_note: str = "", protect=()) -> Path | None:
    """Grid of every launch of ``axis``: measurement and fitted model (or turning points) against time (s)."""
    rows = [e for e in launches if e["ok"] and (e["axis"] or "unspecified") == axis]
    if not rows:
        return None
    n = len(rows)
    ncol = min(6, n)
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(2.6 * ncol, 1.9 * nrow + 0.6))
    axes = fig.subplots(nrow, ncol, squeeze=False, sharey=False)
    scale, unit = (1e3, "displacement (mm)") if kind == "spring" else (180 / math.pi, "angle (deg)")
    for ax, e in zip(axes.flat, rows):
        fit = e.get("_fit")
        graph = e.get("_graph")
        if fit is not None:
            # the fit line under the measured points, which are drawn last with open markers so both stay visible
            k = _every(len(fit.t), MAX_MARKERS)
            ax.plot(fit.t, fit.model * scale, "-", lw=0.9, color="C0", label="fit", zorder=2)
            ax.plot(fit.t[::k], fit.x[::k] * scale, "o", ms=2.2, mfc="none", mew=0.6, color="C1", label="measured",
                    zorder=3)
        elif graph is not None:
            launch, start, ext, _ = graph
            k = _every(len(launch.t))
            ax.plot(launch.t[::k], launch.x[::k] * scale, "-", lw=0.8, color="0.4", label="measured")
            ax.plot(ext.t, (ext.x + ext.offset) * scale, "o", ms=3, color="C3", label="turning points")
        title = Path(e["file"]).stem[-22:]
        if not e["used"]:
            title += " (rejected)"
        ax.set_title(title, fontsize=7)
        ax.tick_params(labelsize=6)
    for i, ax in enumerate(axes.flat):
        r, c = divmod(i, ncol)
        if i >= n:
            ax.axis("off")
            continue
        if r == nrow - 1 or i + ncol >= n:
            ax.set_xlabel("t (s)", fontsize=7)
        if c == 0:
            ax.set_ylabel(unit, fontsize=7)
    axes[0, 0].legend(fontsize=6, loc="upper right")
    if any(e.get("_fit") is not None for e in rows):
        what = "measured (orange circles, on top) and fit (blue line)"
    else:
        what = "measurement (grey) and turning points"
    fig.suptitle(f"{kind} launches, {axis}: {what}{title_note}", fontsize=9)
    # fixed margins: tight_layout on a 24-panel grid costs seconds per figure
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.5 / (1.9 * nrow + 0.6) + 0.04, top=1 - 0.5 / (1.9 * nrow + 0.6),
                        wspace=0.35, hspace=0.75)
    save_figure(fig, path, protect=protect, dpi=110)
    return Path(path)


def plot_vs_reynolds(launches, axis, path, kind, title_note: str = "", protect=()) -> Path | None:
    """Per-launch coefficients with 95 % intervals against the Reynolds number."""
    rows = [e for e in launches if e["ok"] and (e["axis"] or "unspecified") == axis and "Re" in e]
    if not rows:
        return None
    keys = {"spring": ("Cm", "CD", "KL"), "pendulum": ("Cm", "KL", "KQ", "CD")}[kind]
    fig = Figure(figsize=(3.2 * len(keys), 2.8))
    axes = fig.subplots(1, len(keys), squeeze=False)
    for ax, k in zip(axes[0], keys):
        for used, marker, color in ((True, "o", "C0"), (False, "x", "C3")):
            sel = [e for e in rows if e["used"] == used and e.get(k) is not None]
            if not sel:
                continue
            re_ = np.array([e["Re"] for e in sel])
            v = np.array([e[k] for e in sel])
            ci = np.array([e.get(k + "_ci95") or [x, x] for e, x in zip(sel, v)])
            ax.errorbar(re_, v, yerr=[v - ci[:, 0], ci[:, 1] - v], fmt=marker, ms=3, color=color, lw=0.6,
                        label="used" if used else "rejected")
        ax.set_xlabel("Reynolds number Re (-)", fontsize=8)
        ax.set_title(COEFF_LABELS.get(k, k), fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"{kind}, {axis}: coefficients vs Reynolds number (95 % intervals){title_note}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, protect=protect, dpi=110)
    return Path(path)


def plot_cfd(launches, path, title_note: str = "", protect=()) -> Path | None:
    """Force-speed points and both regressions, one panel per table."""
    rows = [e for e in launches if e["ok"] and "_table" in e]
    if not rows:
        return None
    fig = Figure(figsize=(3.4 * len(rows), 3.0))
    axes = fig.subplots(1, len(rows), squeeze=False)
    for ax, e in zip(axes[0], rows):
        t = e["_table"]
        u = np.linspace(min(0.0, t.speed.min()), t.speed.max(), 200)
        ax.plot(t.speed, t.force, "o", ms=4, color="0.3", label="CFD")
        ax.plot(u, e["KL"] * u + e["KQ"] * np.abs(u) * u, "-", color="C0",
                label=f"Chin K_L={e['KL']:.3g}, K_Q={e['KQ']:.3g} (R2 {e['r2']:.4f})")
        ax.plot(u, e["KD"] * np.abs(u) * u, "--", color="C1", label=f"Morison K_D={e['KD']:.3g}")
        ax.set_xlabel("speed (m/s)", fontsize=8)
        ax.set_ylabel("force (N)", fontsize=8)
        ax.set_title(f"{e['axis'] or Path(e['file']).stem}", fontsize=9)
        ax.legend(fontsize=6)
        ax.tick_params(labelsize=7)
    if title_note:
        fig.suptitle(f"CFD force tables and regressions{title_note}", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path, protect=protect, dpi=110)
    return Path(path)


def plot_report(report: dict, launches, directory, kind, title_note: str = "", protect=()) -> list[Path]:
    """Every plot of an identification run into ``directory``; returns the written paths.

    ``title_note`` is appended to every figure title (e.g. ``" - SYNTHETIC data"``).
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    launches = launches or report["launches"]
    out = []
    if kind == "cfd":
        p = plot_cfd(launches, directory / "cfd_regressions.png", title_note, protect=protect)
        return [p] if p else []
    for axis in report["axes"]:
        for fn, name in ((plot_fits, "fits"), (plot_vs_reynolds, "vs_reynolds")):
            p = fn(launches, axis, directory / f"{kind}_{axis}_{name}.png", kind, title_note, protect=protect)
            if p:
                out.append(p)
    return out
