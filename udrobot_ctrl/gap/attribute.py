"""Attribute the gap: fit each catalogue effect by equation error and decide significance against the noise.

Equation error. With smoothed measured velocities nu and their derivatives nu_dot (see
:mod:`udrobot_ctrl.gap.data`), the residual generalised force of the nominal model is

    r = M nu_dot + C(nu) nu + D(nu) nu + g(eta) - B f      (n x 6, N and N m)

and an effect predicts it as ``b0(shape) + A(shape) a`` (:mod:`udrobot_ctrl.gap.effects`).

Composition. Effects in a set add, except where the plant chains them: the thrusters deliver lag(map(f)) with the
static maps (deadband, asymmetry) on the command, the lag after them and the inflow loss on the lagged thrust. So in
a set with a lag (whose filter its shape alone sets), an inflow loss is fitted on the lagged commands
(``Effect.reads_delivered``) and a static map's thrust change is passed through the lag (``Effect.maps_command``;
exact for a lag of the thrust, the small-signal lag for one of the rotor speed): :meth:`Attributor.upstream`.
Summing them instead leaves a misfit a template of another effect takes up (a quadratic damping error beside a
lag standing in for the inflow loss).

Likelihood and noise floor. Each DOF i has its own Gaussian noise of unknown variance; maximising over
the variances gives the concentrated log-likelihood ``-N/2 sum_i log(RSS_i / N)`` (fitted by iteratively
re-weighted bounded least squares). The residual is serially correlated (smoothing, slow dynamics), so the
sample count is replaced by the effective count ``N_eff = N / tau_int``, with the integrated
autocorrelation time ``tau_int`` of the residual of the most flexible model (all catalogue effects at
once) -- the data's own estimate of its noise floor and its whiteness.

    BIC = N_eff sum_i log(RSS_i / N) + k log(N_eff n_dof)

Significance (forward selection). Starting from the nominal model, the effect that lowers BIC most is
added while (a) it lowers BIC by more than 10 ("very strong" evidence, Kass & Raftery 1995) and (b) with
its parameters frozen, it also lowers the holdout runs' equation error by a likelihood-ratio statistic
above chi^2_1(0.99) = 6.63. Two effects whose BIC differ by less than 10 when swapped for one another
are reported as indistinguishable on this data, with the manoeuvre that would separate them.
"""
from __future__ import annotations

import copy
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear, minimize
from scipy.signal import savgol_coeffs
from scipy.sparse import csr_matrix

from udrobot_ctrl.dynamics.plant import PlantParameters, generalized_forces
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.data import Prepared
from udrobot_ctrl.parallel import Helper, in_worker

BIC_STRONG = 10.0
#: where :meth:`Attributor.bound_binds` profiles a parameter beyond a tolerance bound: these multiples of the bound's
#: distance from its physical value further on (a tether's top end 1 m below the surface: at 2, 3, 5, 9 and 17 m),
#: reaching a small ROV's working depths; the last is where the refinement beyond the bound stops
BEYOND_STEPS = (1.0, 2.0, 4.0, 8.0, 16.0)
#: Nelder-Mead budget of a shape refinement, per free shape parameter: a tether anchor walking with the vehicle
#: (four free) stopped 0.4 m off its top end on a fixed budget of 40 evaluations, and a cross-coupled damping took
#: up the rest (the full-sensor all-pairs tether + quadratic-damping case); at 40 each it converges to 2 cm
REFINE_EVALS_PER_SHAPE = 40
HOLDOUT_CHI2 = 6.63
#: a forward step ranks the remaining effects with the shapes of those already selected held, then picks among this
#: many of the best by a joint fit of every shape (:func:`refit`) and adds the pick with every shape refitted: a held
#: shape favours the effect that makes up for its error (without a DVL, a thruster lag's time constant fitted first,
#: which a heave quadratic-damping error complements better than the inflow loss the runs hold, until the lag's time
#: constant is fitted again beside it), and the first reconstruction pass smooths the unlogged velocities with the
#: nominal plant, so an effect selected first fits its shape on velocities that carry the missing effects' force (a
#: stock dead band fitted alone at width 0.35, exponent 1.59: held there, the next pick raised the BIC by 9.7 and
#: selection stopped; refitted (0.30, 2.0) it lowered it by 83, and the linear damping the runs hold was selected
#: next, by 41). With every velocity measured too: a quadratic-damping error's norm weight fitted alone (0.835) and
#: held left the water current the runs hold a holdout replay rise of +3.7 % (p 0.16) and the backward check dropped
#: it; refitted (0.99), +12.9 % (p 0.002). Two templates that share one effect's force split it when fitted jointly
#: (seed 003's power-law wall: an exponential wall and an added-mass error are both candidates); the backward check's
#: removal test refits the remaining shapes too (:func:`udrobot_ctrl.gap.confirm.check_members`), so the wall's decay
#: length takes its share back and the added mass's removal raises the holdout gap by 5.7 % only (p 0.12): dropped
REFIT_CONTENDERS = 3
#: a look-alike (:func:`finalize`) whose grid fit beside the set's other members comes within this many BIC units of
#: the set's is refined before the ``BIC_STRONG`` test: the set's shapes are refitted jointly, and a coarse grid must
#: not separate what a refined shape matches (li2019's straight tank runs: a cable straight up beside the inflow loss,
#: +11.2 on the grid, +5.4 refined, against the quadratic-damping error: both are -k u|u| in surge). Refinement only
#: lowers the BIC; a grid fit further off is not a look-alike (refinement gained 6 and 24 there)
LOOKALIKE_SCREEN = 5 * BIC_STRONG
FIT_RATE_HZ = 10.0
#: memory (bytes) the cached designs, their per-DOF regressors and their cross products may hold together, per
#: attributor (a diagnosis has two: fit and holdout runs; copies for an untested form share the values): a tether's
#: search grid (~320 anchors and forms) is evaluated again by every forward step and look-alike check, and a cache
#: that forgets it halfway recomputes every cable geometry (about a fifth of a stock diagnosis); 10 min of logs at
#: FIT_RATE_HZ make a tether design of 0.9 MB
CACHE_BYTES = 512 * 2 ** 20


def deriv_kernel(prep: Prepared):
    """Weights w (2m,) such that the Savitzky-Golay derivative of nu equals sum_j w_j nu_dot over [t_j, t_j+1).

    By summation by parts, SG'[nu]_n = sum_j c_j nu_n+j = sum_{j=-m}^{m-1} w_j (nu_n+j+1 - nu_n+j) / dt with
    w_j = -dt sum_{i<=j} c_i. Filtering the forces (commands held on each interval, state terms averaged
    over it) with w keeps the equation error exact for the linear part: a fast-varying command otherwise
    looks like a thruster lag, and raw attitude against smoothed rates like an added-mass error.
    """
    return _deriv_weights(max(5, int(round(prep.window_s / prep.dt)) | 1), float(prep.dt))


@lru_cache(maxsize=64)
def _deriv_weights(win: int, dt: float) -> np.ndarray:
    """:func:`deriv_kernel` for a window of ``win`` samples of ``dt`` s (computed once per pair; read-only)."""
    c = savgol_coeffs(win, 2, deriv=1, delta=dt, use="dot")
    w = -dt * np.cumsum(c)[:-1]
    w.flags.writeable = False
    return w


def filter_forces(prep: Prepared, y, held=False, at=None):
    """Apply :func:`deriv_kernel` to sample-wise forces y (n, ...): interval values (held: y_k on [t_k, t_k+1);
    else the mean of the end points), then the weights; nan within m samples of the ends or of a nan.

    ``at`` (sample indices, optional): return only those rows (len(at), ...), from :func:`row_filter`."""
    if at is not None:
        return row_filter(prep, at)(y, held)
    w = deriv_kernel(prep)
    m = w.size // 2
    y = np.asarray(y, float)
    yi = y[:-1] if held else 0.5 * (y[:-1] + y[1:])
    out = np.full_like(y, np.nan)
    n = y.shape[0]
    if n <= 2 * m + 1:
        return out
    acc = np.zeros((n - 2 * m,) + y.shape[1:])
    for j in range(2 * m):  # interval index k = n_c - m + j for centre n_c in [m, n - m)
        acc += w[j] * yi[j: j + n - 2 * m]
    out[m: n - m] = acc
    return out


#: columns :func:`row_filter` filters at a time (a tether's grid has a thousand): their copies then stay small (128 at
#: a time filtered 20 000 samples x 1068 columns in 0.7 of the time of all at once, measured on the 2-core machine)
FILTER_COLUMNS = 128


def row_filter(prep: Prepared, at):
    """:func:`filter_forces` at the sample indices ``at`` only, as a function ``(y, held=False) -> (len(at), ...)``:
    the kernel's rows for those samples held once as a sparse matrix (the stack samples a few rows of a long run and
    filters every regressor there; the same sums, in the same order, as the full-rate filter), ``FILTER_COLUMNS``
    columns at a time."""
    w = deriv_kernel(prep)
    m = w.size // 2
    n = prep.n
    at = np.asarray(at, int)
    ok = (at >= m) & (at < n - m)
    indptr = np.r_[0, np.cumsum(np.where(ok, 2 * m, 0))]
    indices = (at[ok, None] - m + np.arange(2 * m)[None, :]).ravel()
    W = csr_matrix((np.tile(w, int(ok.sum())), indices, indptr), shape=(at.size, max(n - 1, 0)))

    def columns(flat, held):  # the filtered rows of a block of columns (n, c)
        live = np.flatnonzero(np.any(flat != 0.0, axis=0))  # a regressor that is zero throughout filters to zero
        if live.size and live.size == flat.shape[1]:  # every column live (a tether's anchors): no copy, no scatter
            return W @ (flat[:-1] if held else 0.5 * (flat[:-1] + flat[1:]))
        out = np.zeros((at.size, flat.shape[1]))
        if live.size:
            yl = flat[:, live]
            yi = yl[:-1] if held else 0.5 * (yl[:-1] + yl[1:])
            out[:, live] = W @ yi
        return out

    def apply(y, held=False):
        y = np.asarray(y, float)
        flat = y.reshape(n, -1)
        out = np.empty((at.size, flat.shape[1]))
        for c in range(0, flat.shape[1], FILTER_COLUMNS):  # each column filtered on its own: the same sums
            out[:, c:c + FILTER_COLUMNS] = columns(flat[:, c:c + FILTER_COLUMNS], held)
        out[~ok] = np.nan
        return out.reshape((at.size,) + y.shape[1:])
    return apply


def residual(prep: Prepared, p: PlantParameters):
    """Equation-error residual r (n, 6) of the nominal model on one prepared run (nan where not computable)."""
    x = prep.raw_state()
    r = prep.nu_dot @ p.M.T + filter_forces(prep, generalized_forces(x, p)) - filter_forces(prep, prep.f @ prep.B.T,
                                                                                               held=True)
    bad = ~np.isfinite(prep.nu[:, prep.dof_ok]).all(axis=1) | ~np.isfinite(prep.nu_dot[:, prep.dof_ok]).all(axis=1)
    r[bad] = np.nan
    r[:, ~prep.dof_ok] = np.nan
    return r


def build_stack(preps, p: PlantParameters, M_A, rate_hz=FIT_RATE_HZ):
    """Stack the valid samples of prepared runs (decimated to about ``rate_hz``) with their residual.

    Returns
    -------
    stack : effects.Stack
    r : (n, 6) ndarray
        Residual generalised forces.
    dofs : (6,) bool
        DOFs scored (velocity measured in every run and residual not degenerate).
    """
    kinds = {pr.input_kind if pr.input_kind == "tau" else "thrust" for pr in preps}
    if len(kinds) > 1:
        raise ValueError("runs mix per-thruster inputs and tau_* inputs; diagnose them separately")
    parts, runs, row = [], [], 0
    for pr in preps:
        r = residual(pr, p)
        step = max(1, int(round(1.0 / (rate_hz * pr.dt))))
        idx = np.arange(0, pr.n, step)
        idx = idx[np.isfinite(r[idx][:, pr.dof_ok]).all(axis=1)]
        x = pr.raw_state()
        nud = np.where(np.isfinite(pr.nu_dot), pr.nu_dot, 0.0)
        parts.append((x[idx, 6:], nud[idx], x[idx, :6], pr.f[idx], r[idx], pr, idx))
        runs.append({"f": pr.f, "dt": pr.dt, "window_s": pr.window_s, "idx": idx, "rows": slice(row, row + idx.size),
                     "name": pr.name,
                     "x": x, "nu": x[:, 6:], "eta": x[:, :6], "nu_dot": nud,
                     "surfaces": list(pr.surfaces),
                     "smooth": row_filter(pr, idx)})
        row += idx.size
    if not np.logical_and.reduce([pr.dof_ok for pr in preps]).any():
        raise ValueError("nothing is scoreable: no DOF's velocity is observed in every run (log depth, attitude or "
                         "body rates, or body velocities; the thrusts alone constrain nothing)")
    if row < 20:
        raise ValueError("fewer than 20 usable samples (velocities and their derivatives) in the fit runs")
    labels = sorted({lab for pr in preps for _, _, lab in pr.surfaces})
    surfaces = {}
    for lab in labels:
        d, nrm = [], None
        for (_, _, _, _, _, pr, idx) in parts:
            hit = [s for s in pr.surfaces if s[2] == lab]
            d.append(hit[0][0][idx] if hit else np.full(idx.size, np.inf))
            nrm = hit[0][1] if hit else nrm
        surfaces[lab] = (np.concatenate(d), nrm)
    cat = [np.concatenate([q[i] for q in parts]) for i in range(5)]
    dofs = np.logical_and.reduce([pr.dof_ok for pr in preps])
    st = fx.Stack(nu=cat[0], nu_dot=cat[1], eta=cat[2], f=cat[3], B=preps[0].B, inflow=preps[0].inflow,
                  f_ref=np.max([pr.f_ref for pr in preps], axis=0), surfaces=surfaces, runs=runs, p=p, M_A=M_A,
                  virtual=kinds == {"tau"})
    r = np.where(np.isfinite(cat[4]), cat[4], 0.0)
    dofs &= r.std(axis=0) > 0
    return st, r, dofs


def tau_int(x, max_lag=200):
    """Integrated autocorrelation time (samples) of a 1-D series, summed until the correlation drops below 0.05."""
    x = x - x.mean()
    v = np.dot(x, x)
    if v <= 0:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, x.size // 4)):
        rho = np.dot(x[:-k], x[k:]) / v
        if rho < 0.05:
            break
        tau += 2 * rho
    return tau


class ArrayCache:
    """Least-recently-used cache whose values (arrays, or tuples holding arrays) are bounded by their total size.

    Parameters
    ----------
    max_bytes : int
        The oldest entries are dropped once the values' ``nbytes`` sum above this.
    """

    def __init__(self, max_bytes=CACHE_BYTES):
        self.max_bytes = int(max_bytes)
        self._items = OrderedDict()
        self.nbytes = 0

    @staticmethod
    def size(value) -> int:
        """Bytes held by ``value``'s arrays (an array, or a tuple of arrays and small fields)."""
        if isinstance(value, np.ndarray):
            return value.nbytes
        if isinstance(value, tuple):
            return sum(v.nbytes for v in value if isinstance(v, np.ndarray))
        return 0

    def __contains__(self, key) -> bool:
        return key in self._items

    def __getitem__(self, key):
        self._items.move_to_end(key)
        return self._items[key]

    def __setitem__(self, key, value):
        if key in self._items:
            self.nbytes -= self.size(self._items.pop(key))
        self._items[key] = value
        self.nbytes += self.size(value)
        while self.nbytes > self.max_bytes and len(self._items) > 1:
            _, old = self._items.popitem(last=False)
            self.nbytes -= self.size(old)

    def __len__(self) -> int:
        return len(self._items)

    def without(self, drop) -> ArrayCache:
        """A copy without the keys for which ``drop(key)`` is true (the values are shared, not copied)."""
        out = ArrayCache(self.max_bytes)
        for k, v in self._items.items():
            if not drop(k):
                out[k] = v
        return out


class DesignStore:
    """Designs by what they are computed from (:func:`udrobot_ctrl.gap.effects.content_key`), for effects that declare
    the run arrays they read (:attr:`udrobot_ctrl.gap.effects.Effect.reads`): shared by the attributors and the
    identifiability checks of one diagnosis, so that a design whose inputs did not change is computed once -- a thruster
    map's grid (it reads the commands only) in both reconstruction passes, a restoring term's regressor under each move
    of the reconstructed velocities (:func:`udrobot_ctrl.gap.identifiability.assess`). The same numbers as computing it
    again: a design depends on nothing else.

    Parameters
    ----------
    max_bytes : int
        Memory the kept designs may hold (the oldest dropped beyond it).
    """

    def __init__(self, max_bytes=CACHE_BYTES):
        self._cache = ArrayCache(max_bytes)
        self._held = {}  # id -> object named by id in a key (an effect, a plant), kept so that the id stays its own

    def key(self, eff: fx.Effect, s: fx.Stack, shape, upstream=()):
        """The key of ``eff``'s design on ``s`` at ``shape`` (exact floats) behind the ``upstream`` ``(effect, shape)``
        filters (:meth:`Attributor.upstream`), or None when ``eff`` does not declare what it reads or ``s`` not what
        it holds (:func:`udrobot_ctrl.gap.effects.content_key`)."""
        declared = eff.reads is not None and all(u.reads is not None for u, _ in upstream)
        content = fx.content_key(s, eff.reads) if declared else None
        if content is None:
            return None
        for obj in (eff, s.p, *(u for u, _ in upstream)):
            self._held[id(obj)] = obj
        filters = tuple((id(u), tuple(float(v) for v in sh)) for u, sh in upstream)
        return id(eff), tuple(float(v) for v in shape), filters, content

    def design(self, key, compute) -> fx.Design:
        """The design under ``key`` (:meth:`key`; None: not kept), ``compute()`` when it is not kept yet; its
        non-finite entries zeroed (:func:`finite_design`)."""
        if key is None:
            return finite_design(compute())
        if key not in self._cache:
            self._cache[key] = finite_design(compute())
        return self._cache[key]

    def get(self, key):
        """The design under ``key`` when kept, else None."""
        return self._cache[key] if key is not None and key in self._cache else None

    def put(self, key, design) -> fx.Design:
        """Keep ``design`` under ``key`` (nothing when ``key`` is None); returns it with its non-finite entries
        zeroed."""
        d = finite_design(design)
        if key is not None:
            self._cache[key] = d
        return d


def finite_design(d) -> fx.Design:
    """Design ``d`` with its non-finite entries zeroed (``numpy.nan_to_num``; its arrays themselves when finite, as
    :meth:`Stack.full <udrobot_ctrl.gap.effects.Stack.full>` makes them): what the fits read."""
    d = fx.Design(*d)
    return d._replace(b0=fx.finite_values(d.b0), A=fx.finite_values(d.A))


@dataclass
class Fit:
    """Result of fitting a set of (effect, shape) terms."""

    names: tuple
    shapes: dict
    params: dict
    rss: np.ndarray
    k: int
    loglik_n: float  # sum_i log(RSS_i / N) over scored DOFs
    a: np.ndarray = field(repr=False, default=None)
    pred: np.ndarray = field(repr=False, default=None)


class _Solution(NamedTuple):
    """:meth:`Attributor._solve`'s result for S fits of one structure."""

    a: np.ndarray  # (S, k) amplitudes (0 where inactive)
    pred: np.ndarray | None  # (S, nd, n) A a on the scored DOFs (None: no amplitude)
    active: np.ndarray  # (S, k) bool
    names: list  # (k,) amplitude names
    owner: list  # (k,) the effect each amplitude belongs to
    b0: np.ndarray  # (S, n, nd) the fixed parts (the terms' b0) on the scored DOFs


class Attributor:
    """Equation-error fits of catalogue effects on a stack of fit runs (see the module docstring).

    Parameters
    ----------
    stack : Stack
        The runs' equation-error stack (:func:`build_stack`).
    r : ndarray, shape (n, 6)
        Its nominal residual (N, N m).
    dofs : ndarray of bool, shape (6,)
        The DOFs scored.
    catalogue : dict, optional
        Name -> effect (default: the whole catalogue).
    cache_bytes : int
        Memory the cached designs, per-DOF regressors and cross products may hold together (``CACHE_BYTES``).
    """

    def __init__(self, stack, r, dofs, catalogue=None, cache_bytes=CACHE_BYTES, store: DesignStore | None = None):
        self.s, self.r, self.dofs = stack, r, dofs
        self.store = store if store is not None else DesignStore(cache_bytes)
        self.cat = catalogue or fx.catalogue()
        self.N = stack.n
        # designs, their per-DOF regressors and cross products (keys tagged "design", "dof", "gram"; see design,
        # _dof_design, _gram) under one byte budget; stacks with filtered commands (see design)
        self._cache, self._stacks = ArrayCache(cache_bytes), {}
        self._free_shapes = {}  # see free_shapes
        self._best = {}  # see best_shape
        self._binds = {}  # see bound_binds
        self._helper, self._delegated, self._asked = None, frozenset(), {}  # see delegate
        self.n_eff = float(self.N)

    def with_effect(self, name, effect) -> Attributor:
        """A copy whose catalogue entry ``name`` is ``effect`` (e.g. a form the search does not use), with the same
        N_eff; the cached designs of the other effects are shared, those involving ``name`` dropped."""
        out = copy.copy(self)
        out.cat = {**self.cat, name: effect}

        def names_it(key):  # keys name their terms and upstream members (quoted in the key's repr)
            return repr(name) in repr(key)
        out._cache = self._cache.without(names_it)
        out._stacks = {k: v for k, v in self._stacks.items() if not names_it(k)}
        out._free_shapes = {k: v for k, v in self._free_shapes.items() if not names_it(k)}
        out._best = {k: v for k, v in self._best.items() if not names_it(k)}
        out._binds = {k: v for k, v in self._binds.items() if not names_it(k)}
        out._helper, out._delegated, out._asked = None, frozenset(), {}  # the helper serves this attributor only
        return out

    def delegate(self, names, jobs=None) -> None:
        """Search the shapes of ``names`` (:meth:`best_shape`) in a helper process (:class:`~udrobot_ctrl.parallel.
        Helper`) forked now, which keeps their designs, so that :meth:`request` starts them beside the caller's
        other work; ``()`` stops the helper. The results are those computed here (a search depends on the stack, its
        residual and scored DOFs only). Without a second core the searches run here, when asked for.

        A diagnosis delegates the effects the runs cannot identify: they are fitted for the record and as look-alikes,
        and on stock runs a tether's anchor grid costs more than the identifiable effects' searches together. The
        helper holds its own design cache (up to ``cache_bytes`` more memory).
        """
        if self._helper is not None:
            self._helper.close()
        self._helper, self._asked = None, {}
        self._delegated = frozenset(names)
        if self._delegated:
            helper = Helper(self, jobs)
            self._helper = helper if helper.forked else None

    def delegates(self, name) -> bool:
        """Whether the searches of ``name`` run in the helper (:meth:`delegate`)."""
        return self._helper is not None and name in self._delegated and not in_worker()

    def request(self, name, fixed=(), refine=True, seeds=()) -> None:
        """Start :meth:`best_shape` with these arguments in the helper when ``name`` is delegated (:meth:`delegate`)
        and the search is neither done nor asked for; else nothing (it is computed when :meth:`best_shape` asks)."""
        key = _search_key(name, fixed, refine, seeds)
        if self.delegates(name) and key not in self._best and key not in self._asked:
            self._asked[key] = self._helper.submit("best_shape", name, tuple((n, tuple(sh)) for n, sh in fixed),
                                                   bool(refine), tuple(tuple(sh) for sh in seeds))

    def design(self, name, shape, upstream=()) -> fx.Design:
        """The effect's :class:`~udrobot_ctrl.gap.effects.Design` on this stack (non-finite entries zeroed), cached.

        ``upstream``: (name, shape) of the set's members whose input filters act together with this effect in the
        plant's order (:meth:`upstream`): an effect that reads the delivered thrust sees the commands through them,
        a static map's thrust change goes through them."""
        key = _design_key(name, shape, upstream)
        if key not in self._cache:
            s = self._composed(name, upstream) if upstream else self.s
            self._cache[key] = self.store.design(self._store_key(name, shape, upstream),
                                                 lambda: self.cat[name].design(s, tuple(shape)))
        return self._cache[key]

    def _store_key(self, name, shape, upstream=()):
        """The :class:`DesignStore` key of a design on this attributor's stack (None: not kept there)."""
        return self.store.key(self.cat[name], self.s, shape, tuple((self.cat[n], sh) for n, sh in upstream))

    def keep_designs(self, designs) -> None:
        """Keep designs computed elsewhere on this attributor's stack with its own catalogue entries, ``(name, shape)
        -> Design`` (the identifiability probes of :func:`udrobot_ctrl.gap.identifiability.assess`): the searches
        read them as if computed here."""
        for (name, shape), d in designs.items():
            key = _design_key(name, shape)
            if key not in self._cache:
                self._keep_design(key, fx.Design(*d))

    def _keep_design(self, key, d: fx.Design) -> None:
        self._cache[key] = finite_design(d)

    def prefetch(self, name, shapes, fixed=()) -> None:
        """Compute the designs of ``name`` at ``shapes`` not cached yet together (:meth:`Effect.designs
        <udrobot_ctrl.gap.effects.Effect.designs>`), when it sees no other member's filter beside ``fixed``: a grid
        search then reads them from the cache."""
        if self.upstream(name, fixed):
            return
        missing = {_design_key(name, sh): tuple(sh) for sh in shapes}
        missing = {k: sh for k, sh in missing.items() if k not in self._cache}
        stored = {k: self._store_key(name, sh) for k, sh in missing.items()}
        for k in list(missing):
            d = self.store.get(stored[k])
            if d is not None:
                self._cache[k] = d
                del missing[k]
        if len(missing) > 1:
            for key, d in zip(missing, self.cat[name].designs(self.s, list(missing.values()))):
                self._cache[key] = self.store.put(stored[key], d)

    def upstream(self, name, terms) -> tuple:
        """(name, shape) of the members of ``terms`` whose input filter (a lag: shape only) composes with ``name`` in
        the plant's order: an inflow loss reads the lagged thrust, a deadband's or an asymmetry's thrust change is
        lagged; () for the other effects."""
        eff = self.cat[name]
        if not (eff.reads_delivered or eff.maps_command):
            return ()
        return tuple((n, tuple(sh)) for n, sh in terms
                     if n != name and self.cat[n].command_filter(tuple(sh)) is not None)

    def _composed(self, name, upstream) -> fx.Stack:
        """The stack as effect ``name`` sees it behind or before the filters of ``upstream`` (cached)."""
        maps = self.cat[name].maps_command
        key = (maps, _rounded(upstream))
        if key not in self._stacks:
            if len(self._stacks) > 40:
                self._stacks.clear()
            if maps:
                self._stacks[key] = self.s.followed_by([self.cat[n].change_filter(sh) for n, sh in upstream])
            else:
                self._stacks[key] = self.s.delivered([self.cat[n].command_filter(sh) for n, sh in upstream])
        return self._stacks[key]

    def at_bounds(self, fit: Fit, name, rel=1e-3) -> dict:
        """Parameters of ``name`` in ``fit`` that ended on a bound of their search: name -> (value, bound).

        A fit at its bound has not found an optimum inside the physical range the catalogue allows (e.g. a thruster
        lag at the 1 s top of its range): the effect is then likely standing in for something else. Shape
        parameters whose ends are physical forms (``Effect.physical_ends``: a thrust exponent of 1 or 2) are not
        checked, nor those the refinement holds at their grid value (a zero ``refine_step``: a tether's walking or
        taut form). The other shape parameters are checked against the effect's search bounds, amplitudes against
        their design bounds (except those whose ends are physical forms, ``Effect.physical_amplitudes``: a dead
        band's shift of 1, the thrust continuous from the band's edge), within ``rel`` of the smaller of the range's
        width and the bound's magnitude. A shape parameter on a bound that is a tolerance about a physical value
        (``Effect.tolerance_ends``: a tether's top end at the 1 m limit below the surface) is found here only when the
        bound binds (:meth:`bound_binds`: the fit would go on beyond it, clearly better); else the runs cannot place
        it within the tolerance, which is no evidence of a missing term. A confirmed effect found here is not
        significant (:func:`udrobot_ctrl.gap.report.set_aside_at_bound`).
        """
        eff = self.cat[name]
        shape = fit.shapes[name]
        out = {}
        _, bounds = eff.search_space(self.s)
        held = (np.asarray(eff.refine_step(self.s, shape), float) == 0 if eff.refine and bounds
                else np.zeros(len(eff.shape_names), bool))
        checks = [(sn, fit.params[name].get(sn), lo, hi)
                  for sn, (lo, hi), h in zip(eff.shape_names, bounds, held) if sn not in eff.physical_ends and not h]
        d = self.design(name, shape)
        active = np.einsum("nik,nik->k", d.A[:, self.dofs], d.A[:, self.dofs]) > 0
        checks += [(an, fit.params[name].get(an), lo, hi)
                   for an, lo, hi, on in zip(d.names, d.lower, d.upper, active)
                   if on and an not in eff.physical_amplitudes]
        for pname, value, lo, hi in checks:
            if value is None or not np.isfinite(value):
                continue
            for bound in (lo, hi):
                # within rel of the range's width, and of the bound's own magnitude: a wide one-sided range (a
                # damping from -D_L to 1e4) must not flag every value near its physical end
                tol = rel * min(abs(hi - lo), abs(bound))
                if np.isfinite(bound) and abs(value - bound) <= tol and bound != 0.0:
                    out[pname] = (float(value), float(bound))
        for pname, value in eff.tolerance_ends:
            if pname in out and not self.bound_binds(fit, name, pname, value):
                del out[pname]
        return out

    def bound_binds(self, fit: Fit, name, pname, value) -> bool:
        """Whether the runs want shape parameter ``pname`` of ``name`` beyond the bound it ended on in ``fit``, a
        tolerance about the physical ``value`` (``Effect.tolerance_ends``): with that bound moved ``BEYOND_STEPS[-1]``
        times the bound's distance from ``value`` further on, the shape refined again (from the best point of the
        profile at ``BEYOND_STEPS`` times that distance, the other shapes as fitted) lowers the fit-run BIC by more
        than ``BIC_STRONG`` (the same number of parameters, so N_eff times the log-likelihood change). A tether fit
        pinned 1 m below the surface that would go on to the vehicle's depth binds; one that drifted there because
        the runs cannot place its top end within that metre does not. Kept per fit and parameter."""
        key = (name, pname, float(value), _exact((n, fit.shapes[n]) for n in fit.names))
        if key in self._binds:
            return self._binds[key]
        eff = self.cat[name]
        _, bounds = eff.search_space(self.s)
        i = eff.shape_names.index(pname)
        at = float(fit.shapes[name][i])
        fixed = [(n, fit.shapes[n]) for n in fit.names if n != name]
        shape, best = list(fit.shapes[name]), fit
        for k in BEYOND_STEPS:  # the profile beyond the bound, the other shapes held
            shape[i] = at + k * (at - float(value))
            alt = self.fit(fixed + [(name, tuple(shape))])
            best = alt if alt.loglik_n < best.loglik_n else best
        relaxed = list(bounds)
        relaxed[i] = ((bounds[i][0], shape[i]) if at >= float(value) else (shape[i], bounds[i][1]))
        if eff.refine:  # its nested parts judged as the search judges them
            cand = self.nested_parts(self._refine(name, fixed, best.shapes[name], tuple(relaxed)), name, fixed)
            best = cand if cand.loglik_n < best.loglik_n else best
        self._binds[key] = bool(self.n_eff * (fit.loglik_n - best.loglik_n) > BIC_STRONG)
        return self._binds[key]

    def _dof_design(self, name, shape, upstream=()):
        """Regressors of a design on the scored DOFs, (nd, k, n) C-contiguous (kept with the design cache)."""
        key = ("dof", name, tuple(np.round(shape, 6)), _rounded(upstream), self.dofs.tobytes())
        if key not in self._cache:
            A = self.design(name, shape, upstream)[1]
            self._cache[key] = np.ascontiguousarray(A[:, self.dofs, :].transpose(1, 2, 0))
        return self._cache[key]

    def _gram(self, ti, tj, At_i, At_j):
        """Per-DOF cross products At_i At_j^T (nd, k_i, k_j) of two terms' regressors, cached per pair."""
        key = ("gram", ti[0], tuple(np.round(ti[1], 6)), _rounded(ti[2]), tj[0], tuple(np.round(tj[1], 6)),
               _rounded(tj[2]), self.dofs.tobytes())
        if key not in self._cache:
            self._cache[key] = At_i @ At_j.transpose(0, 2, 1)
        return self._cache[key]

    def fit(self, terms, iters=3):
        """Fit terms [(name, shape), ...] jointly; per-DOF variances by re-weighting (:meth:`_solve`)."""
        terms = [(n, tuple(sh)) for n, sh in terms]
        sol = self._solve([terms], iters)
        a, kk = sol.a[0], int(sol.active[0].sum())
        pred = sol.b0[0] + (sol.pred[0].T if sol.pred is not None else 0.0)
        rss = self._rss(sol)[0]
        params, shapes = {}, {}
        for name, shape in terms:
            shapes[name] = tuple(shape)
            sp = dict(zip(self.cat[name].shape_names, shape))
            params[name] = {k_: float(v) for k_, v in sp.items()}
        for nm, own, val in zip(sol.names, sol.owner, a):
            params[own][nm] = float(val)
        kk += sum(self.free_shapes(n) for n, _ in terms)
        full_pred = np.zeros_like(self.r)
        full_pred[:, self.dofs] = pred
        return Fit(tuple(n for n, _ in terms), shapes, params, rss, kk, float(np.sum(np.log(rss / self.N))), a,
                   full_pred)

    def losses(self, fixed, name, shapes, iters=3, chunk=64) -> np.ndarray:
        """``fit(fixed + [(name, shape)]).loglik_n`` for each of ``shapes`` (S,), the fits solved together
        (:meth:`_solve`, ``chunk`` shapes at a time): a grid search's cost is then a few array operations per shape,
        not a fit's Python overhead."""
        fixed = [(n, tuple(sh)) for n, sh in fixed]
        out = []
        for c0 in range(0, len(shapes), chunk):
            sets = [fixed + [(name, tuple(sh))] for sh in shapes[c0:c0 + chunk]]
            out.append(np.sum(np.log(self._rss(self._solve(sets, iters)) / self.N), axis=1))
        return np.concatenate(out) if out else np.zeros(0)

    def _rss(self, sol: _Solution) -> np.ndarray:
        """(S, nd) residual sum of squares per scored DOF of each fit of a :meth:`_solve` (plus 1e-300)."""
        e = self.r[:, self.dofs].T[None] - sol.b0.transpose(0, 2, 1) - (sol.pred if sol.pred is not None else 0.0)
        return np.sum(e ** 2, axis=2) + 1e-300

    def _solve(self, term_sets, iters) -> _Solution:
        """The weighted, bounded least squares of S fits of one structure (the same effects in the same order, each
        term's shape free to differ), together.

        Per fit: amplitudes ``a`` minimising sum_i |y_i - A_i a|^2 / sigma_i^2 over the scored DOFs i within the
        designs' bounds, y = r - b0 (the terms' fixed parts), with sigma_i re-estimated from the residual ``iters``
        times (from the residual's RMS); columns with no energy on the scored DOFs are inactive (zero). The normal
        equations are scaled to a unit diagonal (plus 1e-9) and solved as one batch; a fit whose solution leaves its
        bounds is solved on its own by :func:`bounded_normal_solve`.
        """
        d = self.dofs
        S, nd = len(term_sets), int(d.sum())
        per_set = [[(n, sh, self.upstream(n, terms)) for n, sh in terms] for terms in term_sets]
        first = per_set[0]
        designs = [[self.design(*key) for key in keys] for keys in per_set]
        names = [nm for dz in designs[0] for nm in dz.names]
        owner = [n for (n, _, _), dz in zip(first, designs[0]) for _ in dz.names]
        k = len(names)
        b0 = np.stack(_fixed_parts(designs, self.r, d))  # (S, n, nd)
        y = (self.r[:, d][None] - b0).transpose(0, 2, 1)  # (S, nd, n)
        if k == 0:
            return _Solution(np.zeros((S, 0)), None, np.zeros((S, 0), bool), names, owner, b0)
        # per term: its per-DOF regressors (nd, k_i, n), shared by the fits where its key is the same
        Ats = []
        for t in range(len(first)):
            keys = [keys[t] for keys in per_set]
            if all(kt == keys[0] for kt in keys):
                Ats.append(self._dof_design(*keys[0])[None])
            else:
                Ats.append(np.stack([self._dof_design(*kt) for kt in keys]))
        cuts = np.cumsum([0] + [At.shape[2] for At in Ats])
        G = np.empty((S, nd, k, k))
        for i, Ai in enumerate(Ats):
            for j in range(i, len(Ats)):
                if Ai.shape[0] == 1 and Ats[j].shape[0] == 1:
                    g = self._gram(per_set[0][i], per_set[0][j], Ai[0], Ats[j][0])[None]
                else:
                    g = Ai @ Ats[j].transpose(0, 1, 3, 2)
                G[:, :, cuts[i]:cuts[i + 1], cuts[j]:cuts[j + 1]] = g
                G[:, :, cuts[j]:cuts[j + 1], cuts[i]:cuts[i + 1]] = np.swapaxes(g, -1, -2)
        h = np.concatenate([(At @ y[..., None])[..., 0] for At in Ats], axis=2)  # (S, nd, k)
        lo = np.concatenate([dz.lower for dz in designs[0]])
        hi = np.concatenate([dz.upper for dz in designs[0]])

        def prediction(a):  # A a per fit, (S, nd, n): the terms' products summed in place (einsum's sums start
            # from +0.0, so starting from the first term, not from 0, gives the same numbers without a copy)
            out = None
            for i, At in enumerate(Ats):
                part = (np.einsum("sk,sdkn->sdn", a[:, cuts[i]:cuts[i + 1]], At) if At.shape[0] == S
                        else np.einsum("sk,dkn->sdn", a[:, cuts[i]:cuts[i + 1]], At[0]))
                if out is None:
                    out = part
                else:
                    out += part
            return out

        sig = np.broadcast_to(np.sqrt(np.mean(self.r[:, d] ** 2, axis=0)) + 1e-12, (S, nd))
        energy = np.einsum("sikk->sk", G / sig[:, :, None, None] ** 2)
        active = energy > 1e-12 * np.maximum(1.0, energy.max(axis=1, keepdims=True))
        eye = np.eye(k)
        a, pred = np.zeros((S, k)), None
        for it in range(iters):
            w = 1.0 / sig ** 2
            Gw = np.einsum("sikl,si->skl", G, w)
            hw = np.einsum("sik,si->sk", h, w)
            scale = np.sqrt(np.einsum("skk->sk", Gw)) + 1e-300
            with np.errstate(invalid="ignore", divide="ignore"):  # an inactive column's 0/0, replaced below
                Gn = Gw / (scale[:, :, None] * scale[:, None, :]) + 1e-9 * eye
                rhs = np.where(active, hw / scale, 0.0)
            off = ~(active[:, :, None] & active[:, None, :])  # an inactive column: a unit row, zero right-hand side
            Gn = np.where(off, eye, Gn)
            z = np.linalg.solve(Gn, rhs[..., None])[..., 0]
            out = ~np.all(((z >= lo * scale) & (z <= hi * scale)) | ~active, axis=1)
            for s_ in np.flatnonzero(out):  # bounds bind: the active-set method on that fit's active columns
                on = active[s_]
                z[s_] = 0.0
                z[s_, on] = bounded_normal_solve(Gn[s_][np.ix_(on, on)], rhs[s_, on], lo[on] * scale[s_, on],
                                                 hi[on] * scale[s_, on])
            a = np.where(active, z / scale, 0.0)
            pred = prediction(a)
            if it + 1 < iters:  # the weights of the next pass (the last pass's prediction is the fit's)
                sig = np.sqrt(np.mean((y - pred) ** 2, axis=2)) + 1e-12
        return _Solution(a, prediction(a) if pred is None else pred, active, names, owner, b0)

    def free_shapes(self, name) -> int:
        """Number of shape parameters of ``name`` the search moves (a form held at one end is not one)."""
        if name not in self._free_shapes:
            _, bounds = self.cat[name].search_space(self.s)
            self._free_shapes[name] = (sum(1 for lo, hi in bounds if hi > lo) if bounds
                                       else len(self.cat[name].shape_names))
        return self._free_shapes[name]

    def bic(self, fit: Fit) -> float:
        return self.n_eff * fit.loglik_n + fit.k * np.log(self.n_eff * max(1, self.dofs.sum()))

    def best_shape(self, name, fixed=(), refine=True, seeds=()):
        """Best fit of ``name`` (grid search over its shape and any ``seeds`` shapes, e.g. its refined single-effect
        shape, then local refinement, ``REFINE_EVALS_PER_SHAPE`` evaluations per free shape parameter) together with
        fixed terms.

        The result is kept per arguments (exact shapes): the look-alike screens of one selection repeat searches
        (an unidentifiable tether's grid with nothing fixed, in each finalisation), and a search depends on nothing
        else (the stack, its residual and scored DOFs are the attributor's own; N_eff does not enter a likelihood).
        """
        key = _search_key(name, fixed, refine, seeds)
        if key not in self._best:
            self.request(name, fixed, refine, seeds)
            self._best[key] = (self._helper.result(self._asked.pop(key)) if key in self._asked else
                               self._search_shape(name, fixed, refine, seeds))
        return self._best[key]

    def best_shapes(self, searches) -> list:
        """:meth:`best_shape` of each ``(name, fixed, refine, seeds)`` of ``searches``, in order: the searches
        delegated to the helper (:meth:`delegate`) are started there first, the others computed here meanwhile."""
        searches = [tuple(sr) for sr in searches]
        for sr in searches:
            self.request(*sr)
        here = {i: self.best_shape(*sr) for i, sr in enumerate(searches) if not self.delegates(sr[0])}
        return [here[i] if i in here else self.best_shape(*sr) for i, sr in enumerate(searches)]

    def _search_shape(self, name, fixed, refine, seeds):
        """:meth:`best_shape` computed."""
        eff = self.cat[name]
        grid, bounds = eff.search_space(self.s)
        self.prefetch(name, tuple(grid) + tuple(seeds), fixed)
        shapes = [tuple(sh) for sh in tuple(grid) + tuple(seeds)]
        losses = self.losses(fixed, name, shapes)
        best = self.fit(list(fixed) + [(name, shapes[_first_min(losses)])])
        if refine and eff.refine and bounds:
            starts = self._form_starts(eff, shapes, losses, best)
            best = self._chosen_form(eff, [best, *(self._refine(name, fixed, x0, bounds) for x0 in starts)])
        return self.nested_parts(best, name, fixed)

    def _form(self, eff, shape) -> tuple:
        """The values of ``eff``'s held shape parameters (a zero ``refine_step``) at ``shape``: the form it fixes."""
        shape = np.asarray(shape, float)
        return tuple(shape[np.asarray(eff.refine_step(self.s, shape), float) == 0])

    def _form_starts(self, eff, shapes, losses, best: Fit) -> list:
        """Where :meth:`_search_shape` refines from: the best grid shape, and for an effect with a default form
        (``Effect.default_form``: a wall effect's planes), the best grid shape of each other form whose grid fit
        comes within ``LOOKALIKE_SCREEN`` BIC units of the best (on the effective sample count of the best's
        residual, as :meth:`nested_parts`)."""
        first = best.shapes[eff.name]
        if eff.default_form(self.s) is None:
            return [first]
        n_eff = self.effective_samples(best)
        lead = float(np.nanmin(losses))
        forms = {}
        for sh, loss in zip(shapes, losses):
            key = self._form(eff, sh)
            if np.isfinite(loss) and n_eff * (loss - lead) < LOOKALIKE_SCREEN and loss < forms.get(key, (np.inf,))[0]:
                forms[key] = (loss, sh)
        own = self._form(eff, first)
        return [first] + [sh for key, (_, sh) in sorted(forms.items(), key=lambda kv: kv[1][0]) if key != own]

    def _chosen_form(self, eff, fits) -> Fit:
        """The best of ``fits`` (one effect's grid and refined fits), unless the effect's default form
        (``Effect.default_form``: a wall effect acting on every plane) is among them and its best fit comes within
        ``BIC_STRONG`` of it (the forms have the same parameter count): a form other than the physical default is
        kept only when the fit pays for it, on the effective sample count of the best's residual."""
        best = min(fits, key=lambda f: f.loglik_n)
        default = eff.default_form(self.s)
        own = [f for f in fits if default is not None and self._form(eff, f.shapes[eff.name]) == tuple(default)]
        if not own:
            return best
        alt = min(own, key=lambda f: f.loglik_n)
        return alt if self.effective_samples(best) * (alt.loglik_n - best.loglik_n) <= BIC_STRONG else best

    def nested_parts(self, fit: Fit, name, fixed=()) -> Fit:
        """``fit`` with each of ``name``'s nested shape groups (``Effect.nested``: a tether's attachment point) set
        back to its defaults unless the fit pays for it: with the group at its defaults (the amplitudes fitted again,
        ``fixed`` held) the fit-run BIC would rise by more than ``BIC_STRONG`` counting the group's parameters, on
        the effective sample count of ``fit``'s own residual (:meth:`effective_samples`; a search does not depend on
        the attributor's N_eff, set later from every effect's residual)."""
        eff = self.cat[name]
        for group, defaults in eff.nested:
            idx = [eff.shape_names.index(g) for g in group]
            shape = list(fit.shapes[name])
            if all(shape[i] == d for i, d in zip(idx, defaults)):
                continue
            for i, d in zip(idx, defaults):
                shape[i] = float(d)
            alt = self.fit(list(fixed) + [(name, tuple(shape))])
            n_eff = self.effective_samples(fit)
            gain = n_eff * (alt.loglik_n - fit.loglik_n) - len(group) * np.log(n_eff * max(1, self.dofs.sum()))
            if gain <= BIC_STRONG:
                fit = alt
        return fit

    def effective_samples(self, fit: Fit) -> float:
        """N_eff of ``fit``'s residual on the scored DOFs: N over :meth:`residual_tau` (at least 10)."""
        return max(10.0, self.N / max(self.residual_tau(fit), 1.0))

    def residual_tau(self, fit: Fit) -> float:
        """The median integrated autocorrelation time (samples) of ``fit``'s residual, per run and scored DOF (runs
        of more than 20 rows; 1 without any)."""
        e = (self.r - fit.pred)[:, self.dofs]
        taus = [[tau_int(seg[:, j]) for j in range(seg.shape[1])]
                for seg in (e[run["rows"]] for run in self.s.runs) if seg.shape[0] > 20]
        return float(np.median(taus)) if taus else 1.0

    def _refine(self, name, fixed, shape, bounds) -> Fit:
        """The local refinement of :meth:`best_shape`: Nelder-Mead on the free shape parameters of ``name`` (its
        ``refine_step``, ``REFINE_EVALS_PER_SHAPE`` evaluations each) from ``shape`` within ``bounds``, the terms
        ``fixed`` held; the fit where it ends."""
        eff = self.cat[name]
        x0 = np.array(shape, float)
        lo = np.array([b[0] for b in bounds])
        hi = np.array([b[1] for b in bounds])
        step = np.asarray(eff.refine_step(self.s, x0), float)
        free = step != 0  # a zero step holds that shape parameter (a form chosen on the grid)

        def full_shape(zf):
            z = x0.copy()
            z[free] = zf
            return np.clip(z, lo, hi)

        def obj(zf):  # fit(...).loglik_n without the Fit (its parameters and prediction): the same sum
            return float(self.losses(fixed, name, [tuple(full_shape(zf))], iters=2)[0])

        z0 = x0[free]
        simplex = np.vstack([z0] + [z0 + np.diag(step[free])[i] for i in range(z0.size)])
        res = minimize(obj, z0, method="Nelder-Mead",
                       options={"initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-7,
                                "maxfev": REFINE_EVALS_PER_SHAPE * z0.size})
        return self.fit(list(fixed) + [(name, tuple(full_shape(res.x)))])

    def estimate_noise(self, singles):
        """Set N_eff from the residual of all effects at once (their best single shapes)."""
        terms = [(n, f.shapes[n]) for n, f in singles.items()]
        full = self.fit(terms, iters=2)
        tau = self.residual_tau(full)
        self.n_eff = max(10.0, self.N / max(tau, 1.0))
        return tau, full


def _fixed_parts(designs, r, dofs) -> list:
    """Per fit of :meth:`Attributor._solve` (``designs``: its terms' designs), the sum of its terms' fixed parts b0
    on the scored ``dofs`` (n, nd), from zero (shaped as the residual ``r``); computed once per distinct set of b0
    arrays (a grid's shapes share one)."""
    done = {}
    for dzs in designs:
        key = tuple(id(dz.b0) for dz in dzs)
        if key not in done:  # the designs are held by the caller: their ids stay theirs
            done[key] = sum((dz.b0 for dz in dzs), np.zeros_like(r))[:, dofs]
    return [done[tuple(id(dz.b0) for dz in dzs)] for dzs in designs]


def _search_key(name, fixed, refine, seeds) -> tuple:
    """The key of a :meth:`Attributor.best_shape` search (exact shapes)."""
    return name, _exact(fixed), bool(refine), _exact((name, sh) for sh in seeds)


def _first_min(values) -> int:
    """Index of the first smallest value, nan counting as +inf (a fit that failed never wins a grid search)."""
    v = np.asarray(values, float)
    return int(np.argmin(np.where(np.isnan(v), np.inf, v)))


def bounded_normal_solve(G, h, lo, hi) -> np.ndarray:
    """argmin_z z^T G z - 2 h^T z subject to lo <= z <= hi, for a symmetric positive definite G (k, k) (the normal
    equations of a fit): the unconstrained solution when it lies within the bounds; else the active-set method of
    bounded-variable least squares (Stark and Parker 1995) on the normal equations, whose every step solves the free
    variables with the others held at their bounds and ends when the Karush-Kuhn-Tucker conditions hold. The problem is
    strictly convex, so its minimiser is unique and this is what scipy's ``bvls`` returns (it takes over, on the
    Cholesky factor, should the active set not settle within its iteration budget)."""
    k = h.size
    z = np.linalg.solve(G, h)
    if np.all(z >= lo) and np.all(z <= hi):
        return z
    z = np.clip(z, lo, hi)
    free = (z > lo) & (z < hi)
    tol = 1e-12 * (np.abs(h).max() + 1e-300)  # the KKT test's tolerance
    for _ in range(4 * k + 4):
        fixed = ~free
        target = z.copy()
        if free.any():
            # the free rows of the free and fixed columns, C-ordered as np.ix_ gives them (a matrix-vector product's
            # sums follow the layout): columns first, then the rows
            target[free] = np.linalg.solve(G[:, free][free], h[free] - G[:, fixed][free] @ z[fixed])
        if (target >= lo).all() and (target <= hi).all():
            z = target
            grad = G @ z - h  # KKT: at a lower bound the objective must rise inwards (grad >= 0), at an upper one fall
            wrong = np.where(fixed & (z <= lo), -grad, 0.0) + np.where(fixed & (z >= hi), grad, 0.0)
            worst = int(np.argmax(wrong))
            if wrong[worst] <= tol:
                return z
            free[worst] = True
            continue
        # move towards the target until the first free variable meets its bound; that one is held there
        step = target - z
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(step < 0, (lo - z) / step, np.where(step > 0, (hi - z) / step, np.inf))
        room[~free] = np.inf
        alpha = float(np.clip(room.min(), 0.0, 1.0))
        z = np.clip(z + alpha * step, lo, hi)
        free &= (z > lo) & (z < hi)
    L = np.linalg.cholesky(G)
    return lsq_linear(L.T, solve_triangular(L, h, lower=True, check_finite=False), bounds=(lo, hi), method="bvls").x


def _design_key(name, shape, upstream=()) -> tuple:
    """The cache key of a design (shape rounded to 1e-6, see :func:`_rounded`)."""
    return ("design", name, tuple(np.round(shape, 6)), _rounded(upstream))


def _exact(terms) -> tuple:
    """A key of (name, shape) pairs, shapes as exact floats."""
    return tuple((n, tuple(float(v) for v in sh)) for n, sh in terms)


def _rounded(terms) -> tuple:
    """A cache key of (name, shape) pairs."""
    return tuple((n, tuple(np.round(sh, 6))) for n, sh in terms)


def holdout_loglik(att_h: Attributor, fit: Fit):
    """sum_i log(RSS_i/N) on a holdout stack with the parameters of ``fit`` frozen."""
    d = att_h.dofs
    pred = np.zeros_like(att_h.r)
    terms = [(n, fit.shapes[n]) for n in fit.names]
    for name in fit.names:
        des = att_h.design(name, fit.shapes[name], att_h.upstream(name, terms))
        a = np.array([fit.params[name][nm] for nm in des.names])
        pred += des.b0 + (np.einsum("nik,k->ni", des.A, a) if a.size else 0.0)
    e = (att_h.r - pred)[:, d]
    return float(np.sum(np.log(np.sum(e ** 2, axis=0) / att_h.N + 1e-300)))


def passes_forward_test(delta_bic: float, lr: float) -> bool:
    """The forward-selection test of an addition: the fit-run BIC lower by more than ``BIC_STRONG`` and the holdout
    equation-error likelihood ratio above ``HOLDOUT_CHI2``."""
    return delta_bic < -BIC_STRONG and lr > HOLDOUT_CHI2


def holdout_lr(att_h: Attributor, without: Fit, with_: Fit) -> float:
    """Holdout equation-error likelihood ratio 2 ln(L_with / L_without) = N_eff (ll(without) - ll(with)), with
    both fits' parameters frozen (N_eff of the holdout stack); chi^2-distributed under 'no improvement'."""
    return float(att_h.n_eff * (holdout_loglik(att_h, without) - holdout_loglik(att_h, with_)))


@dataclass(frozen=True)
class SelectionStep:
    """One forward-selection step: the best remaining effect and whether it was added."""

    effect: str
    delta_bic: float  # BIC change on the fit runs when added to the current set
    holdout_lr: float  # holdout equation-error likelihood ratio, parameters frozen
    accepted: bool


@dataclass(frozen=True)
class Combination:
    """A joint fit of several effects on the fit runs, with their look-alikes and the residual noise level."""

    members: tuple
    fit: Fit
    indistinguishable: dict  # member -> effects whose swap for it changes BIC by less than BIC_STRONG
    noise_sigma: np.ndarray  # (6,) residual std per DOF (N, N m), nan for DOFs not scored


@dataclass(frozen=True)
class Selection:
    """Single fits of every candidate, the noise floor and the forward selection on the fit runs."""

    nominal: Fit
    singles: dict  # name -> Fit of that effect alone
    delta_bic: dict  # name -> single-effect BIC change
    steps: tuple  # SelectionStep, in order
    tau_int: float  # integrated autocorrelation time of the residual, samples
    n_eff: float  # N / tau_int on the fit runs
    candidates: Combination  # the effects forward selection added, jointly fitted

    @property
    def proposed(self) -> tuple:
        """Effects forward selection added (candidates for the holdout confirmation)."""
        return self.candidates.members


def forward_select(att: Attributor, att_h: Attributor, names=None, max_effects=4, log=None,
                   exclude=()) -> Selection:
    """Single fits of every effect, noise floor, forward selection and look-alike groups.

    An effect is added while it lowers the fit-run BIC by more than ``BIC_STRONG`` and, with its parameters frozen,
    raises the holdout equation-error likelihood by a ratio above ``HOLDOUT_CHI2``. Each step ranks the remaining
    effects with the selected ones' shapes held and, once a selected effect has a free shape, picks among the
    ``REFIT_CONTENDERS`` best by a joint fit of all shapes (:func:`refit`) and adds the pick with every shape
    refitted (its trial; see ``REFIT_CONTENDERS``). When the pick fails either test, the other effects are tried
    in BIC order (each whose grid fit passes both tests, refined or refitted, then tested again), and the first that
    passes is added: the selection stops only when no remaining effect passes, so one effect that the holdout
    rejects (a CG-CB offset fitted on a bench log) does not hide another that both support.

    Parameters
    ----------
    att, att_h : Attributor
        Fit-run and holdout stacks.
    names : sequence of str, optional
        Candidate effects (default: the whole catalogue).
    max_effects : int
        At most this many effects are added.
    log : callable, optional
        Receives one line per step.
    exclude : sequence of str
        Effects the runs cannot identify (:mod:`udrobot_ctrl.gap.identifiability`): fitted alone for the record
        (best grid shape, not refined) and never selected; they are still look-alikes of a selected effect whose
        fit they match on the observed DOFs (the runs cannot tell them apart: that is what the report must say).
    """
    names = list(names or att.cat)
    nominal = att.fit([])
    # an effect the runs cannot identify is fitted on its grid only: its parameters are not identified, and refining
    # them (a tether's four anchor coordinates) would cost a fifth of a stock diagnosis for a number nobody reads
    singles = dict(zip(names, att.best_shapes((n, (), n not in exclude, ()) for n in names)))
    tau, _ = att.estimate_noise(singles)
    bic0 = att.bic(nominal)
    delta = {n: att.bic(f) - bic0 for n, f in singles.items()}
    selected, current, cur_bic, steps = [], nominal, bic0, []
    while len(selected) < max_effects:
        fixed = [(n, current.shapes[n]) for n in selected]
        # the grid plus the effect's refined single-effect shape: a coarse grid must not hand the step to a
        # many-parameter look-alike (e.g. cross-coupled damping for a current between grid points)
        cands = {n: att.best_shape(n, fixed, refine=False, seeds=(singles[n].shapes[n],))
                 for n in names if n not in selected and n not in exclude}
        if not cands:
            break
        ranked = sorted(cands, key=lambda n: att.bic(cands[n]))
        best, trials = ranked[0], {}
        if any(att.free_shapes(m) for m in selected):
            trials = {n: refit(att, [*selected, n], {**current.shapes, n: cands[n].shapes[n]})
                      for n in ranked[:REFIT_CONTENDERS]}
            best = min(trials, key=lambda n: att.bic(trials[n]))
        # the pick first, then (when it fails) the rest in BIC order whose grid fit passes both tests: one effect the
        # holdout rejects must not hide another that the fit runs and the holdout both support
        order = [best] + [n for n in ranked if n != best]
        added = None
        for n in order:
            if n != best and not (att.bic(cands[n]) - cur_bic < -BIC_STRONG
                                  and holdout_lr(att_h, current, cands[n]) > HOLDOUT_CHI2):
                continue
            if n in trials:
                fit_n = trials[n]
            elif trials:
                fit_n = refit(att, [*selected, n], {**current.shapes, n: cands[n].shapes[n]})
            else:
                fit_n = att.best_shape(n, fixed, refine=True)
            d_bic = att.bic(fit_n) - cur_bic
            lr = holdout_lr(att_h, current, fit_n)
            ok = passes_forward_test(d_bic, lr)
            steps.append(SelectionStep(n, float(d_bic), float(lr), bool(ok)))
            if log:
                log(f"  forward step {len(steps)}: {n} dBIC {d_bic:.1f}, holdout LR {lr:.1f} -> "
                    f"{'candidate' if ok else 'not added'}")
            if ok:
                added = (n, fit_n)
                break
        if added is None:
            if log:
                log("  forward selection stops: no remaining effect lowers the fit-run BIC by more than "
                    f"{BIC_STRONG:g} and raises the holdout likelihood by a ratio above {HOLDOUT_CHI2:g}")
            break
        selected.append(added[0])
        current, cur_bic = added[1], att.bic(added[1])
    return Selection(nominal=nominal, singles=singles, delta_bic=delta, steps=tuple(steps), tau_int=tau,
                     n_eff=att.n_eff, candidates=finalize(att, selected, names, current))


def refit(att: Attributor, members, shapes=None):
    """Joint fit of ``members`` with each one's shape re-optimised given the others (one coordinate pass).

    Used after members are dropped: the remaining parameters were fitted alongside the dropped ones and
    would otherwise keep the share of the residual the dropped effects had taken (the backward check's removal
    test, :func:`udrobot_ctrl.gap.confirm.check_members`, and :func:`finalize`); and by forward selection, to compare
    the best candidates of a step with every shape fitted again and to add the pick. A given shape also seeds its
    member's search, so the pass never ends worse than where it started. With no members it is the nominal fit.
    """
    shapes = {n: s for n, s in (shapes or {}).items() if n in members}
    for n in members:
        if n not in shapes:
            shapes[n] = att.best_shape(n, [(m, shapes[m]) for m in members if m in shapes]).shapes[n]
    for n in members:
        fixed = [(m, shapes[m]) for m in members if m != n]
        shapes[n] = att.best_shape(n, fixed, seeds=(shapes[n],)).shapes[n]
    return att.fit([(n, shapes[n]) for n in members])


def finalize(att: Attributor, selected, names, final=None, lookalikes=True) -> Combination:
    """Final joint fit of the selected effects (``final``, or a :func:`refit`), their look-alikes (unless
    ``lookalikes`` is False: an intermediate set) and the noise level per DOF."""
    selected = tuple(selected)
    final = final if final is not None else refit(att, selected)
    cur_bic = att.bic(final)
    screens = [(s_name, n, [(m, final.shapes[m]) for m in selected if m != s_name])
               for s_name in (selected if lookalikes else ()) for n in names if n not in selected]
    alts = att.best_shapes((n, others, False, ()) for _, n, others in screens)
    near = [i for i, alt in enumerate(alts) if att.bic(alt) - cur_bic < LOOKALIKE_SCREEN]  # refined before the test
    for i, alt in zip(near, att.best_shapes((screens[i][1], screens[i][2], True, ()) for i in near)):
        alts[i] = alt
    found = {(s_name, n) for (s_name, n, _), alt in zip(screens, alts) if att.bic(alt) - cur_bic < BIC_STRONG}
    indist = {s_name: [n for n in names if (s_name, n) in found] for s_name in (selected if lookalikes else ())}
    sigma = np.full(6, np.nan)
    sigma[att.dofs] = np.sqrt(final.rss / att.N)
    return Combination(members=selected, fit=final, indistinguishable=indist, noise_sigma=sigma)
