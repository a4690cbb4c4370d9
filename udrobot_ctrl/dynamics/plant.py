"""6-DOF Fossen plant, numpy implementation (vectorised over leading batch axes).

    eta_dot = J(eta) nu                                   (Fossen 2021, eq. 2.40)
    (M_RB + M_A) nu_dot + C_RB(nu) nu + C_A(nu) nu + D_L nu + D_n(nu) nu + g(eta) = tau

State order ``x y z phi theta psi u v w p q r`` (NED position, ZYX Euler angles, body velocities).
The equations themselves are written once, in :mod:`udrobot_ctrl.dynamics.equations`; this module
evaluates them on numpy arrays (any leading batch shape; per-vehicle parameters from
:func:`udrobot_ctrl.dynamics.sim.stack_parameters` too) and assembles the plant parameters. The casadi
twin :mod:`udrobot_ctrl.dynamics.plant_casadi` and the numba kernels use the same equations.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics.equations import equations

#: V, thruster supply assumed when a vehicle states none (UDrobot: Cely 2019 sec. 3.1 nominal 12 V).
DEFAULT_SUPPLY_VOLTAGE = 12.0

_EQ = equations(np.sin, np.cos, np.tan)
_KERNELS = None  # udrobot_ctrl.dynamics.sim_kernels once loaded (see compiled_kernels)
_KERNEL_PARAMETERS: dict = {}  # id(p) -> (p, kernel arguments), see _kernel_parameters


class SingularMassMatrixError(ValueError):
    """The total mass matrix M_RB + M_A is not symmetric positive definite."""


def skew(a):
    """Skew-symmetric matrix S(a) with S(a) b = a x b (works on (..., 3))."""
    a = np.asarray(a, dtype=float)
    z = np.zeros_like(a[..., 0])
    return np.stack([
        np.stack([z, -a[..., 2], a[..., 1]], -1),
        np.stack([a[..., 2], z, -a[..., 0]], -1),
        np.stack([-a[..., 1], a[..., 0], z], -1),
    ], -2)


def rigid_body_mass(mass, inertia_cg, r_g):
    """M_RB about CO (Fossen 2021 eq. 3.44): [[m I, -m S(r_g)], [m S(r_g), I_g - m S(r_g)^2]].

    Parameters
    ----------
    mass : float
        kg.
    inertia_cg : (3, 3) array_like
        Inertia about the CG, kg m^2.
    r_g : (3,) array_like
        CG position relative to CO, m.
    """
    S = skew(r_g)
    M = np.zeros((6, 6))
    M[:3, :3] = mass * np.eye(3)
    M[:3, 3:] = -mass * S
    M[3:, :3] = mass * S
    M[3:, 3:] = np.asarray(inertia_cg, float) - mass * S @ S
    return M


def wrap_angle(a):
    """Angle(s) wrapped to [-pi, pi), rad."""
    return (np.asarray(a, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def _components(a) -> np.ndarray:
    """(..., k) -> (k, ...): the component axis first, as :mod:`~udrobot_ctrl.dynamics.equations` indexes it."""
    a = np.asarray(a, dtype=float)
    return a.transpose((a.ndim - 1,) + tuple(range(a.ndim - 1))) if a.ndim > 1 else a  # np.moveaxis(a, -1, 0)


def _assemble(parts) -> np.ndarray:
    """Tuple of components -> (..., k) (components broadcast against each other)."""
    arrays = [np.asarray(a) for a in parts]
    out = np.empty(np.broadcast_shapes(*(a.shape for a in arrays)) + (len(arrays),), np.result_type(*arrays))
    for i, a in enumerate(arrays):
        out[..., i] = a
    return out


def coriolis_centripetal(M, nu):
    """C(nu) nu for a symmetric 6x6 inertia M, from Kirchhoff's equations (Fossen 2021 eqs. 3.46, 6.43).

    With a = M11 v + M12 w and b = M21 v + M22 w: C(nu) nu = [w x a ; v x a + w x b].
    Valid for M_RB, M_A and their sum. ``nu`` has shape (..., 6); returns N, N m.
    """
    return _assemble(_EQ.coriolis(np.asarray(M, dtype=float), _components(nu)))


def restoring_forces(eta, weight, buoyancy, r_g, r_b):
    """g(eta) for a submerged vehicle (Fossen 2021 eq. 4.6), N and N m.

    Parameters
    ----------
    eta : (..., 6) array_like
        Position (m) and ZYX Euler angles (rad); only phi and theta enter.
    weight, buoyancy : float
        W and B, N.
    r_g, r_b : (3,) array_like
        CG and CB relative to CO, m.
    """
    e = _components(eta)
    return _assemble(_EQ.restoring(e[3], e[4], weight, buoyancy, _components(r_g), _components(r_b)))


def rotation_zyx(phi, theta, psi):
    """Body-to-NED rotation R(Theta) for ZYX Euler angles (rad); broadcasts, returns (..., 3, 3)."""
    R = _assemble(_EQ.rotation(np.asarray(phi, float), np.asarray(theta, float), np.asarray(psi, float)))
    return R.reshape(R.shape[:-1] + (3, 3))


def kinematics(eta, nu):
    """eta_dot = J(eta) nu (Fossen 2021 eq. 2.40); singular at theta = +-pi/2.

    Returns (..., 6): NED velocity (m/s) and Euler-angle rates (rad/s).
    """
    eta, nu = np.asarray(eta, dtype=float), np.asarray(nu, dtype=float)
    if eta.shape == nu.shape and eta.ndim <= 2 and eta.shape[-1:] == (6,):  # the compiled twin, row by row
        rows = eta.reshape(-1, 6)
        out = np.empty(rows.shape)
        compiled_kernels().kinematics_rows(np.ascontiguousarray(rows), np.ascontiguousarray(nu.reshape(-1, 6)), out)
        return out.reshape(eta.shape)
    return _assemble(_EQ.kinematics(_components(eta), _components(nu)))


def thruster_matrix(thrusters):
    """Thruster configuration matrix T (6 x n): tau = T f, columns [d_i ; r_i x d_i].

    Parameters
    ----------
    thrusters : sequence of Thruster
        Positions (m, body frame, relative to CO) and directions (normalised here).

    Returns
    -------
    (6, n) ndarray
        Column i: the wrench X Y Z (N) K M N (N m) of 1 N from thruster i.
    """
    cols = []
    for t in thrusters:
        d = np.asarray(t.direction, float)
        d = d / np.linalg.norm(d)
        cols.append(np.concatenate([d, np.cross(np.asarray(t.position, float), d)]))
    return np.array(cols).T if cols else np.zeros((6, 0))


def thrust_limits(thrusters):
    """Per-thruster limits (lower, upper) in N: [-max_reverse_N, max_forward_N]."""
    lo = np.array([-t.max_reverse_N for t in thrusters], float)
    hi = np.array([t.max_forward_N for t in thrusters], float)
    return lo, hi


@dataclass(frozen=True)
class PlantParameters:
    """Precomputed numeric arrays of a vehicle for fast evaluation (:func:`plant_parameters` builds them).

    Attributes
    ----------
    M, M_inv : (6, 6) ndarray
        Mass matrix M = M_RB + M_A (kg, kg m, kg m^2) about CO and its inverse.
    D_L : (6, 6) ndarray
        Linear damping, N s/m and N m s/rad.
    Q : (6, 6) ndarray
        Quadratic damping coefficients: D_n(nu)_ij = Q_ij |nu_j|.
    weight, buoyancy : float
        W = m g and B = rho g V, N.
    r_g, r_b : (3,) ndarray
        Centres of gravity and buoyancy relative to CO, m.
    T : (6, n) ndarray
        Thruster configuration matrix (:func:`thruster_matrix`).
    f_min, f_max : (n,) ndarray
        Each thruster's thrust limits, N (f_min <= 0 <= f_max).
    name : str
        The model's name.
    M_A : (6, 6) ndarray, optional
        Added mass alone, kg and kg m^2.
    effects : tuple of PlantEffect
        The model's effects that act at run time (thrust, lag, force); see :mod:`udrobot_ctrl.dynamics.effects`.
    supply_voltage : float
        Thruster supply voltage for PWM -> thrust, V (the vehicle's own, or the T200 curve's default).
    ardusub_frame : str, optional
        The vehicle's ArduSub frame (its autopilot's mixer), None if it has none.
    size_m : float, optional
        The largest distance of a thruster from CO, m (bounds a centre of pressure or a tether attachment);
        None if unknown.
    """

    M: np.ndarray
    M_inv: np.ndarray
    D_L: np.ndarray
    Q: np.ndarray
    weight: float
    buoyancy: float
    r_g: np.ndarray
    r_b: np.ndarray
    T: np.ndarray
    f_min: np.ndarray
    f_max: np.ndarray
    name: str = ""
    M_A: np.ndarray | None = None
    effects: tuple = ()  # the model's effects that act at run time (thrust, lag, force); see dynamics.effects

    @property
    def f_ref(self) -> np.ndarray:
        """Each thruster's capacity max(max_forward_N, max_reverse_N), N (reference of the thrust maps)."""
        return np.maximum(np.asarray(self.f_max, float), -np.asarray(self.f_min, float))

    @property
    def capacities(self) -> tuple:
        """Each thruster's forward and reverse capacity (max_forward_N, max_reverse_N), N, both positive."""
        return np.asarray(self.f_max, float), -np.asarray(self.f_min, float)
    supply_voltage: float = DEFAULT_SUPPLY_VOLTAGE  # V, thruster supply for pwm -> thrust (the vehicle's own)
    ardusub_frame: str | None = None  # the vehicle's ArduSub frame (its autopilot's mixer), None if it has none
    #: the vehicle's size (m): the largest distance of a thruster from the CO (effects.vehicle_size), bounding a centre
    #: of pressure or a tether attachment; None: unknown (effects.ASSUMED_VEHICLE_SIZE_M)
    size_m: float | None = None


def plant_parameters(vehicle) -> PlantParameters:
    """Assemble M = M_RB + M_A and the other arrays; checks M is symmetric positive definite.

    Parameters
    ----------
    vehicle : udrobot_ctrl.vehicle.Vehicle
        The vehicle's data (SI units). Read by its fields only: the vehicle layer sits above this one
        (docs/architecture.md), so it is not imported here.

    Returns
    -------
    PlantParameters
        The arrays the equations take, with the vehicle's effects folded in.

    Raises
    ------
    SingularMassMatrixError
        If M is not symmetric or not positive definite (naming the model).
    """
    M = rigid_body_mass(vehicle.mass, vehicle.inertia_cg, vehicle.r_g) + np.asarray(vehicle.added_mass, float)
    if not np.allclose(M, M.T, atol=1e-9 * max(1.0, np.abs(M).max())):
        raise SingularMassMatrixError(f"model {vehicle.name!r}: M_RB + M_A is not symmetric")
    eig = np.linalg.eigvalsh(0.5 * (M + M.T))
    if eig.min() <= 1e-9 * eig.max():
        raise SingularMassMatrixError(
            f"model {vehicle.name!r}: M_RB + M_A is not positive definite (smallest eigenvalue {eig.min():.3g})"
        )
    lo, hi = thrust_limits(vehicle.thrusters)
    nominal = PlantParameters(
        M=M, M_inv=np.linalg.inv(M), D_L=np.asarray(vehicle.linear_damping, float),
        Q=np.asarray(vehicle.quadratic_damping, float), weight=vehicle.weight, buoyancy=vehicle.buoyancy,
        r_g=np.asarray(vehicle.r_g, float), r_b=np.asarray(vehicle.r_b, float),
        T=thruster_matrix(vehicle.thrusters), f_min=lo, f_max=hi, name=vehicle.name,
        M_A=np.asarray(vehicle.added_mass, float),
        supply_voltage=float((vehicle.extras or {}).get("voltage", DEFAULT_SUPPLY_VOLTAGE)),
        ardusub_frame=(vehicle.extras or {}).get("ardusub_frame") or None,
        size_m=fx.vehicle_size([t.position for t in vehicle.thrusters]),
    )
    return fx.fold_parameters(nominal, vehicle.effects) if vehicle.effects else nominal


def compiled_kernels():
    """:mod:`udrobot_ctrl.dynamics.sim_kernels` (the numba twins of the equations), loaded on first use: the one
    loader of the plant's row kernels and the simulator's integration kernels."""
    global _KERNELS
    if _KERNELS is None:
        # local import: loading the numba kernels takes ~1.5 s, paid only by the calls that run them
        from udrobot_ctrl.dynamics import sim_kernels

        _KERNELS = sim_kernels
    return _KERNELS


def _kernel_parameters(p: PlantParameters) -> tuple:
    """(M, D_L, Q, W, B, r_g, r_b) of one vehicle as the compiled kernels take them (C-contiguous float64).

    Kept for the few most recent parameter sets (a replay evaluates the same ones thousands of times); the
    entry holds ``p`` itself, so its id cannot be reused while cached, and ``p`` is frozen.
    """
    hit = _KERNEL_PARAMETERS.get(id(p))
    if hit is not None and hit[0] is p:
        return hit[1]
    def c(a):
        return np.ascontiguousarray(a, dtype=float)
    out = (c(p.M), c(p.D_L), c(p.Q), float(p.weight), float(p.buoyancy), c(p.r_g), c(p.r_b))
    if len(_KERNEL_PARAMETERS) >= 16:
        _KERNEL_PARAMETERS.clear()
    _KERNEL_PARAMETERS[id(p)] = (p, out)
    return out


def _parameters(p: PlantParameters) -> tuple:
    """(M, M_inv, D_L, Q, W, B, r_g, r_b) indexed as the equations expect; a leading vehicle axis moves last."""
    stacked = np.ndim(p.M) == 3

    def per_vehicle(a):
        a = np.asarray(a, dtype=float)
        return np.moveaxis(a, 0, -1) if stacked else a

    rg, rb = np.asarray(p.r_g, float), np.asarray(p.r_b, float)
    return (per_vehicle(p.M), per_vehicle(p.M_inv), per_vehicle(p.D_L), per_vehicle(p.Q),
            np.asarray(p.weight, float), np.asarray(p.buoyancy, float),
            np.moveaxis(rg, -1, 0), np.moveaxis(rb, -1, 0))


def require_nominal(p: PlantParameters, tool: str) -> None:
    """Refuse a model with run-time effects in ``tool``, which holds only the nominal equations (its parameter
    effects are already folded into the matrices and need no refusal)."""
    if p.effects:
        raise ValueError(f"model {p.name!r} has effects ({', '.join(e.name for e in p.effects)}) that {tool} does "
                         f"not simulate; use udrobot_ctrl.dynamics.sim.simulate, which does")


def _check_last_axis(name, a, n):
    if a.shape[-1:] != (n,):
        raise ValueError(f"{name} must have {n} components on its last axis (got shape {a.shape})"
                         + ("; thruster forces become a wrench with thrust_to_wrench(f, p)" if name == "tau" else ""))


def generalized_forces(x, p: PlantParameters):
    """Sum of C(nu) nu + D(nu) nu + g(eta) for state x (..., 12), minus the force effects of the model; N, N m."""
    x = np.asarray(x, dtype=float)
    _check_last_axis("x", x, 12)
    if x.ndim <= 2 and np.ndim(p.M) == 2:  # one vehicle: the compiled twin of the equations, row by row
        out = np.empty((x.size // 12, 6))
        compiled_kernels().generalized_forces_rows(np.ascontiguousarray(x.reshape(-1, 12)), *_kernel_parameters(p), out)
        F = out.reshape(x.shape[:-1] + (6,))
        return F - _assemble(effect_forces(_components(x), p)) if p.effects else F
    M, _, D_L, Q, W, B, r_g, r_b = _parameters(p)
    X = _components(x)
    F = _EQ.generalized_forces(X, M, D_L, Q, W, B, r_g, r_b)
    if p.effects:
        F = tuple(a - b for a, b in zip(F, effect_forces(X, p)))
    return _assemble(F)


def state_derivative(x, tau, p: PlantParameters):
    """x_dot = f(x, tau) for state (..., 12) and body wrench tau (..., 6) in N, N m.

    ``tau`` is the body wrench, not per-thruster thrusts: convert those with :func:`thrust_to_wrench`.
    The equations of the module docstring: eta_dot = J(eta) nu (Fossen 2021, eq. 2.40) and
    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau plus the model's run-time effects.

    Parameters
    ----------
    x : (..., 12) array_like
        State x y z (m, NED) phi theta psi (rad) u v w (m/s, body) p q r (rad/s, body).
    tau : (..., 6) array_like
        Body wrench X Y Z (N) K M N (N m).
    p : PlantParameters
        The plant.

    Returns
    -------
    (..., 12) ndarray
        State derivative: m/s, rad/s, m/s^2 and rad/s^2.

    Raises
    ------
    ValueError
        If ``x`` does not end in 12 states or ``tau`` in 6 wrench components.
    """
    x = np.asarray(x, dtype=float)
    tau = np.asarray(tau, float)
    if x.shape[-1:] != (12,):
        raise ValueError(f"state_derivative: x has shape {x.shape}; expected (..., 12) "
                         "(x y z phi theta psi u v w p q r)")
    if tau.shape[-1:] != (6,):
        hint = (f"; {tau.shape[-1]} values look like per-thruster thrusts: pass thrust_to_wrench(thrusts, p)"
                if tau.ndim and tau.shape[-1] == p.T.shape[1] else "")
        raise ValueError(f"state_derivative: tau has shape {tau.shape}; expected (..., 6), the body wrench "
                         f"X Y Z K M N in N and N m{hint}")
    if not p.effects:
        return _assemble(_EQ.state_derivative(_components(x), _components(tau), *_parameters(p)))
    X = _components(x)
    eta, nu = X[:6], X[6:]
    rhs = tau - generalized_forces(x, p)
    dM = fx.added_mass_increment(fx.NUMPY, eta, nu, p.effects)
    if dM is None:
        nu_dot = rhs @ np.asarray(p.M_inv).T
    else:
        Mt = np.asarray(p.M) + np.stack(np.broadcast_arrays(*[_assemble(row) for row in dM]), axis=-2)
        nu_dot = np.linalg.solve(Mt, rhs[..., None])[..., 0]
    return np.concatenate([_assemble(_EQ.kinematics(eta, nu)), nu_dot], axis=-1)


def water_relative_terms(nu, p: PlantParameters) -> tuple:
    """C_A(nu) nu + D(nu) nu (6 components, N and N m) for velocity components ``nu``: the terms that act on the
    velocity relative to the water (a current changes them). Batches of at most one axis go through the compiled
    twin of the equations (:func:`compiled_kernels`, with the added mass as the inertia and no restoring force; a
    replay evaluates them thousands of times on a few dozen states), others through the equations themselves."""
    comps = np.broadcast_arrays(*[np.asarray(c, float) for c in nu])
    M_A, D_L, Q = (np.ascontiguousarray(a, dtype=float) for a in (p.M_A, p.D_L, p.Q))
    if comps[0].ndim <= 1 and M_A.ndim == 2:
        v = np.stack(comps, axis=-1).reshape(-1, 6)
        out = np.empty_like(v)
        zero3 = np.zeros(3)
        compiled_kernels().generalized_forces_rows(np.concatenate([np.zeros_like(v), v], axis=1), M_A, D_L, Q, 0.0,
                                                   0.0, zero3, zero3, out)
        return tuple(out.reshape(comps[0].shape + (6,))[..., i] for i in range(6))
    return tuple(a + b for a, b in zip(_EQ.damping(D_L, Q, nu), _EQ.coriolis(M_A, nu)))


def effect_forces(X, p: PlantParameters) -> tuple:
    """Generalised force (6 components, N and N m) of the model's force effects at state components ``X``.

    The water current enters as the change of the damping and added-mass Coriolis terms when they act on the
    velocity relative to the water; tether and wall suction as external forces.
    """
    eta, nu = X[:6], X[6:]
    total = [0.0] * 6
    nu_r = fx.relative_velocity(fx.NUMPY, eta, nu, p.effects)
    if nu_r is not nu:
        total = [a - b for a, b in zip(water_relative_terms(nu, p), water_relative_terms(nu_r, p))]
    ext = fx.external_force(fx.NUMPY, eta, nu, p.effects)
    if ext is not None:
        total = [a + b for a, b in zip(total, ext)]
    return tuple(total)


def delivered_wrench(x, f, p: PlantParameters):
    """Body wrench (..., 6) of thrusts ``f`` (..., n) that are already clipped, mapped and lagged, after the
    state-dependent inflow loss of the model's effects (:func:`udrobot_ctrl.dynamics.effects.inflow_loss`)."""
    f = np.asarray(f, dtype=float)
    fe = fx.thrust_effects(p.effects)
    if any(e.name == "thrust_inflow_loss" for e in fe):
        X = _components(np.asarray(x, float))
        f = _assemble(fx.inflow_loss(fx.NUMPY, list(_components(f)), X[6:], fe, p.T, p.f_ref))
    return f @ np.asarray(p.T).T


def thrust_to_wrench(f, p: PlantParameters, clip=True):
    """Body wrench tau = T sat(f) (N, N m) from thrusts f (..., n) in N; clipped to each thruster's limits.

    Parameters
    ----------
    f : (..., n) array_like
        Thrust of each thruster, N, in the model's thruster order.
    p : PlantParameters
        The plant (its ``T``, ``f_min``, ``f_max``).
    clip : bool
        Clip each thrust to [f_min, f_max] first (default True).

    Returns
    -------
    (..., 6) ndarray
        Body wrench X Y Z (N) K M N (N m).
    """
    f = np.asarray(f, dtype=float)
    if clip:
        f = np.clip(f, p.f_min, p.f_max)
    return f @ p.T.T
