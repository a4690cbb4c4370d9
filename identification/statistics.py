"""Launch statistics: amplitude groups L1-L4, pairwise rank-sum tests, outliers, aggregation.

Pairwise test
-------------
Wilcoxon rank-sum (Mann-Whitney U) test, two-sided, normal approximation with continuity
correction and tie correction (MATLAB ``ranksum`` 'approximate'). This matches the structure of
Cely 2019 Tables 6, 8 and 9: with 6 vs 6 launches sigma_U = sqrt(6*6*13/12) = 6.245, and the
tables' z values are multiples of 0.5/6.245 (e.g. z = -0.240 <-> |U - 18| - 0.5 = 1.5, p = 0.8102;
z = 2.0016 <-> 12.5), which is what this test produces. z is reported with the sign of
(rank sum of the first group - its expectation).

Outlier rule
------------
Tukey's far-out fences on group-centred values: for each key coefficient, every launch's value
minus the median of its amplitude group (so a genuine amplitude/Reynolds dependence is not taken
for scatter) is divided by the launch's own standard error when every launch has one (small
launches are less precise: this makes the deviations comparable), pooled over the axis, and a
launch is rejected when its deviation lies outside
[Q1 - 3 IQR, Q3 + 3 IQR] of the pooled deviations (applied once, only with at least 5 launches).
The 1.5 IQR "outside" fences reject a quarter of clean 6-launch groups (simulated: 27 % of normal
samples of 6 have a point beyond them, 32 % for 24); the 3 IQR fences on 24 pooled deviations flag
1.5 % of clean axes per coefficient. The launch's results are kept in the report with the reason.

Aggregate
---------
With per-launch standard errors: inverse-variance weighted mean; its standard error is inflated
by the Birge ratio sqrt(chi2 / (n - 1)) when the launches scatter more than their own intervals
say (launch-to-launch variation the single-launch fit cannot see), and the 95 % interval uses
Student's t with n - 1 degrees of freedom. Without standard errors: mean +- t s / sqrt(n).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

LEVELS = {"spring": (0.010, 0.020, 0.030, 0.040), "pendulum": tuple(math.radians(a) for a in (2.5, 5, 10, 15))}


def amplitude_groups(amplitudes, levels) -> list:
    """Group label ``L1``.. for each launch amplitude: nearest protocol level in log scale."""
    lv = np.log(np.asarray(levels, float))
    out = []
    for a in amplitudes:
        if a is None or not np.isfinite(a) or a <= 0:
            out.append(None)
            continue
        out.append(f"L{int(np.argmin(np.abs(lv - math.log(a)))) + 1}")
    return out


def rank_sum_test(a, b) -> dict:
    """Two-sided Wilcoxon rank-sum test of samples ``a`` and ``b``.

    Returns
    -------
    dict
        ``p`` (two-sided p-value), ``z`` (continuity-corrected normal statistic), ``U`` (Mann-Whitney
        U of ``a``), ``n1``, ``n2``.
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    n1, n2 = a.size, b.size
    if n1 == 0 or n2 == 0:
        return {"p": None, "z": None, "U": None, "n1": n1, "n2": n2}
    ranks = stats.rankdata(np.concatenate([a, b]))
    r1 = float(np.sum(ranks[:n1]))
    U = r1 - n1 * (n1 + 1) / 2
    mu = n1 * n2 / 2
    _, counts = np.unique(np.concatenate([a, b]), return_counts=True)
    n = n1 + n2
    tie = float(np.sum(counts ** 3 - counts)) / (n * (n - 1)) if n > 1 else 0.0
    var = n1 * n2 / 12 * ((n + 1) - tie)
    if var <= 0:
        return {"p": 1.0, "z": 0.0, "U": U, "n1": n1, "n2": n2}
    d = U - mu
    z = (d - 0.5 * np.sign(d)) / math.sqrt(var)
    p = min(1.0, 2 * float(stats.norm.sf(abs(z))))
    return {"p": p, "z": float(z), "U": U, "n1": n1, "n2": n2}


def pairwise_tests(values, groups) -> list:
    """Rank-sum tests between every pair of amplitude groups (as in Tables 6, 8, 9)."""
    values = np.asarray(values, float)
    labels = sorted({g for g in groups if g is not None})
    out = []
    for i, gi in enumerate(labels):
        for gj in labels[i + 1:]:
            a = values[[g == gi for g in groups]]
            b = values[[g == gj for g in groups]]
            res = rank_sum_test(a[np.isfinite(a)], b[np.isfinite(b)])
            res.update({"groups": [gi, gj]})
            out.append(res)
    return out


def tukey_fences(values, k=1.5):
    """(low, high) Tukey fences of finite ``values``."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    q1, q3 = np.percentile(v, [25, 75])
    iqr = q3 - q1
    return float(q1 - k * iqr), float(q3 + k * iqr)


def outlier_reasons(table: dict, keys, k=3.0, min_n=5, groups: dict | None = None) -> dict:
    """Reasons to reject launches by Tukey's fences on group-centred values (see module docstring).

    Parameters
    ----------
    table : dict
        ``{launch_id: {coef: value}}``.
    keys : sequence of str
        Coefficients checked.
    k : float
        Fence multiple of the IQR (3 = Tukey's "far out").
    min_n : int
        No rejection with fewer launches.
    groups : dict, optional
        ``{launch_id: group}``; values are centred on their group's median first.

    Returns
    -------
    dict
        ``{launch_id: reason}`` for rejected launches.
    """
    reasons: dict = {}
    ids = list(table)
    if len(ids) < min_n:
        return reasons
    groups = groups or {}
    for key in keys:
        vals = np.array([table[i].get(key, np.nan) for i in ids], float)
        if np.sum(np.isfinite(vals)) < min_n:
            continue
        centre = np.zeros(vals.size)
        for g in {groups.get(i) for i in ids}:
            sel = np.array([groups.get(i) == g for i in ids]) & np.isfinite(vals)
            if sel.any():
                centre[sel] = np.median(vals[sel])
        se = np.array([table[i].get(key + "_se", np.nan) for i in ids], float)
        scaled = bool(np.all(np.isfinite(se[np.isfinite(vals)]) & (se[np.isfinite(vals)] > 0)))
        dev = (vals - centre) / se if scaled else vals - centre
        unit = " standard errors" if scaled else ""
        lo, hi = tukey_fences(dev, k)
        for i, v, d, c in zip(ids, vals, dev, centre):
            if np.isfinite(d) and not lo <= d <= hi:
                msg = (f"outlier: {key} = {v:.4g} is {d:+.3g}{unit} from its group median {c:.4g}, outside Tukey "
                       f"fences [{lo:.3g}, {hi:.3g}] ({k:g} IQR of the axis's group-centred values)")
                reasons[i] = reasons[i] + "; " + msg if i in reasons else msg
    return reasons


def aggregate(values, se=None) -> dict:
    """Combine per-launch values into a value with a 95 % interval (see module docstring).

    Returns
    -------
    dict
        ``value``, ``ci95`` [lo, hi], ``se``, ``n``, ``method`` and, when weighted, ``birge_ratio``.
    """
    v = np.asarray(values, float)
    ok = np.isfinite(v)
    if se is not None:
        s = np.asarray(se, float)
        ok &= np.isfinite(s) & (s > 0)
    v = v[ok]
    n = v.size
    if n == 0:
        return {"value": None, "ci95": None, "se": None, "n": 0, "method": "none"}
    if n == 1:
        if se is None:
            return {"value": float(v[0]), "ci95": None, "se": None, "n": 1, "method": "single"}
        s1 = float(s[ok][0])
        return {"value": float(v[0]), "ci95": [float(v[0] - 1.96 * s1), float(v[0] + 1.96 * s1)], "se": s1,
                "n": 1, "method": "single launch (its own interval)"}
    q = float(stats.t.ppf(0.975, n - 1))
    if se is None:
        m = float(np.mean(v))
        e = float(np.std(v, ddof=1) / math.sqrt(n))
        return {"value": m, "ci95": [m - q * e, m + q * e], "se": e, "n": n, "method": "mean, t interval"}
    w = 1.0 / s[ok] ** 2
    m = float(np.sum(w * v) / np.sum(w))
    chi2 = float(np.sum(w * (v - m) ** 2))
    birge = math.sqrt(max(chi2 / (n - 1), 1.0))
    e = birge / math.sqrt(float(np.sum(w)))
    return {"value": m, "ci95": [m - q * e, m + q * e], "se": e, "n": n,
            "method": "inverse-variance weighted mean, Birge-inflated, t interval", "birge_ratio": birge}
