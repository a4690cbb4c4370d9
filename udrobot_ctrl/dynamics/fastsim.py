"""Fast open-loop simulation with casadi: RK4 ``mapaccum`` rollouts, optional C compilation, vehicle batches.

* :func:`rollout` — one vehicle, an input sequence (n_steps, k) held per step of ``dt``: the RK4 step of
  :func:`udrobot_ctrl.dynamics.plant_casadi.rk4_step_function` accumulated over time with ``mapaccum`` (one call,
  no Python loop). :class:`Rollout` caches the built (and, when ``compile=True``, gcc-compiled) function;
  compiled libraries are cached on disk keyed by a hash of the plant parameters, dt, horizon and casadi version,
  and compilation is abandoned (falling back to casadi's virtual machine) if gcc takes longer than 2 s.
* :func:`rollout_batch` — N vehicles with their own hydrodynamic and restoring parameters (a parametric RK4
  step ``map``-ped over vehicles), one shared input sequence, states recorded every ``record_every`` steps.

Thrust inputs are clipped to each thruster's limits before integration (as :func:`udrobot_ctrl.dynamics.sim.simulate`).
Closed-loop simulation, also of N vehicles with their own parameters (the sensitivity sweeps), stays in
:mod:`udrobot_ctrl.dynamics.sim`.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from udrobot_ctrl.caches import private_dir, unsafe_reason, user_cache_root
from udrobot_ctrl.dynamics import integrators, plant_casadi
from udrobot_ctrl.dynamics.plant import PlantParameters, require_nominal
from udrobot_ctrl.dynamics.sim import as_parameters
from udrobot_files.output import atomic_write

COMPILE_TIMEOUT_S = 2.0


def cache_dir() -> Path:
    """Directory for compiled rollouts (``$UDROBOT_CACHE``, else ``$XDG_CACHE_HOME/udrobot_ctrl/fastsim``,
    :func:`udrobot_ctrl.caches.user_cache_root`); see :func:`private_cache_dir` for the checks made before
    anything in it is loaded."""
    chosen = os.environ.get("UDROBOT_CACHE")
    return Path(chosen) if chosen else user_cache_root() / "fastsim"


def private_cache_dir() -> Path:
    """:func:`cache_dir`, created 0700, if it is a folder owned by this user and not writable by others; else
    (with a warning) a private temporary folder for this process (:func:`udrobot_ctrl.caches.private_dir`)."""
    return private_dir(cache_dir(), "fastsim")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def verified_library(lib: Path):
    """None if ``lib`` may be loaded: ours, not writable by others, and its sha256 equals the one recorded in
    ``<lib>.sha256`` when it was built; else the reason it must not be loaded."""
    for f in (lib, lib.with_name(lib.name + ".sha256")):
        why = unsafe_reason(f, want_dir=False)
        if why is not None:
            return f"{f.name} {why}"
    recorded = lib.with_name(lib.name + ".sha256").read_text(encoding="ascii", errors="replace").strip()
    if _sha256(lib) != recorded:
        return f"{lib.name} does not match the sha256 recorded when it was built"
    return None


def parameter_hash(p: PlantParameters, *extra) -> str:
    """sha256 (16 hex) of every numeric plant array, the extra keys and the casadi version."""
    h = hashlib.sha256(ca.__version__.encode())
    for a in (p.M, p.D_L, p.Q, p.r_g, p.r_b, p.T, p.f_min, p.f_max, [p.weight, p.buoyancy]):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    h.update(repr(extra).encode())
    return h.hexdigest()[:16]


def compile_function(fun: ca.Function, key: str, timeout: float = COMPILE_TIMEOUT_S):
    """A gcc-compiled copy of ``fun`` loaded with ``casadi.external`` (cached as ``<name>_<key>.so``), or None.

    The library lives in :func:`private_cache_dir` with its sha256 in ``<lib>.sha256``; a cached library is
    loaded only if both files are this user's, not writable by others, and the hash matches (else it is
    rebuilt, with a warning). Returns None (caller keeps the interpreted function) when gcc is missing,
    fails or exceeds ``timeout`` s.
    """
    folder = private_cache_dir()
    lib = folder / f"{fun.name()}_{key}.so"
    digest = lib.with_name(lib.name + ".sha256")
    if lib.exists() or lib.is_symlink():
        why = verified_library(lib)
        if why is None:
            try:
                return ca.external(fun.name(), str(lib))
            except RuntimeError:
                why = "failed to load"
        warnings.warn(f"compiled kernel {lib}: {why}; rebuilding it", RuntimeWarning, stacklevel=2)
        lib.unlink(missing_ok=True)
        digest.unlink(missing_ok=True)
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        src = f"{fun.name()}_{key}.c"
        gen = ca.CodeGenerator(src, {"with_header": False})
        gen.add(fun)
        gen.generate(tmp + os.sep)
        out = Path(tmp) / "lib.so"
        try:
            subprocess.run([gcc, "-O1", "-fPIC", "-shared", str(Path(tmp) / src), "-o", str(out), "-lm"],
                           check=True, timeout=timeout, capture_output=True)
        except (subprocess.TimeoutExpired, subprocess.CalledProcessError, OSError):
            return None
        data = out.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    # the hash first, then the library: a reader never sees a library without its hash (concurrent builders
    # write identical bytes); both via unpredictable O_EXCL temporary names in the private folder
    atomic_write(digest, sha + "\n", file_mode=0o600)
    atomic_write(lib, data, file_mode=0o600)
    if verified_library(lib) is not None:  # replaced between our write and now: do not load it
        return None
    return ca.external(fun.name(), str(lib))


class Rollout:
    """Open-loop RK4 rollout of one vehicle over ``n_steps`` steps of ``dt`` s.

    Parameters
    ----------
    model : name, path, Vehicle or PlantParameters
    dt : float
        Step, s.
    n_steps : int
        Horizon in steps.
    inputs : {'thrust', 'tau'}
    compile : bool
        Try to compile to C (cached on disk); falls back silently, see :attr:`compiled`.
    """

    def __init__(self, model, dt: float, n_steps: int, inputs: str = "thrust", compile: bool = False):
        if dt <= 0 or n_steps < 1:
            raise ValueError(f"dt must be > 0 and n_steps >= 1 (got dt={dt}, n_steps={n_steps})")
        self.p = as_parameters(model)
        self.dt, self.n_steps, self.inputs = float(dt), int(n_steps), inputs
        step = plant_casadi.rk4_step_function(self.p, self.dt, inputs, name="rk4")
        self.k = step.size1_in(1)
        self.function = step.mapaccum("rollout", self.n_steps)
        self.compiled = False
        if compile:
            fun = compile_function(self.function, parameter_hash(self.p, self.dt, self.n_steps, inputs))
            if fun is not None:
                self.function, self.compiled = fun, True

    def __call__(self, x0, u) -> np.ndarray:
        """States (n_steps + 1, 12) from ``x0`` (12,) with ``u`` (n_steps, k) or (k,) held per step."""
        u = np.broadcast_to(np.asarray(u, dtype=float), (self.n_steps, self.k))
        if self.inputs == "thrust":
            u = np.clip(u, self.p.f_min, self.p.f_max)
        x0 = np.asarray(x0, dtype=float).reshape(12)
        xs = np.asarray(self.function(x0, u.T)).T
        out = np.vstack([x0, xs])
        if not np.all(np.isfinite(out)):
            bad = int(np.argmax(~np.all(np.isfinite(out), axis=1)))
            raise FloatingPointError(f"rollout of {self.p.name!r} diverged at t = {bad * self.dt:.3f} s")
        return out


def rollout(model, x0, u, dt: float = 0.01, inputs: str = "thrust", compile: bool = False) -> np.ndarray:
    """One-shot :class:`Rollout`: states (n + 1, 12) for inputs ``u`` (n, k)."""
    u = np.atleast_2d(np.asarray(u, float))
    return Rollout(model, dt, u.shape[0], inputs, compile)(x0, u)


# ----------------------------------------------------------------------------- batches of vehicles
MATRICES = ("M", "M_inv", "D_L", "Q")


def sparsity_patterns(params, tol: float = 0.0) -> tuple:
    """Union over vehicles of the nonzero patterns of M, M^-1, D_L, Q (four (6, 6) bool arrays)."""
    return tuple(np.any([np.abs(getattr(p, name)) > tol for p in params], axis=0) for name in MATRICES)


def pack_parameters(p: PlantParameters, patterns=None) -> np.ndarray:
    """Per-vehicle numbers of the batch step: entries of M, M^-1, D_L, Q inside ``patterns`` (row-major;
    all 36 when None), then W, B (N), r_g, r_b (m)."""
    require_nominal(p, "the batch rollout (per-vehicle parameters)")
    patterns = patterns or tuple(np.ones((6, 6), bool) for _ in MATRICES)
    mats = [getattr(p, name)[mask] for name, mask in zip(MATRICES, patterns)]
    return np.concatenate(mats + [[p.weight, p.buoyancy], p.r_g, p.r_b])


def _unpack(theta, patterns):
    mats, k = [], 0
    for mask in patterns:
        m = ca.SX(6, 6)
        for i, j in zip(*np.nonzero(mask)):
            m[int(i), int(j)] = theta[k]
            k += 1
        mats.append(m)
    return mats, [theta[k + i] for i in range(8)]


def _parametric_derivative(x, tau, theta, patterns):
    """Symbolic x_dot with parameters theta (see :func:`pack_parameters`): the equations of
    :mod:`udrobot_ctrl.dynamics.equations` with symbolic matrices (structural zeros outside ``patterns``)."""
    (M, M_inv, D_L, Q), (W, B, xg, yg, zg, xb, yb, zb) = _unpack(theta, patterns)
    return ca.vertcat(*plant_casadi.EQUATIONS.state_derivative(x, tau, M, M_inv, D_L, Q, W, B,
                                                                ca.vertcat(xg, yg, zg), ca.vertcat(xb, yb, zb)))


def batch_step_function(T: np.ndarray, dt: float, inputs: str = "thrust", patterns=None) -> ca.Function:
    """RK4 step F(x[12], u[k], theta) -> x_next with per-vehicle parameters theta (:func:`pack_parameters`)."""
    patterns = patterns or tuple(np.ones((6, 6), bool) for _ in MATRICES)
    x = ca.SX.sym("x", 12)
    theta = ca.SX.sym("theta", int(sum(m.sum() for m in patterns)) + 8)
    if inputs == "thrust":
        u = ca.SX.sym("u", T.shape[1])
        tau = ca.DM(np.asarray(T, float)) @ u
    elif inputs == "tau":
        u = ca.SX.sym("u", 6)
        tau = u
    else:
        raise ValueError(f"inputs must be 'thrust' or 'tau', got {inputs!r}")
    x_next = integrators.rk4_step(lambda _t, xx: _parametric_derivative(xx, tau, theta, patterns), 0.0, x, dt)
    return ca.Function("rk4p", [x, u, theta], [x_next])


@dataclass
class BatchRollout:
    """N vehicles x ``n_records * record_every`` RK4 steps, one shared input sequence.

    The parametric RK4 step is ``map``-ped over vehicles and chained ``record_every`` times into one
    (optionally compiled) function called once per record, so memory is 12 x N x n_records doubles. ``patterns``
    (from :func:`sparsity_patterns`) restricts the matrices to their nonzero entries (fewer operations).
    """

    T: np.ndarray
    f_min: np.ndarray
    f_max: np.ndarray
    dt: float
    n_records: int
    record_every: int
    n_vehicles: int
    inputs: str = "thrust"
    parallel: str = "serial"
    compile: bool = False
    patterns: tuple | None = None

    def __post_init__(self):
        step = batch_step_function(self.T, self.dt, self.inputs, self.patterns)
        k = step.size1_in(1)
        xs, thetas = ca.MX.sym("x", 12, self.n_vehicles), ca.MX.sym("theta", step.size1_in(2), self.n_vehicles)
        us = ca.MX.sym("u", k, self.record_every)
        mapped = step.map(self.n_vehicles, self.parallel)
        x = xs
        for j in range(self.record_every):
            x = mapped(x, us[:, j], thetas)
        # records are looped in Python (n_records calls): casadi's mapaccum of this large MX graph costs
        # seconds and gigabytes to build for 1000 vehicles, the loop costs microseconds per call
        self.k = k
        self.function = ca.Function("batch_chunk", [xs, us, thetas], [x])
        self.compiled = False
        if self.compile:
            pat = None if self.patterns is None else [np.asarray(m).tolist() for m in self.patterns]
            key = hashlib.sha256(repr((np.asarray(self.T).tolist(), self.dt, self.n_records, self.record_every,
                                       self.n_vehicles, self.inputs, pat, self.parallel,
                                       ca.__version__)).encode()).hexdigest()[:16]
            fun = compile_function(self.function, key)
            if fun is not None:
                self.function, self.compiled = fun, True

    def __call__(self, x0, u, thetas) -> np.ndarray:
        """States (n_records + 1, N, 12) every ``record_every * dt`` s.

        x0 : (N, 12) or (12,); u : (n_steps, k) or (k,) shared by all vehicles; thetas : (N, n_theta) from
        :func:`pack_parameters` with the same ``patterns``.
        """
        n_steps = self.n_records * self.record_every
        u = np.broadcast_to(np.asarray(u, float), (n_steps, self.k))
        if self.inputs == "thrust":
            u = np.clip(u, self.f_min, self.f_max)
        x0 = np.broadcast_to(np.asarray(x0, float), (self.n_vehicles, 12))
        th = ca.DM(np.asarray(thetas, float).T)
        out = np.empty((self.n_records + 1, self.n_vehicles, 12))
        out[0] = x0
        x = ca.DM(np.ascontiguousarray(x0.T))
        r = self.record_every
        for j in range(self.n_records):
            x = self.function(x, u[j * r:(j + 1) * r].T, th)
            out[j + 1] = np.asarray(x).T
        if not np.all(np.isfinite(out)):
            raise FloatingPointError(f"batch rollout diverged for vehicles "
                                     f"{np.nonzero(~np.all(np.isfinite(out), axis=(0, 2)))[0][:10].tolist()}")
        return out


def rollout_batch(models, x0, u, dt: float = 0.01, record_every: int = 10, inputs: str = "thrust",
                  compile: bool = False, parallel: str = "serial") -> np.ndarray:
    """Simulate N vehicles (sequence of models sharing one thruster layout) under one input sequence.

    Returns states (n_steps // record_every + 1, N, 12), recorded every ``record_every * dt`` s.
    """
    ps = [as_parameters(m) for m in models]
    p0 = ps[0]
    for i, p in enumerate(ps[1:], start=1):
        if not (np.allclose(p.T, p0.T) and np.allclose(p.f_min, p0.f_min) and np.allclose(p.f_max, p0.f_max)):
            raise ValueError(f"vehicle {i} has a different thruster layout or limits from vehicle 0")
    u = np.atleast_2d(np.asarray(u, float))
    if u.shape[0] % record_every:
        raise ValueError(f"number of input steps {u.shape[0]} must be a multiple of record_every={record_every}")
    patterns = sparsity_patterns(ps)
    br = BatchRollout(p0.T, p0.f_min, p0.f_max, dt, u.shape[0] // record_every, record_every, len(ps), inputs,
                      parallel, compile, patterns)
    return br(x0, u, np.stack([pack_parameters(p, patterns) for p in ps]))
