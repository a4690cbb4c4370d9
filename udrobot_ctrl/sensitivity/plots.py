"""Plots of sensitivity results: tornado (local / one-at-a-time) and Sobol / Morris index bars with CIs.

Every function returns a matplotlib Figure (object API: no pyplot, no backend switch) and saves it when ``path`` is
given.
"""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from udrobot_files.output import save_figure


def tornado(local_result, metric: str, top: int | None = 12, path=None, unit: str = "", title: str | None = None):
    """Tornado plot: metric with each coefficient at the low / high end of its range, others nominal.

    Bars are sorted by the size of the swing; the vertical line is the nominal metric. Parameters whose
    finite-difference derivative is flagged unreliable (non-smooth metric) are marked with ``*``.

    Parameters
    ----------
    local_result : LocalResult
        A local study (:func:`~udrobot_ctrl.sensitivity.local.local_sensitivity`).
    metric : str
        The metric plotted.
    top : int, optional
        Plot only the ``top`` largest swings (all when None).
    path : str or Path, optional
        Save the figure there (atomically).
    unit : str
        The metric's unit, for the axis label.
    title : str, optional
        Figure title (default: the metric and its nominal value).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    r = local_result
    base = r.base[metric]
    lo, hi = np.asarray(r.low[metric]), np.asarray(r.high[metric])
    order = np.argsort(-np.nan_to_num(np.abs(hi - lo), nan=-1.0))
    if top:
        order = order[:top]
    order = order[::-1]
    rel = r.reliable(metric)
    labels = [r.names[j] + ("" if rel[j] else " *") for j in order]
    fig = Figure(figsize=(7, 0.35 * len(order) + 1.5))
    ax = fig.subplots()
    y = np.arange(len(order))
    ax.barh(y, lo[order] - base, left=base, color="tab:blue", label="coefficient at range low")
    ax.barh(y, hi[order] - base, left=base, color="tab:orange", alpha=0.8, label="coefficient at range high")
    ax.axvline(base, color="k", lw=1)
    ax.set_yticks(y, labels)
    ax.set_xlabel(f"{metric}{f' ({unit})' if unit else ''}")
    ax.set_title(title or f"{metric}: nominal {base:.4g} (* = non-smooth)")
    ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    if path:
        save_figure(fig, path, dpi=120)
    return fig


def sobol_bars(global_result, metric: str, top: int | None = 12, path=None, title: str | None = None):
    """Bar plot of first-order (S1) and total (ST) Sobol indices with their confidence intervals.

    A Morris result is drawn as mu* (with its interval) and sigma.

    Parameters
    ----------
    global_result : GlobalResult
        A Sobol or Morris study (:func:`~udrobot_ctrl.sensitivity.global_.run_sobol`, ``run_morris``).
    metric : str
        The metric plotted.
    top : int, optional
        Plot only the ``top`` most important parameters (all when None).
    path : str or Path, optional
        Save the figure there (atomically).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    r = global_result
    idx = r.indices[metric]
    if r.method == "morris":
        keys = (("mu_star", "mu_star_conf", "mu*"), ("sigma", None, "sigma"))
    else:
        keys = (("S1", "S1_conf", "S1 (first order)"), ("ST", "ST_conf", "ST (total)"))
    main = np.nan_to_num(np.asarray(idx[keys[1][0] if r.method == "sobol" else keys[0][0]]), nan=-1.0)
    order = np.argsort(-main)
    if top:
        order = order[:top]
    x = np.arange(len(order))
    fig = Figure(figsize=(max(6, 0.6 * len(order) + 2), 4))
    ax = fig.subplots()
    w = 0.38
    for k, (key, conf, label) in enumerate(keys):
        vals = np.asarray(idx[key])[order]
        err = np.asarray(idx[conf])[order] if conf else None
        ax.bar(x + (k - 0.5) * w, vals, w, yerr=err, capsize=3, label=label)
    ax.set_xticks(x, [r.names[j] for j in order], rotation=40, ha="right")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_ylabel("Sobol index (share of the variance of " + metric + ", -)" if r.method == "sobol"
                  else f"Morris mu*, sigma (units of {metric})")
    ax.set_title(title or f"{r.method.capitalize()} indices of {metric} ({int(r.conf_level * 100)} % CI, "
                 f"{r.n_runs} runs)")
    ax.legend(fontsize="small")
    fig.tight_layout()
    if path:
        save_figure(fig, path, dpi=120)
    return fig
