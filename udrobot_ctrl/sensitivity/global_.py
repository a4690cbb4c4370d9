"""Global sensitivity: Sobol (Saltelli/Sobol' sampling) and Morris elementary effects, via SALib.

Both run their model evaluations through :func:`~udrobot_ctrl.sensitivity.executor.run_sweep`, so they use
local processes or a dask cluster and resume from a study directory.

Sample counts (SALib 1.6 ``sample.sobol``): a base sample of ``N`` points (a power of 2) gives
``N (d + 2)`` model runs for first and total indices, ``N (2 d + 2)`` with second-order indices.
Morris with ``r`` trajectories gives ``r (d + 1)`` runs.

Reproducibility: the same ``seed`` (0 included) gives the same design *and* the same bootstrap intervals
(SALib's Sobol analysis treats an int seed 0 as "no seed", so the seed is passed as a
``numpy.random.Generator``). A study with an ``out`` folder holds the folder's lock for the whole call
(:class:`~udrobot_ctrl.sensitivity.results.StudyLock`).

Small samples: Sobol indices lie in [0, 1]; :attr:`GlobalResult.warnings` (also issued as a
``RuntimeWarning``) flags a base sample below :data:`SOBOL_MIN_N` and any metric whose interval half-width
exceeds :data:`SOBOL_MAX_CONF` (then the interval spans more than half the index range and the
ranking means little).
"""
from __future__ import annotations

import functools
import inspect
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.sensitivity.executor import as_executor, run_sweep
from udrobot_ctrl.sensitivity.results import ResultStore, StudyLock, write_table

#: assumed: below N = 64 base samples the bootstrap interval of an index is typically wider than its range
SOBOL_MIN_N = 64
#: assumed: an interval half-width above 0.5 spans more than half of the [0, 1] index range
SOBOL_MAX_CONF = 0.5


def holds_study_lock(fn):
    """Run ``fn`` holding the lock of its ``out`` study folder (keyword argument) for the whole call."""
    sig = inspect.signature(fn)

    @functools.wraps(fn)
    def run(*args, **kwargs):
        out = sig.bind(*args, **kwargs).arguments.get("out")
        if out is None:
            return fn(*args, **kwargs)
        with StudyLock(out):
            return fn(*args, **kwargs)
    return run


@dataclass
class GlobalResult:
    """Indices of every metric plus the raw sweep.

    Attributes
    ----------
    method : {'sobol', 'morris'}
        The study's method.
    names : list of str
        Parameter names.
    indices : dict
        ``{metric: {index: (d,) array}}``: Sobol ``S1 S1_conf ST ST_conf`` (and ``S2``), Morris
        ``mu mu_star mu_star_conf sigma``. Conf entries are half-widths of the ``conf_level`` bootstrap
        interval.
    table : dict
        Tidy sweep table (one row per model run).
    n_runs : int
        Model runs evaluated.
    wall_s : float
        Wall time of the sweep (s).
    failed : dict
        ``{metric: number of runs with a NaN}``; indices of such metrics are NaN.
    conf_level : float
        Confidence level of the bootstrap intervals (a probability, 0.95).
    warnings : list of str
        Why the indices may be uninformative (small base sample, wide intervals; :func:`sobol_warnings`).
    """

    method: str
    names: list
    indices: dict
    table: dict
    n_runs: int
    wall_s: float
    failed: dict = field(default_factory=dict)
    conf_level: float = 0.95
    warnings: list = field(default_factory=list)

    @property
    def metrics(self) -> list:
        return list(self.indices)

    def indices_table(self) -> dict:
        """Tidy table: one row per (metric, parameter) with every index as a column."""
        rows = {"metric": [], "parameter": []}
        keys = sorted({k for v in self.indices.values() for k in v if k != "S2"})
        for k in keys:
            rows[k] = []
        for metric, idx in self.indices.items():
            for j, name in enumerate(self.names):
                rows["metric"].append(metric)
                rows["parameter"].append(name)
                for k in keys:
                    rows[k].append(float(idx[k][j]) if k in idx else np.nan)
        return rows

    def ranking(self, metric: str, key: str | None = None) -> list:
        """Parameters sorted by importance for ``metric`` (ST for Sobol, mu_star for Morris)."""
        key = key or ("ST" if self.method == "sobol" else "mu_star")
        v = np.nan_to_num(np.asarray(self.indices[metric][key], float), nan=-np.inf)
        return [self.names[j] for j in np.argsort(-v)]


def _problem(space_or_problem) -> dict:
    if isinstance(space_or_problem, dict):
        return space_or_problem
    return space_or_problem.salib_problem()


def _study(method, problem, evaluator, **kw) -> dict:
    desc = evaluator.describe() if hasattr(evaluator, "describe") else type(evaluator).__name__
    return {"method": method, "parameters": problem["names"], "bounds": problem["bounds"], "evaluator": desc, **kw}


def _sweep(evaluator, X, executor, out, resume, study, names, progress, chunk_size, desc):
    ex = as_executor(executor)
    own = ex is not executor
    store = None
    try:
        store = ResultStore(out, study, X, names, resume=resume) if out is not None else None
        t0 = time.perf_counter()
        table = run_sweep(evaluator, X, executor=ex, store=store, chunk_size=chunk_size, progress=progress, desc=desc)
        wall = time.perf_counter() - t0
        if store is not None:
            table = store.consolidate()
    finally:
        if store is not None:
            store.close()
        if own:
            ex.close()
    done = len(table.get("sample_id", ())) if table else 0
    if done < X.shape[0]:
        kept = f"; the finished runs are kept in {out}: --resume computes the others" if out is not None else ""
        raise StudyIncompleteError(f"{desc} study incomplete: {done} of the {X.shape[0]} requested runs were "
                                   f"evaluated{kept}")
    return table, wall


class StudyIncompleteError(ValueError):
    """A sweep that evaluated fewer runs than its design asked for: no indices are computed from it."""


def _metric_columns(table, names) -> list:
    skip = {"sample_id", "error", *names}
    return [k for k in table if k not in skip and np.asarray(table[k]).dtype != object]


def sobol_samples(problem: dict, N: int, seed: int = 0, second_order: bool = False) -> np.ndarray:
    """Saltelli/Sobol' design of ``N (d + 2)`` (or ``N (2 d + 2)``) rows; ``N`` must be a power of 2."""
    from SALib.sample import sobol as sobol_sample

    if N < 2 or N & (N - 1):
        raise ValueError(f"Sobol base sample N must be a power of 2 >= 2, got {N}")
    return sobol_sample.sample(problem, N, calc_second_order=second_order, scramble=True, seed=seed)


def sobol_warnings(N: int, indices: dict) -> list:
    """Why Sobol indices of a study may be uninformative: a small base sample, too wide intervals."""
    out = []
    if N < SOBOL_MIN_N:
        out.append(f"base sample N = {N} < {SOBOL_MIN_N}: bootstrap intervals of the indices are typically wider "
                   f"than their [0, 1] range; use N >= {SOBOL_MIN_N} (the interval shrinks like 1/sqrt(N))")
    for metric, idx in indices.items():
        conf = np.concatenate([np.ravel(idx.get("S1_conf", [])), np.ravel(idx.get("ST_conf", []))])
        conf = conf[np.isfinite(conf)]
        if conf.size and conf.max() > SOBOL_MAX_CONF:
            out.append(f"{metric}: confidence half-width up to {conf.max():.2f} (> {SOBOL_MAX_CONF}); its indices "
                       "are not resolved, increase N (or use --rank for a heavy-tailed metric)")
    return out


def _sobol_ratio(num, y_var):
    """SALib's normalisation of an estimator by the sample variance (0 where the variance is ~0)."""
    return np.divide(num, y_var, out=np.zeros_like(y_var, dtype=np.float64), where=y_var > np.finfo(float).eps)


def sobol_first_total(problem: dict, Y, num_resamples: int = 100, conf_level: float = 0.95, seed=None) -> dict:
    """``SALib.analyze.sobol.analyze(problem, Y, calc_second_order=False, ...)``: the same numbers, faster.

    SALib (1.4-1.5) recomputes the bootstrap resamples of ``A`` and ``B``, their concatenation and its variance
    for every parameter and for each of S1 and ST (4 d times per metric); they do not depend on the parameter,
    so they are computed once here, with the same numpy operations in the same order, and the random
    resampling matrix is drawn from ``seed`` exactly as SALib draws it. A test holds the results equal to
    SALib's bit for bit. For problems with groups SALib itself is called.

    Returns
    -------
    dict
        ``S1``, ``S1_conf``, ``ST``, ``ST_conf`` (d,) arrays.
    """
    from SALib.analyze import sobol as sobol_analyze
    from scipy.stats import norm

    if problem.get("groups") is not None:
        res = sobol_analyze.analyze(problem, np.asarray(Y), calc_second_order=False, num_resamples=num_resamples,
                                    conf_level=conf_level, seed=seed)
        return {k: np.asarray(res[k]) for k in ("S1", "S1_conf", "ST", "ST_conf")}
    rng = np.random.default_rng(seed).integers if seed else np.random.randint
    Y = np.asarray(Y)
    D = int(problem["num_vars"])
    if Y.size % (D + 2):
        raise RuntimeError("Incorrect number of samples in model output file: expected N (d + 2) values "
                           "(first and total order)")
    if not 0 < conf_level < 1:
        raise RuntimeError("Confidence level must be between 0-1.")
    N = Y.size // (D + 2)
    Y = (Y - Y.mean()) / Y.std()
    step = D + 2
    A = Y[0:Y.size:step]
    B = Y[step - 1:Y.size:step]
    AB = np.zeros((N, D))
    for j in range(D):
        AB[:, j] = Y[j + 1:Y.size:step]
    r = rng(N, size=(N, num_resamples))
    Z = norm.ppf(0.5 + conf_level / 2)
    eps = np.finfo(float).eps
    Ar, Br = A[r], B[r]
    y, yr = np.r_[A, B], np.r_[Ar, Br]
    constant, constant_r = np.ptp(y) <= eps, np.ptp(yr) <= eps  # SALib's estimators then return 0 (and warn)
    if constant or constant_r:
        warnings.warn(sobol_analyze.CONST_RESULT_MSG, stacklevel=2)
    y_var = np.var(y, axis=0)
    yr_var = np.var(yr, axis=0)
    var_diff = np.ptp(yr)
    out = {k: np.zeros(D) for k in ("S1", "S1_conf", "ST", "ST_conf")}
    for j in range(D):
        ABj, ABrj = AB[:, j], AB[r, j]
        if not constant:
            out["S1"][j] = _sobol_ratio(np.mean(B * (ABj - A), axis=0), y_var)
            out["ST"][j] = _sobol_ratio(0.5 * np.mean((A - ABj) ** 2, axis=0), y_var)
        if var_diff != 0.0:
            s1 = np.zeros(num_resamples) if constant_r else _sobol_ratio(np.mean(Br * (ABrj - Ar), axis=0), yr_var)
            st = np.zeros(num_resamples) if constant_r else _sobol_ratio(0.5 * np.mean((Ar - ABrj) ** 2, axis=0),
                                                                         yr_var)
            out["S1_conf"][j] = Z * s1.std(ddof=1)
            out["ST_conf"][j] = Z * st.std(ddof=1)
    return out


@holds_study_lock
def run_sobol(evaluator, space, N: int, executor=None, out=None, resume=False, seed: int = 0,
              second_order: bool = False, conf_level: float = 0.95, num_resamples: int = 200,
              progress: bool = True, chunk_size: int | None = None, transform: str | None = None) -> GlobalResult:
    """Sobol first-order and total indices with bootstrap confidence intervals for every metric.

    Parameters
    ----------
    evaluator : callable
        See :mod:`udrobot_ctrl.sensitivity.executor`.
    space : ParameterSpace or SALib problem dict
        The parameters and their ranges.
    N : int
        Base sample size (power of 2); the number of runs is ``N (d + 2)`` (``N (2 d + 2)`` with
        ``second_order``).
    executor : SweepExecutor, concurrent.futures.Executor or distributed.Client, optional
        Where the runs are evaluated (default: local processes on every CPU).
    out : path, optional
        Study directory for the incremental, resumable table (plus ``indices.csv``).
    resume : bool
        Keep the runs already in ``out`` (same study) and evaluate only the others.
    seed : int
        Seed of the Sobol sequence's scrambling and of the bootstrap.
    second_order : bool
        Also the second-order indices ``S2``.
    conf_level : float
        Confidence level of the bootstrap intervals (a probability).
    num_resamples : int
        Bootstrap resamples.
    progress : bool
        Show a progress bar.
    chunk_size : int, optional
        Samples per task (default :func:`~udrobot_ctrl.sensitivity.executor.default_chunk_size`).
    transform : {None, 'rank'}, optional
        ``rank``: indices of the ranks of each metric instead of its values. Variance-based indices of
        a heavy-tailed metric (a few runs that lose control dominate the variance) have huge CIs; the
        ranks keep the ordering information and give stable indices (of the rank-transformed output).

    Returns
    -------
    GlobalResult
        ``S1``, ``ST`` (and ``S2``) with their interval half-widths per metric (dimensionless), and the sweep.
    """
    from SALib.analyze import sobol as sobol_analyze
    from scipy.stats import rankdata

    if transform not in (None, "rank"):
        raise ValueError(f"transform must be None or 'rank', got {transform!r}")

    problem = _problem(space)
    X = sobol_samples(problem, N, seed, second_order)
    study = _study("sobol", problem, evaluator, N=N, seed=seed, second_order=second_order)
    table, wall = _sweep(evaluator, X, executor, out, resume, study, problem["names"], progress, chunk_size, "sobol")
    indices, failed = {}, {}
    for metric in _metric_columns(table, problem["names"]):
        Y = np.asarray(table[metric], float)
        failed[metric] = int(np.count_nonzero(~np.isfinite(Y)))
        if transform == "rank" and not failed[metric]:
            Y = rankdata(Y)
        d = problem["num_vars"]
        if failed[metric] or np.ptp(Y) == 0:
            nan = np.full(d, np.nan) if failed[metric] else np.zeros(d)
            indices[metric] = {"S1": nan, "S1_conf": nan, "ST": nan, "ST_conf": nan}
            continue
        # a Generator, not the int: SALib's analyze skips seeding for seed 0 (``if seed:``)
        if second_order:
            res = sobol_analyze.analyze(problem, Y, calc_second_order=True, num_resamples=num_resamples,
                                        conf_level=conf_level, seed=np.random.default_rng(seed))
            indices[metric] = {k: np.asarray(res[k]) for k in ("S1", "S1_conf", "ST", "ST_conf", "S2")}
        else:  # SALib's numbers, without its repeated resampling (see sobol_first_total)
            indices[metric] = sobol_first_total(problem, Y, num_resamples, conf_level, np.random.default_rng(seed))
    notes = sobol_warnings(N, indices)
    for note in notes:
        warnings.warn(f"Sobol study: {note}", RuntimeWarning, stacklevel=3)
    result = GlobalResult("sobol", problem["names"], indices, table, X.shape[0], wall, failed, conf_level, notes)
    if out is not None:
        write_table(f"{out}/indices" + ("_rank" if transform else ""), result.indices_table())
    return result


@holds_study_lock
def run_morris(evaluator, space, trajectories: int = 20, executor=None, out=None, resume=False, seed: int = 0,
               num_levels: int = 4, conf_level: float = 0.95, num_resamples: int = 200, progress: bool = True,
               chunk_size: int | None = None) -> GlobalResult:
    """Morris elementary effects (mu, mu*, sigma) with a bootstrap interval on mu*; ``r (d + 1)`` runs.

    Parameters
    ----------
    evaluator : callable
        See :mod:`udrobot_ctrl.sensitivity.executor`.
    space : ParameterSpace or SALib problem dict
        The parameters and their ranges.
    trajectories : int
        Number of Morris trajectories r.
    executor : SweepExecutor, concurrent.futures.Executor or distributed.Client, optional
        Where the runs are evaluated (default: local processes on every CPU).
    out : path, optional
        Study directory for the incremental, resumable table (plus ``indices.csv``).
    resume : bool
        Keep the runs already in ``out`` (same study) and evaluate only the others.
    seed : int
        Seed of the trajectories and of the bootstrap.
    num_levels : int
        Grid levels p of each parameter's range.
    conf_level : float
        Confidence level of the bootstrap interval on mu* (a probability).
    num_resamples : int
        Bootstrap resamples.
    progress : bool
        Show a progress bar.
    chunk_size : int, optional
        Samples per task.

    Returns
    -------
    GlobalResult
        ``mu``, ``mu_star``, ``mu_star_conf`` and ``sigma`` per metric (metric units), and the sweep.
    """
    from SALib.analyze import morris as morris_analyze
    from SALib.sample import morris as morris_sample

    problem = _problem(space)
    if trajectories < 2:
        raise ValueError(f"Morris needs >= 2 trajectories, got {trajectories}")
    X = morris_sample.sample(problem, trajectories, num_levels=num_levels, seed=seed)
    study = _study("morris", problem, evaluator, trajectories=trajectories, seed=seed, num_levels=num_levels)
    table, wall = _sweep(evaluator, X, executor, out, resume, study, problem["names"], progress, chunk_size, "morris")
    indices, failed = {}, {}
    for metric in _metric_columns(table, problem["names"]):
        Y = np.asarray(table[metric], float)
        failed[metric] = int(np.count_nonzero(~np.isfinite(Y)))
        if failed[metric]:
            nan = np.full(problem["num_vars"], np.nan)
            indices[metric] = {"mu": nan, "mu_star": nan, "mu_star_conf": nan, "sigma": nan}
            continue
        res = morris_analyze.analyze(problem, X, Y, num_resamples=num_resamples, conf_level=conf_level,
                                     num_levels=num_levels, seed=seed)
        indices[metric] = {k: np.asarray(res[k], float) for k in ("mu", "mu_star", "mu_star_conf", "sigma")}
    result = GlobalResult("morris", problem["names"], indices, table, X.shape[0], wall, failed, conf_level)
    if out is not None:
        write_table(f"{out}/indices", result.indices_table())
    return result


# ----------------------------------------------------------------------------- analytic test functions
class Ishigami:
    """Ishigami function f = sin x1 + a sin^2 x2 + b x3^4 sin x1 on [-pi, pi]^3 (an evaluator).

    Known Sobol indices (a = 7, b = 0.1): S1 = (0.3139, 0.4424, 0), ST = (0.5576, 0.4424, 0.2437).
    """

    names = ("x1", "x2", "x3")

    def __init__(self, a: float = 7.0, b: float = 0.1):
        self.a, self.b = a, b

    def __call__(self, X):
        X = np.asarray(X, float)
        y = np.sin(X[:, 0]) + self.a * np.sin(X[:, 1]) ** 2 + self.b * X[:, 2] ** 4 * np.sin(X[:, 0])
        return {"y": y}

    def describe(self) -> str:
        return f"ishigami(a={self.a}, b={self.b})"

    def problem(self) -> dict:
        return {"num_vars": 3, "names": list(self.names), "bounds": [[-np.pi, np.pi]] * 3}

    def analytic_indices(self):
        """(S1, ST) from the closed form (Sobol' & Levitan 1999)."""
        a, b, pi = self.a, self.b, np.pi
        v1 = 0.5 * (1 + b * pi**4 / 5) ** 2
        v2 = a**2 / 8
        v13 = b**2 * pi**8 * (1 / 18 - 1 / 50)
        v = v1 + v2 + v13
        return np.array([v1, v2, 0.0]) / v, np.array([v1 + v13, v2, v13]) / v


# ----------------------------------------------------------------------------- Monte Carlo
@dataclass
class MonteCarloResult:
    """Uniform Monte Carlo over the ranges: the tidy table and per-metric percentiles.

    Attributes
    ----------
    names : list of str
        Parameter names.
    table : dict
        Tidy sweep table (one row per model run).
    summary : dict
        ``{metric: {"mean", "std", "p5", "p50", "p95": value (metric unit), "failed": runs with a NaN}}``.
    n_runs : int
        Model runs evaluated.
    wall_s : float
        Wall time of the sweep, s.
    """

    names: list
    table: dict
    summary: dict
    n_runs: int
    wall_s: float


@holds_study_lock
def run_monte_carlo(evaluator, space, n: int, executor=None, out=None, resume=False, seed: int = 0,
                    progress: bool = True, chunk_size: int | None = None) -> MonteCarloResult:
    """``n`` independent uniform samples over the ranges of ``space`` through the executor.

    ``summary[metric]`` holds mean, std, p5, p50, p95 (NaN runs excluded; ``failed`` counts them).

    Parameters
    ----------
    evaluator : callable
        See :mod:`udrobot_ctrl.sensitivity.executor`.
    space : ParameterSpace or SALib problem dict
        The parameters and their ranges.
    n : int
        Number of samples (model runs).
    executor : SweepExecutor, concurrent.futures.Executor or distributed.Client, optional
        Where the runs are evaluated (default: local processes on every CPU).
    out : path, optional
        Study directory for the incremental, resumable table (plus ``summary.csv``).
    resume : bool
        Keep the runs already in ``out`` (same study) and evaluate only the others.
    seed : int
        Seed of the uniform samples.
    progress : bool
        Show a progress bar.
    chunk_size : int, optional
        Samples per task.

    Returns
    -------
    MonteCarloResult
        The sweep and each metric's mean, standard deviation and 5/50/95 % percentiles.
    """
    problem = _problem(space)
    if n < 1:
        raise ValueError(f"Monte Carlo needs n >= 1 samples, got {n}")
    b = np.asarray(problem["bounds"], float)
    X = b[:, 0] + np.random.default_rng(seed).random((n, len(b))) * (b[:, 1] - b[:, 0])
    study = _study("montecarlo", problem, evaluator, n=n, seed=seed)
    table, wall = _sweep(evaluator, X, executor, out, resume, study, problem["names"], progress, chunk_size,
                         "monte carlo")
    summary = {}
    for metric in _metric_columns(table, problem["names"]):
        y = np.asarray(table[metric], float)
        ok = y[np.isfinite(y)]
        stats = (np.mean(ok), np.std(ok), *np.percentile(ok, [5, 50, 95])) if ok.size else (np.nan,) * 5
        summary[metric] = dict(zip(("mean", "std", "p5", "p50", "p95"), map(float, stats)),
                               failed=int(y.size - ok.size))
    if out is not None:
        rows = {"metric": list(summary)}
        for k in ("mean", "std", "p5", "p50", "p95", "failed"):
            rows[k] = [summary[m][k] for m in summary]
        write_table(f"{out}/summary", rows)
    return MonteCarloResult(problem["names"], table, summary, X.shape[0], wall)
