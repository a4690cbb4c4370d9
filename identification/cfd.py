"""CFD force-speed regressions (Cely 2019 sec. 4.1, Table 5).

A steady CFD run at inflow speed u gives the drag force F on the body. Two regressions through the
origin are fitted per axis:

* Chin form: F = K_L u + K_Q |u| u  (K_L in N s/m, K_Q in N s^2/m^2);
* Morison-only form: F = K_D |u| u with K_D = 1/2 rho C_D A, so C_D = 2 K_D / (rho A)
  for the projected area A (m^2) the drag coefficient refers to.

Both are ordinary least squares without intercept (a body at rest feels no drag). R^2 is reported
in the centred form 1 - SS_res / sum (F - mean F)^2, which is what a spreadsheet trend line through
the origin reports and what the paper's Table 5 lists; the uncentred form
1 - SS_res / sum F^2 is also returned (``r2_uncentred``) because it is the one that is bounded in
[0, 1] for a regression through the origin. 95 % intervals come from the OLS covariance with
Student's t on n - p degrees of freedom. Steady CFD carries no added mass.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from identification.decay import LaunchError, read_csv_rows

MIN_POINTS = 3


@dataclass
class ForceTable:
    """One axis of CFD results: inflow speed (m/s) and drag force (N), same sign convention.

    Attributes
    ----------
    path : str
        Source file.
    speed : ndarray
        Inflow speed u, m/s.
    force : ndarray
        Drag force F, N (same sign as u).
    """

    path: str
    speed: np.ndarray
    force: np.ndarray


def read_force_table(path) -> ForceTable:
    """Read a ``speed,force`` CSV (m/s, N); errors name the file, row and field.

    Parameters
    ----------
    path : str or Path
        The CSV.

    Returns
    -------
    ForceTable
        The speeds (m/s) and forces (N).
    """
    cols, _ = _read(path)
    return ForceTable(str(path), cols["speed"], cols["force"])


def _read(path):
    """Like :func:`identification.decay.read_columns` but without the time-ordering rule."""
    import math

    path = Path(path)
    numbered = read_csv_rows(path)
    if not numbered:
        raise LaunchError(path, "empty file (expected a header speed,force and data rows)")
    line, head = numbered[0]
    header = [h.strip().lower() for h in head]
    if "speed" not in header or "force" not in header:
        raise LaunchError(path, f"header {','.join(header)!r} lacks the expected columns speed,force", row=line)
    idx = {c: header.index(c) for c in ("speed", "force")}
    data = {"speed": [], "force": []}
    lines = []
    for line, r in numbered[1:]:
        lines.append(line)
        for c, k in idx.items():
            if k >= len(r) or not r[k].strip():
                raise LaunchError(path, "missing value", row=line, field=c)
            try:
                v = float(r[k])
            except ValueError:
                raise LaunchError(path, f"{r[k].strip()!r} is not a number", row=line, field=c) from None
            if not math.isfinite(v):
                raise LaunchError(path, f"non-finite value {r[k].strip()!r} (NaN/inf)", row=line, field=c)
            data[c].append(v)
    speed, force = np.array(data["speed"]), np.array(data["force"])
    if speed.size < MIN_POINTS:
        raise LaunchError(path, f"only {speed.size} data rows, need at least {MIN_POINTS} speeds")
    if np.unique(np.abs(speed)).size < 2 or np.all(speed == 0):
        raise LaunchError(path, "need at least two distinct nonzero speeds to separate K_L from K_Q", field="speed")
    check_drag(path, speed, force, lines)
    return {"speed": speed, "force": force}, "speed"


def check_drag(path, speed, force, lines) -> None:
    """Reject a table that is not a drag curve: the force must oppose the flow (same sign as the inflow speed,
    nonzero) and its magnitude must increase with the speed (steady drag is monotonic in |u|).

    Raises
    ------
    LaunchError
        Naming the file, the row (file line) and the reason.
    """
    moving = speed != 0
    bad = np.flatnonzero(moving & ~(force * np.sign(speed) > 0))
    if bad.size:
        k = int(bad[0])
        what = "zero" if force[k] == 0 else "of the opposite sign to the speed"
        raise LaunchError(path, f"force {force[k]:g} N at speed {speed[k]:g} m/s is {what}; a drag table needs "
                          f"a force along the inflow (same sign as the speed, nonzero) at every nonzero speed",
                          row=lines[k], field="force")
    order = np.argsort(np.abs(speed), kind="stable")
    u, f = np.abs(speed[order]), np.abs(force[order])
    for a, b in zip(range(u.size - 1), range(1, u.size)):
        if u[b] > u[a] and not f[b] > f[a]:
            ia, ib = int(order[a]), int(order[b])
            raise LaunchError(path, f"|force| {f[b]:g} N at |speed| {u[b]:g} m/s (row {lines[ib]}) is not above "
                              f"{f[a]:g} N at {u[a]:g} m/s (row {lines[ia]}); drag must increase with speed "
                              f"(a constant or falling force is not a drag curve)", row=lines[ib], field="force")


def _ols(X, y):
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    n, p = X.shape
    dof = max(n - p, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(X.T @ X)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    q = float(stats.t.ppf(0.975, dof))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    ss_unc = float(y @ y)
    rss = float(r @ r)
    return coef, se, q, {"r2": 1 - rss / ss_tot if ss_tot > 0 else float("nan"),
                         "r2_uncentred": 1 - rss / ss_unc if ss_unc > 0 else float("nan"),
                         "rms_residual": float(np.sqrt(rss / n)), "n": int(n)}


def chin_regression(speed, force) -> dict:
    """Fit F = K_L u + K_Q |u| u.

    Parameters
    ----------
    speed : array_like
        Inflow speed u, m/s.
    force : array_like
        Drag force F, N (same sign as u).

    Returns
    -------
    dict
        ``KL`` (N s/m), ``KQ`` (N s^2/m^2), their ``*_se`` and ``*_ci95``, ``r2``, ``r2_uncentred``,
        ``rms_residual`` (N), ``n``.
    """
    u = np.asarray(speed, float)
    f = np.asarray(force, float)
    coef, se, q, fit = _ols(np.column_stack([u, np.abs(u) * u]), f)
    out = {}
    for k, c, s in zip(("KL", "KQ"), coef, se):
        out[k], out[k + "_se"], out[k + "_ci95"] = float(c), float(s), [float(c - q * s), float(c + q * s)]
    out.update(fit)
    return out


def morison_regression(speed, force, area=None, rho=1000.0) -> dict:
    """Fit F = K_D |u| u and, given the projected area, C_D = 2 K_D / (rho A).

    Parameters
    ----------
    speed, force : array_like
        m/s and N.
    area : float, optional
        Projected area A, m^2.
    rho : float
        Water density, kg/m^3.

    Returns
    -------
    dict
        ``KD`` (N s^2/m^2) with ``KD_se``/``KD_ci95``; ``CD`` likewise when ``area`` is given; ``r2``...
    """
    u = np.asarray(speed, float)
    f = np.asarray(force, float)
    coef, se, q, fit = _ols((np.abs(u) * u)[:, None], f)
    kd, s = float(coef[0]), float(se[0])
    out = {"KD": kd, "KD_se": s, "KD_ci95": [kd - q * s, kd + q * s]}
    if area is not None:
        if not area > 0:
            raise ValueError(f"projected area must be positive (m^2), got {area}")
        c = 2.0 / (rho * area)
        out.update({"CD": kd * c, "CD_se": s * c, "CD_ci95": [(kd - q * s) * c, (kd + q * s) * c]})
    out.update(fit)
    return out


def identify_table(table: ForceTable, area=None, rho=1000.0) -> dict:
    """Both regressions for one axis, in the layout of Table 5 (Chin at top level, Morison under ``morison``).

    Parameters
    ----------
    table : ForceTable
        The axis's CFD results.
    area : float, optional
        Projected area A, m^2 (for C_D).
    rho : float
        Water density, kg/m^3.

    Returns
    -------
    dict
        :func:`chin_regression`'s fields (``KL`` N s/m, ``KQ`` N s^2/m^2 ...) and ``morison``:
        :func:`morison_regression`'s.
    """
    chin = chin_regression(table.speed, table.force)
    mor = morison_regression(table.speed, table.force, area, rho)
    out = dict(chin)
    out["KD"] = mor["KD"]
    out["KD_ci95"] = mor["KD_ci95"]
    if "CD" in mor:
        out["CD"], out["CD_se"], out["CD_ci95"] = mor["CD"], mor["CD_se"], mor["CD_ci95"]
    out["morison"] = mor
    out["speed_range"] = [float(np.min(np.abs(table.speed))), float(np.max(np.abs(table.speed)))]
    return out


def synthetic_table(KL, KQ, speeds=None, noise=0.0, rng=None) -> tuple[np.ndarray, np.ndarray]:
    """Force table F = K_L u + K_Q |u| u (+ relative Gaussian noise) for tests and the demo.

    ``speeds`` default: 0.2, 0.5 and 1 to 10 m/s in 1 m/s steps — the range Cely 2019 sec. 3.4 states
    (0.2-10 m/s); the individual speeds are assumed (the paper does not list them).
    """
    u = np.r_[0.2, 0.5, np.arange(1.0, 10.01, 1.0)] if speeds is None else np.asarray(speeds, float)
    f = KL * u + KQ * np.abs(u) * u
    if noise:
        rng = rng or np.random.default_rng(0)
        f = f * (1 + noise * rng.standard_normal(u.size))
    return u, f
