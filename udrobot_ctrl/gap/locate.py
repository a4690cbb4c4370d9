"""Locate the gap: which channels, which operating regime, which time windows and frequency band hold it.

Inputs are the nominal model's multiple-shooting errors (:mod:`udrobot_ctrl.gap.shrink`) and equation-error
residuals. The *share* of a channel is its part of the sum over channels of (error / channel scale)^2. Within
a channel, each regime family (horizontal speed, thrust level, distance to the nearest surface, depth) is
binned and the bin whose error share most exceeds its share of the time is reported as the condition.
Windows are the stretches where the error energy (2 s moving average) exceeds twice its mean.
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.gap.shrink import errors

SPEED_BINS = (0.0, 0.1, 0.25, 0.5, 1.0, np.inf)
THRUST_BINS = (0.0, 0.1, 0.3, 0.6, np.inf)
DIST_BINS = (0.0, 0.3, 0.6, 1.0, 2.0, np.inf)
FREQ_BANDS = ((0.0, 0.05), (0.05, 0.5), (0.5, np.inf))


def _regimes(prep):
    nu = np.where(np.isfinite(prep.nu), prep.nu, np.nan)
    out = {"horizontal speed": (np.hypot(nu[:, 0], np.nan_to_num(nu[:, 1])), SPEED_BINS, "m/s"),
           "thrust level (fraction of maximum)": (np.max(np.abs(prep.f) / prep.f_ref, axis=1), THRUST_BINS, ""),
           "depth": (prep.eta[:, 2], (-np.inf, 0.5, 1.0, 2.0, 4.0, np.inf), "m")}
    if prep.surfaces:
        d = np.min(np.column_stack([s[0] for s in prep.surfaces]), axis=1)
        out["distance to the nearest wall/seabed"] = (d, DIST_BINS, "m")
    return out


def _bin_label(lo, hi, unit):
    if not np.isfinite(lo):
        return f"below {hi:g} {unit}".strip()
    if not np.isfinite(hi):
        return f"above {lo:g} {unit}".strip()
    return f"{lo:g}-{hi:g} {unit}".strip()


def _windows(t, e2, dt, max_windows=5):
    k = max(1, int(round(2.0 / dt)))
    y = np.convolve(np.nan_to_num(e2), np.ones(k) / k, mode="same")
    mean = np.nanmean(y) if np.isfinite(y).any() else 0
    hot = y > 2 * mean
    d = np.diff(np.concatenate([[0], hot.astype(int), [0]]))
    segs = [(a, b) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)) if b - a > 1]
    segs.sort(key=lambda ab: -np.nansum(e2[ab[0]:ab[1]]))
    return sorted([[round(float(t[a]), 2), round(float(t[b - 1]), 2)] for a, b in segs[:max_windows]])


def frequency_shares(res, dt):
    """Share of the residual power (per DOF column) in the bands of FREQ_BANDS (Hz)."""
    out = {}
    r = np.nan_to_num(res - np.nanmean(res, axis=0))
    P = np.abs(np.fft.rfft(r, axis=0)) ** 2
    fr = np.fft.rfftfreq(r.shape[0], dt)
    tot = P.sum(axis=0) + 1e-300
    for lo, hi in FREQ_BANDS:
        sel = (fr >= lo) & (fr < hi)
        out[_bin_label(lo, hi, "Hz")] = (P[sel].sum(axis=0) / tot)
    return out


def locate(preps, sims, scale, residuals=None, min_share=0.1):
    """Where the nominal model disagrees with the runs.

    Parameters
    ----------
    preps, sims : lists
        Prepared runs and their nominal multiple-shooting simulations.
    scale : dict
        Channel -> normalising scale (std of the measurement).
    residuals : list of (n, 6) arrays, optional
        Equation-error residuals per run (for the frequency bands).

    Returns
    -------
    location : list of dict
        ``{"channel", "share", "condition", "windows", "run", "regimes"}`` for channels with share >= min_share.
    detail : dict
        Channel shares, per-run shares and frequency-band shares.
    """
    energy = {}
    per_run = {}
    for prep, sim in zip(preps, sims):
        for c, e in errors(prep, sim).items():
            if c not in scale or scale[c] <= 0:
                continue
            e2 = (e / scale[c]) ** 2
            s = float(np.nansum(e2))
            energy[c] = energy.get(c, 0.0) + s
            per_run.setdefault(c, []).append((s, prep, e2))
    total = sum(energy.values()) or 1.0
    shares = {c: v / total for c, v in sorted(energy.items(), key=lambda kv: -kv[1])}
    location = []
    for c, sh in shares.items():
        if sh < min_share:
            continue
        best_run = max(per_run[c], key=lambda x: x[0])
        regimes = {}
        cond = None
        best_excess = 0.0
        for fam in _regimes(best_run[1]):
            num, den = {}, {}
            for _s, prep, e2 in per_run[c]:
                vals, bins, unit = _regimes(prep)[fam]
                ok = np.isfinite(e2) & np.isfinite(vals)
                for lo, hi in zip(bins[:-1], bins[1:]):
                    sel = ok & (vals >= lo) & (vals < hi)
                    lab = _bin_label(lo, hi, unit)
                    num[lab] = num.get(lab, 0.0) + float(np.sum(e2[sel]))
                    den[lab] = den.get(lab, 0) + int(sel.sum())
            tn, td = sum(num.values()) or 1.0, sum(den.values()) or 1
            regimes[fam] = {lab: {"error_share": round(num[lab] / tn, 3), "time_share": round(den[lab] / td, 3)}
                            for lab in num if den[lab] > 0}
            for lab, v in regimes[fam].items():
                excess = v["error_share"] - v["time_share"]
                if v["error_share"] >= 0.3 and excess > best_excess:
                    best_excess = excess
                    cond = (f"{fam} {lab} (holds {100 * v['error_share']:.0f}% of the {c} error in "
                            f"{100 * v['time_share']:.0f}% of the time)")
        location.append({"channel": c, "share": round(sh, 3),
                         "condition": cond or "spread over all regimes (no regime concentrates it)",
                         "windows": _windows(best_run[1].t, best_run[2], best_run[1].dt), "run": best_run[1].name,
                         "regimes": regimes})
    detail = {"channel_share": {c: round(v, 3) for c, v in shares.items()}}
    if residuals:
        dofs = ("X", "Y", "Z", "K", "M", "N")
        acc = {}
        for prep, res in zip(preps, residuals):
            fs = frequency_shares(res, prep.dt)
            for band, arr in fs.items():
                acc.setdefault(band, []).append(arr)
        detail["residual_frequency_share"] = {
            band: {d: round(float(np.mean([a[i] for a in arrs])), 3) for i, d in enumerate(dofs)}
            for band, arrs in acc.items()}
    return location, detail
