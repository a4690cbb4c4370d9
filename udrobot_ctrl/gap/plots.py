"""Figures of a diagnosis: residuals per channel with located windows shaded; simulated vs measured."""
from __future__ import annotations

import re
from pathlib import Path

from matplotlib.figure import Figure

from udrobot_ctrl.gap.shrink import errors
from udrobot_ctrl.io.files import save_figure
from udrobot_ctrl.vehicle import STATE_INDEX

# units of the state channels (udrobot-run/1): positions m, angles rad, velocities m/s and rad/s
UNITS = {"x": "m", "y": "m", "z": "m", "phi": "rad", "theta": "rad", "psi": "rad", "u": "m/s", "v": "m/s",
         "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s"}


def file_label(run_name: str) -> str:
    """File-name-safe label of a run name: ``pool.csv[last third]`` -> ``pool_last_third``."""
    label = re.sub(r"\.(csv|json|bag|mcap|db3|tlog|bin)(?=\[|$)", "", run_name, flags=re.IGNORECASE)
    return re.sub(r"[^\w.-]+", "_", label).strip("_.") or "run"


def plot_paths(outdir, fit_names, holdout_names) -> list:
    """The figures :func:`write_plots` will write for these run names (checked before the diagnosis runs)."""
    out = Path(outdir)
    return ([out / f"residuals_{file_label(n)}.png" for n in [*fit_names, *holdout_names]]
            + [out / f"overlay_{file_label(n)}.png" for n in holdout_names])


def write_plots(ctx, report, outdir, protect=()):
    """Write residuals_<run>.png (all runs) and overlay_<run>.png (holdout runs, before/after); returns paths."""

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    windows = {}
    for loc in report["location"]:
        windows.setdefault(loc["run"], []).extend(loc["windows"])
    for prep, sim in zip(ctx.preps, ctx.nominal_sims):
        err = errors(prep, sim)
        chans = list(err)
        fig = Figure(figsize=(10, 1.6 * len(chans) + 1))
        axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], chans):
            ax.plot(prep.t, err[c], lw=0.7)
            ax.set_ylabel(f"{c} sim - meas\n({UNITS.get(c, '')})")
            for a, b in windows.get(prep.name, []):
                ax.axvspan(a, b, color="orange", alpha=0.25)
        axes[-1, 0].set_xlabel("t (s)")
        fig.suptitle(f"nominal model residuals, {prep.name} (located windows shaded)")
        p = save_figure(fig, out / f"residuals_{file_label(prep.name)}.png", protect=protect, dpi=90)
        paths.append(p)
    n_fit = ctx.n_fit
    for prep, s0, s1 in zip(ctx.preps[n_fit:], ctx.nominal_sims[n_fit:], ctx.after_sims):
        chans = [c for c in report["gap_before"]["scored"] if c in prep.meas]
        if not chans:
            continue
        fig = Figure(figsize=(10, 1.6 * len(chans) + 1))
        axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], chans):
            ax.plot(prep.t, prep.meas[c], "k.", ms=1.5, label="measured")
            ax.plot(prep.t, s0[:, STATE_INDEX[c]], lw=0.8, label="nominal")
            if s1 is not s0:
                ax.plot(prep.t, s1[:, STATE_INDEX[c]], lw=0.8, label="with significant effects")
            ax.set_ylabel(f"{c} ({UNITS.get(c, '')})")
        axes[0, 0].legend(loc="upper right", fontsize=7)
        axes[-1, 0].set_xlabel("t (s)")
        fig.suptitle(f"holdout {prep.name}: multiple-shooting replay before/after")
        p = save_figure(fig, out / f"overlay_{file_label(prep.name)}.png", protect=protect, dpi=90)
        paths.append(p)
    return paths
