"""Figures of a diagnosis: residuals per channel with the located windows shaded; simulated vs measured, with
an X where a replay window diverges (the rest of that window is scored at the error cap). Both hatch the replay
windows the report names outside the plant's domain (``replay_domain``: above the surface, inverted, a thruster
held at its limit), with their codes.

The replay columns of a channel (:data:`COLUMN`): the state for ``u v w p q r z phi theta psi``, the specific force
for the accelerometer ``ax ay az`` (scored on runs without a DVL), compared with the measurement minus the
accelerometer bias the smoother estimated.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from udrobot_ctrl.constants import STATE_INDEX
from udrobot_ctrl.dynamics.plant import wrap_angle
from udrobot_ctrl.gap.shrink import ACCEL, ANGLES, UNITS, accel_bias, diverged_samples, errors
from udrobot_files.output import save_figure

#: channel -> its column in a replay (:func:`udrobot_ctrl.gap.shrink.simulate_windows`)
COLUMN = {**STATE_INDEX, **{c: 12 + j for j, c in enumerate(ACCEL)}}


def measured(prep, c):
    """The measurement a replay's channel ``c`` is scored against: the logged value, the accelerometer minus the
    smoother's bias estimate (:func:`udrobot_ctrl.gap.shrink.accel_bias`)."""
    bias = accel_bias(prep)
    if c in ACCEL and bias is not None:
        return prep.meas[c] - bias[ACCEL.index(c)]
    return prep.meas[c]


def replayed(prep, sim, c):
    """A replay's channel ``c`` as the overlay draws it: the state or specific-force column, an angle drawn on the
    measurement's branch (measured + the wrapped error, as the gap scores it), so that a replay that integrated
    through +-pi and a logged angle that wrapped do not look 2 pi apart."""
    y = sim[:, COLUMN[c]]
    if c in ANGLES:
        m = measured(prep, c)
        return m + wrap_angle(y - m)
    return y


def divergence_starts(sim) -> np.ndarray:
    """Sample indices where a replay's window diverges: the first sample of each diverged stretch (the window
    column turns negative, :func:`udrobot_ctrl.gap.shrink.diverged_samples`)."""
    bad = diverged_samples(sim)
    return np.flatnonzero(bad & ~np.concatenate([[False], bad[:-1]]))


def located_windows(report) -> dict:
    """Run name -> [(t0, t1, channel), ...]: the worst windows of each located channel (the report's
    ``location``), in the run they were found in."""
    out = {}
    for loc in report["location"]:
        for a, b in loc.get("windows") or []:
            out.setdefault(loc["run"], []).append((a, b, loc["channel"]))
    return out


def domain_windows(report, which: str = "nominal") -> dict:
    """Run name -> [(t0, t1, codes), ...]: the replay windows the report names outside the plant's domain
    (``replay_domain``, ``which``: ``nominal`` or ``after``); empty when the report has none."""
    out = {}
    for w in ((report.get("replay_domain") or {}).get(which) or []):
        out.setdefault(w["run"], []).append((w["t"][0], w["t"][1], tuple(w["codes"])))
    return out


def shade_domain(axes, spans, color="red") -> None:
    """Hatch the windows ``spans`` [(t0, t1, codes)] on every axis of ``axes`` and name their codes on the first."""
    for ax in axes:
        for a, b, _ in spans:
            ax.axvspan(a, b, facecolor="none", edgecolor=color, hatch="//", alpha=0.5, lw=0)
    for a, b, codes in spans:
        axes[0].annotate(", ".join(codes), ((a + b) / 2, 0.02), xycoords=("data", "axes fraction"), ha="center",
                         va="bottom", fontsize=6, color=color)


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
    windows = located_windows(report)
    for prep, sim in zip(ctx.preps, ctx.nominal_sims):
        err = errors(prep, sim)
        chans = list(err)
        if not chans:
            continue
        spans = windows.get(prep.name, [])
        fig = Figure(figsize=(10, 1.6 * len(chans) + 1))
        axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], chans):
            ax.plot(prep.t, err[c], lw=0.7)
            ax.set_ylabel(f"{c} sim - meas\n({UNITS.get(c, '')})")
            for a, b, _ in spans:
                ax.axvspan(a, b, color="orange", alpha=0.35, lw=0)
        for a, b, c in spans:  # which located channel each window is the worst of
            axes[0, 0].annotate(c, ((a + b) / 2, 1.0), xycoords=("data", "axes fraction"), ha="center",
                                va="bottom", fontsize=7, color="darkorange")
        outside = domain_windows(report).get(prep.name, [])
        shade_domain(axes[:, 0], outside)
        axes[-1, 0].set_xlabel("t (s)")
        shaded = (f"the located channels' worst windows shaded: {', '.join(dict.fromkeys(c for *_, c in spans))}"
                  if spans else "no located window in this run")
        fig.suptitle(f"nominal model residuals, {prep.name} ({shaded})"
                     + (f"; hatched: {len(outside)} replay windows outside the plant's domain (scored, not a finding)"
                        if outside else ""))
        p = save_figure(fig, out / f"residuals_{file_label(prep.name)}.png", protect=protect, dpi=90)
        paths.append(p)
    n_fit = ctx.n_fit
    for prep, s0, s1 in zip(ctx.preps[n_fit:], ctx.nominal_sims[n_fit:], ctx.after_sims):
        chans = [c for c in report["gap_before"]["scored"] if c in prep.meas and c in COLUMN]
        if not chans:
            continue
        fig = Figure(figsize=(10, 1.6 * len(chans) + 1))
        axes = fig.subplots(len(chans), 1, sharex=True, squeeze=False)
        for ax, c in zip(axes[:, 0], chans):
            ax.plot(prep.t, measured(prep, c), "k.", ms=1.5,
                    label="measured" + (" (bias removed)" if c in ACCEL else ""))
            replays = [(s0, "nominal")] + ([(s1, "with significant effects")] if s1 is not s0 else [])
            for sim, label in replays:
                (line,) = ax.plot(prep.t, replayed(prep, sim, c), lw=0.8, label=label)
                starts = divergence_starts(sim)
                if starts.size:  # at the top edge: a diverged replay's values are off any useful scale
                    ax.plot(prep.t[starts], np.ones(starts.size), "X", ms=7, mec="k", color=line.get_color(),
                            transform=ax.get_xaxis_transform(), clip_on=False, zorder=4,
                            label=f"{label}: replay diverges ({starts.size} windows)")
            ax.set_ylabel(f"{c} ({UNITS.get(c, '')})")
        outside = {which: domain_windows(report, which).get(prep.name, []) for which in ("nominal", "after")}
        shade_domain(axes[:, 0], outside["nominal"], "red")
        if s1 is not s0:
            shade_domain(axes[:, 0], outside["after"], "purple")
        axes[0, 0].legend(loc="upper right", fontsize=7)
        axes[-1, 0].set_xlabel("t (s)")
        diverged = any(divergence_starts(sim).size for sim in (s0, s1))
        n_out = len(outside["nominal"]) + (len(outside["after"]) if s1 is not s0 else 0)
        fig.suptitle(f"holdout {prep.name}: multiple-shooting replay before/after"
                     + ("; X: a replay window diverges (the rest of the window is scored at the error cap)"
                        if diverged else "")
                     + (f"; hatched: windows outside the plant's domain (red nominal, purple corrected: {n_out})"
                        if n_out else ""))
        p = save_figure(fig, out / f"overlay_{file_label(prep.name)}.png", protect=protect, dpi=90)
        paths.append(p)
    return paths
