"""Local sensitivity: derivatives of closed-loop metrics with respect to every coefficient.

Central finite differences with step control, all runs through the sweep executor:

* step ``h_j = rel_step |p_j|`` (``rel_step (high - low)`` for a zero nominal), shrunk so that
  ``p_j - h_j >= 0.5 p_j`` (coefficients stay physical);
* two central differences, ``D(h)`` and ``D(h/2)``, combined by Richardson extrapolation
  ``D = (4 D(h/2) - D(h)) / 3`` (truncation error O(h^4)); ``fd_error = |D(h/2) - D(h)|`` estimates
  the error of the plain central difference and flags non-smooth metrics (a settling time that jumps
  between samples, a saturation onset): ``reliable`` is False when it exceeds 10 % of |D| (+ an
  absolute floor);
* one-at-a-time (OAT) runs at each parameter's ``low`` and ``high`` give the metric over the whole
  range (the bars of a tornado plot), which matters where the metric is not linear over the range.

Closed-loop metrics are smooth in the coefficients while the thrusters do not saturate and no
threshold-crossing (settling) time jumps; the Richardson check is how the tool tells.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.sensitivity.global_ import _metric_columns, _sweep, holds_study_lock
from udrobot_ctrl.sensitivity.results import write_table


@dataclass
class LocalResult:
    """Local derivatives around the nominal point.

    Attributes
    ----------
    names : list of str
        The parameters (``AXIS.QUANTITY``), in column order.
    nominal : (d,) ndarray
        Their nominal values, each in its parameter's unit.
    step : (d,) ndarray
        The larger FD step h_j (unit of the parameter).
    base : dict
        ``{metric: value at nominal}``.
    derivative, fd_error : dict
        ``{metric: (d,)}`` d metric / d p_j (metric unit per parameter unit) and its error estimate.
    elasticity : dict
        ``{metric: (d,)}`` (d metric / d p_j) p_j / metric: % change of the metric per % of the coefficient
        (NaN for a metric that is ~0 at the nominal point, below 5 % of its largest value over the ranges).
    low, high : dict
        ``{metric: (d,)}`` metric with parameter j at its range end, others nominal (OAT).
    bounds : (d, 2) ndarray
        Each parameter's range [low, high], its unit.
    n_runs : int
        Samples evaluated (1 + 6 d).
    wall_s : float
        Wall time of the sweep, s.
    runs : dict
        The sweep's table of runs (``sample_id``, metrics, ``error``), one row per evaluated sample.
    """

    names: list
    nominal: np.ndarray
    step: np.ndarray
    base: dict
    derivative: dict
    fd_error: dict
    elasticity: dict
    low: dict
    high: dict
    bounds: np.ndarray
    n_runs: int = 0
    wall_s: float = 0.0
    runs: dict = field(default_factory=dict)

    @property
    def metrics(self) -> list:
        return list(self.base)

    def reliable(self, metric: str, rtol: float = 0.1) -> np.ndarray:
        d = np.abs(self.derivative[metric])
        floor = 1e-9 * max(1.0, abs(self.base[metric]))
        return np.isfinite(d) & (self.fd_error[metric] <= rtol * d + floor)

    def range_effect(self, metric: str) -> np.ndarray:
        """Metric change from the low to the high end of each range (OAT), metric units."""
        return self.high[metric] - self.low[metric]

    def ranking(self, metric: str) -> list:
        """Parameters sorted by |range effect| (largest first)."""
        eff = np.nan_to_num(np.abs(self.range_effect(metric)), nan=-1.0)
        return [self.names[j] for j in np.argsort(-eff)]

    def table(self) -> dict:
        """Tidy table: one row per (metric, parameter)."""
        rows = {k: [] for k in ("metric", "parameter", "nominal", "low", "high", "step", "base", "derivative",
                                "fd_error", "reliable", "elasticity", "metric_at_low", "metric_at_high")}
        for m in self.metrics:
            rel = self.reliable(m)
            for j, name in enumerate(self.names):
                vals = (m, name, self.nominal[j], self.bounds[j, 0], self.bounds[j, 1], self.step[j], self.base[m],
                        self.derivative[m][j], self.fd_error[m][j], int(rel[j]), self.elasticity[m][j],
                        self.low[m][j], self.high[m][j])
                for k, v in zip(rows, vals):
                    rows[k].append(v)
        return rows


def fd_steps(nominal, bounds, rel_step: float = 1e-2) -> np.ndarray:
    """Finite-difference steps h_j (see module docstring)."""
    p = np.asarray(nominal, float)
    b = np.asarray(bounds, float)
    h = np.where(p != 0, rel_step * np.abs(p), rel_step * (b[:, 1] - b[:, 0]))
    return np.where(p > 0, np.minimum(h, 0.5 * p), h)


def local_design(nominal, bounds, step) -> np.ndarray:
    """Rows: nominal, then per parameter p+h, p-h, p+h/2, p-h/2, low, high (1 + 6 d rows)."""
    p = np.asarray(nominal, float)
    d = p.size
    rows = [p.copy()]
    for j in range(d):
        for value in (p[j] + step[j], p[j] - step[j], p[j] + step[j] / 2, p[j] - step[j] / 2,
                      bounds[j][0], bounds[j][1]):
            r = p.copy()
            r[j] = value
            rows.append(r)
    return np.array(rows)


@holds_study_lock
def local_sensitivity(evaluator, space, rel_step: float = 1e-2, executor=None, out=None, resume: bool = False,
                      progress: bool = True, chunk_size: int | None = None) -> LocalResult:
    """Derivatives of every metric of ``evaluator`` at the nominal point of ``space``.

    Parameters
    ----------
    evaluator : callable
        ``evaluator(X) -> {metric: (n,)}`` (see :mod:`udrobot_ctrl.sensitivity.executor`).
    space : ParameterSpace
        Parameters with ``nominal`` and ``bounds`` (or any object with ``names``, ``nominal``, ``bounds``).
    rel_step : float
        Relative FD step (default 1 %; the h/2 step is 0.5 %).
    executor : SweepExecutor, concurrent.futures.Executor or distributed.Client, optional
        Where the runs are evaluated (default: local processes on every CPU).
    out : path, optional
        Study directory (resumable); ``local.csv`` holds :meth:`LocalResult.table`.
    resume : bool
        Keep the runs already in ``out`` (same study) and evaluate only the others.
    progress : bool
        Show a progress bar.
    chunk_size : int, optional
        Samples per task (default :func:`~udrobot_ctrl.sensitivity.executor.default_chunk_size`).

    Returns
    -------
    LocalResult
        Richardson-extrapolated central derivatives (metric unit per parameter unit), their error estimates,
        elasticities and the one-at-a-time values at the range ends.
    """
    names = list(space.names)
    p = np.asarray(space.nominal, float)
    bounds = np.asarray(space.bounds, float)
    h = fd_steps(p, bounds, rel_step)
    X = local_design(p, bounds, h)
    desc = evaluator.describe() if hasattr(evaluator, "describe") else type(evaluator).__name__
    study = {"method": "local", "parameters": names, "bounds": bounds.tolist(), "rel_step": rel_step,
             "evaluator": desc}
    table, wall = _sweep(evaluator, X, executor, out, resume, study, names, progress, chunk_size, "local")
    d = len(names)
    base, der, err, ela, lo, hi = {}, {}, {}, {}, {}, {}
    for m in _metric_columns(table, names):
        Y = np.asarray(table[m], float)
        y0 = Y[0]
        Yr = Y[1:].reshape(d, 6)
        D1 = (Yr[:, 0] - Yr[:, 1]) / (2 * h)
        D2 = (Yr[:, 2] - Yr[:, 3]) / h
        base[m] = float(y0)
        der[m] = (4 * D2 - D1) / 3
        err[m] = np.abs(D2 - D1)
        # elasticity is meaningless for a metric that is ~0 at the nominal point (e.g. a speed error)
        meaningful = abs(y0) > 5e-2 * np.nanmax(np.abs(np.concatenate([Yr[:, 4], Yr[:, 5], [y0]])))
        with np.errstate(divide="ignore", invalid="ignore"):
            ela[m] = der[m] * p / y0 if meaningful else np.full(d, np.nan)
        lo[m], hi[m] = Yr[:, 4], Yr[:, 5]
    result = LocalResult(names, p, h, base, der, err, ela, lo, hi, bounds, X.shape[0], wall, table)
    if out is not None:
        write_table(f"{out}/local", result.table())
    return result
