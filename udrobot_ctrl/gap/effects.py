"""The effect catalogue: each unmodelled effect as a physically parameterised addition to the plant.

Every effect contributes an extra generalised force ``p`` (N, N m) to the nominal equation of motion

    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = B f + p(x, nu_dot, f; theta)

so that, with the *equation-error residual* ``r = M nu_dot + C nu + D nu + g - B f`` computed from the
measured (smoothed) velocities, each effect predicts ``r``. The parameters split into a few *shape*
parameters (searched on a grid and refined, e.g. a lag time constant or a decay length) and *amplitude*
parameters entering linearly (fitted by bounded least squares): ``p = b0(shape) + A(shape) a``.

Replays use the plant's own definition of each effect (:mod:`udrobot_ctrl.dynamics.effects`, the physics a
corrected model simulates): :meth:`Effect.hooks` wraps it as an input filter (deadband, asymmetry, lag), a
state-dependent force and an added-mass increment. The regressors below are the derivatives of those forms with
respect to their amplitude parameters, evaluated on the measured (smoothed) data.

Templates (the diagnoser's lumped forms; a truth generator should use different forms):

``thrust_inflow_loss``  f_act = f - (k1 |f| + k2 sqrt(|f| f_ref)) u_a, u_a the axial advance speed of the
                        actuator (linear K_T(J) gives the sqrt term, fixed-rpm curves the |f| term).
``thruster_deadband``   a deadband of width w in the normalised command u = (|f|/f_ref)^(1/p), p the shape
                        ``command_exponent``: f_act = 0 for u < w; beyond, a blend (amplitude c) of the hard cut
                        and the continuous curve from zero at w (p = 1: f - c w f_ref sign(f); p = 2, c = 1: thrust
                        ~ (u - w)^2 rescaled to full thrust at full command, an ESC's PWM-domain deadband).
``thruster_asymmetry``  reverse thrust (1 - a) f for f < 0.
``thruster_lag``        first-order lag of time constant T_lag on every actuator, of the thrust (k = 1) or of the
                        rotor speed (k = 2, thrust ~ n|n|), k the shape ``thrust_exponent``.
``tether_drag``         cross-flow drag of a cable from the vehicle to an anchor fixed in the pool (a deck, a boat;
                        shape: its NED position), e the unit vector towards it: F_ned = -(k_q |V_n| + k_l) V_n,
                        V_n = V - (V.e) e. The direction turns as the vehicle moves; a far anchor is a fixed
                        direction (a cable straight up gives horizontal drag). The top end may walk with the
                        vehicle, and the cable be slack (lumped) or taut (drag per metre of the straight line);
                        it is tied at a hull point r_a (shape), with that point's velocity and the moment r_a x F.
``wall_effect``         per surface at distance h with normal n: added mass a_m exp(-h/lam) n n^T and a
                        suction force -a_s exp(-h/lam) |V_t|^2 n (V_t the speed along the surface).
``water_current``       steady NED current (c_N, c_E, c_D): damping acts on nu - R^T c.
``linear_damping``      extra diagonal linear damping d_i (N s/m, N m s).
``quadratic_damping_error``  Q_ii scaled by (1 + s_i), the error's drag on each axis' speed |nu_i| or (shape
                        ``norm_weight`` a) on (1 - a) |nu_i| + a |nu_g|, |nu_g| the translational or rotational speed.
``added_mass_error``    M_A,ii scaled by (1 + s_i) (with its Coriolis-centripetal part).
``cross_coupled_damping``    off-diagonal linear and quadratic damping D_ij nu_j, Q_ij |nu_j| nu_j.
``buoyancy_offset``     net buoyancy B - W changed by dB (N).
``cg_cb_offset``        restoring moments (x_g W - x_b B, y_g W - y_b B, z_g W - z_b B) changed by dBG (N m).
``drag_centre_offset``  the nominal translational drag F(v) = -(D v + Q |v| v) acts at a centre of pressure r_cp off
                        the CO, with that point's velocity v + omega x r_cp, and makes the moment r_cp x F; the
                        template is its expansion to first order in r_cp (linear in r_cp: least squares), the
                        replay the plant's exact form.
"""
from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass, field, replace
from functools import partial
from typing import ClassVar, NamedTuple

import numpy as np

from udrobot_ctrl.constants import DOF_NAMES as DOF
from udrobot_ctrl.constants import VELOCITY_NAMES as VEL
from udrobot_ctrl.dynamics import effects as pfx
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import (
    PlantParameters,
    coriolis_centripetal,
    effect_forces,
    generalized_forces,
    rotation_zyx,
)
from udrobot_ctrl.gap.data import restoring_gradient

EFFECT_NAMES = pfx.EFFECT_NAMES


@dataclass
class Stack:
    """Samples of one or more prepared runs stacked for equation-error fitting (n valid samples).

    ``runs`` keeps, per run, the full command sequence and the indices of its valid samples, so that
    input filters (lag) run over the whole sequence before sampling.
    """

    nu: np.ndarray
    nu_dot: np.ndarray
    eta: np.ndarray
    f: np.ndarray
    B: np.ndarray
    inflow: np.ndarray
    f_ref: np.ndarray
    surfaces: dict
    runs: list
    p: PlantParameters
    M_A: np.ndarray
    virtual: bool = False  # tau_* inputs: six virtual wrench actuators (B = I)
    #: terms of a run's arrays that every shape of an effect reads alike (:meth:`kept`); shared by the copies
    #: ``replace`` makes, keyed by the arrays' identity
    memo: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        return int(self.nu.shape[0])

    def kept(self, what: str, arrays, compute):
        """``compute(*arrays)`` for a run's full-rate ``arrays``, computed once per stack (and its copies): a
        shape-independent term of a design (a surface's body-frame normal, the rotation of the attitude) that a grid
        search and refinement would otherwise compute again for every shape. Keyed by ``what`` and the arrays'
        identity; the entry holds the arrays, so that their ids stay theirs (a copy with moved velocities,
        :func:`udrobot_ctrl.gap.identifiability._perturbed`, has arrays of its own)."""
        key = (what, *map(id, arrays))
        if key not in self.memo:  # the entry holds the arrays: an id in a key is never another array's
            self.memo[key] = (tuple(arrays), compute(*arrays))
        return self.memo[key][1]

    def full(self, func, held=False, filt=True):
        """Evaluate func(run) -> (n_full, ...) on each run at its full rate (raw logged state, held commands),
        filter it like the velocity derivative (``held``: a command held over each interval; ``filt=False``
        for terms already built from the filtered nu_dot) and sample it at the stacked rows (``run["smooth"](y,
        held)`` filters y and returns those rows)."""
        parts = []
        for r in self.runs:
            y = func(r)
            parts.append(r["smooth"](y, held=held) if filt else y[r["idx"]])
        return finite_values(np.concatenate(parts, axis=0), own=True)

    def delivered(self, filters) -> Stack:
        """This stack with each run's command sequence passed through ``filters`` (``(f (n, k), dt) -> f``, in
        order): the thrust the actuators deliver, which effects downstream of the filters read."""
        chain = _chained(filters)
        return replace(self, runs=[{**r, "f": chain(r["f"], r["dt"])} for r in self.runs])

    def only_actuators(self, keep) -> Stack:
        """This stack with the commands of every actuator not in ``keep`` (indices) set to zero: the part of a
        per-actuator effect (:attr:`Effect.per_actuator`) that the actuators ``keep`` make."""
        mask = np.isin(np.arange(self.f.shape[1]), np.asarray(keep, int)).astype(float)
        return replace(self, f=self.f * mask, runs=[{**r, "f": r["f"] * mask} for r in self.runs])

    def followed_by(self, filters) -> Stack:
        """This stack with ``filters`` (``(df (n, k), dt) -> df``, linear, in order) recorded as what a static map's
        thrust change goes through before it acts (``run["after"]``; :meth:`Effect.change_filter`)."""
        return replace(self, runs=[{**r, "after": _chained(filters)} for r in self.runs])


def finite_values(a, own=False) -> np.ndarray:
    """``numpy.nan_to_num(a)``: ``a`` itself when every entry is finite (no copy), else its non-finite entries
    replaced (in place when ``own``: the caller owns ``a`` and nothing else reads it)."""
    if np.isfinite(a).all():
        return a
    return np.nan_to_num(a, copy=not own)


def digest(a) -> tuple:
    """A content key of array ``a``: its dtype, shape and a 128-bit BLAKE2b hash of its bytes."""
    a = np.ascontiguousarray(a)
    return a.dtype.str, a.shape, hashlib.blake2b(a.tobytes(), digest_size=16).digest()


def content_key(s: Stack, reads) -> tuple | None:
    """What a design that reads the run arrays ``reads`` (:attr:`Effect.reads`) is computed from on stack ``s``, by
    value: per run its length, sampling step, derivative filter window, stacked rows and the read arrays' contents;
    the actuators (B, inflow, f_ref), the nominal added mass and whether the inputs are a commanded wrench; and the
    nominal plant by identity (a key names the ``s.p`` its holder keeps). Each array is hashed once per stack and its
    copies (:meth:`Stack.kept`). None when a run does not say its filter window (a stack not made by
    :func:`udrobot_ctrl.gap.attribute.build_stack`, whose filter may be anything)."""
    if any("window_s" not in r for r in s.runs):
        return None

    def hashed(a):
        return s.kept("digest", (a,), digest)
    runs = tuple((r["f"].shape[0], float(r["dt"]), float(r["window_s"]), hashed(r["idx"]),
                  *(hashed(r[k]) for k in reads)) for r in s.runs)
    return (id(s.p), bool(s.virtual), *(hashed(np.asarray(a, float)) for a in (s.B, s.inflow, s.f_ref, s.M_A)),
            tuple(reads), runs)


def _chained(filters):
    """One filter ``(y, dt) -> y`` applying ``filters`` in order."""
    def chain(y, dt):
        for flt in filters:
            y = flt(y, dt)
        return y
    return chain


def _after(r, df):
    """A static map's thrust change ``df`` (n, k) of run ``r`` as it reaches the vehicle (``Stack.followed_by``)."""
    return r["after"](df, r["dt"]) if "after" in r else df


def _to_body(R, vec):
    return np.einsum("...ji,...j->...i", R, vec)


class Design(NamedTuple):
    """An effect's prediction of the equation-error residual for one shape: ``b0 + A a`` with bounds on ``a``.

    Attributes
    ----------
    b0 : (n, 6) ndarray
        Shape-only part of the predicted generalised force, N and N m.
    A : (n, 6, k) ndarray
        Regressors of the k amplitude parameters (N or N m per unit of each parameter).
    names : tuple of str
        The amplitude parameters' names (with their unit).
    lower, upper : (k,) ndarray
        Bounds of the amplitude parameters.
    """

    b0: np.ndarray
    A: np.ndarray
    names: tuple
    lower: np.ndarray
    upper: np.ndarray


class Actuation(NamedTuple):
    """How a run's commands reach the vehicle: what an effect's replay hooks need besides its parameters.

    Attributes
    ----------
    B : (6, k) ndarray
        Actuator matrix: nominal wrench = B f (thrusters, or six virtual wrench actuators).
    inflow : (6, k) ndarray
        Axial inflow speed of actuator j is ``inflow[:, j] . nu``, m/s.
    f_ref : (k,) ndarray
        Reference magnitude of each actuator, N (or N m).
    M_A : (6, 6) ndarray
        Nominal added mass.
    """

    B: np.ndarray
    inflow: np.ndarray
    f_ref: np.ndarray
    M_A: np.ndarray


class PlantForces(NamedTuple):
    """The nominal plant's generalised forces at the states a hook is given, as its caller already computed them
    (the hook context's ``PLANT_FORCES`` entry, :class:`Hooks`): a parameter effect's hook then evaluates the plant
    once, not twice."""

    plant: PlantParameters  # the plant they were computed with (``generalized_forces(x, plant)``)
    forces: np.ndarray  # (N, 6) N and N m, one row per state


#: the key of a hook context's :class:`PlantForces` (optional)
PLANT_FORCES = "plant_forces"


@dataclass
class Hooks:
    """How an effect enters a simulation: input filter, extra force, added-mass increment (any may be None)."""

    input_filter: object = None  # (f (n,k), dt) -> f_act (n,k); applied to the whole command sequence
    force: object = None  # (x (N,12), f (N,k), ctx dict) -> (N,6)
    mass: object = None  # (x (N,12), ctx dict) -> (N,6,6)
    # ctx: the surfaces' (distance, normal, label) at these states ("surfaces") and, optionally, the nominal plant's
    # forces there (PLANT_FORCES); force and mass of one evaluation get the same ctx, in which a hook may keep terms
    # both need (the wall's, keyed by its own identity and checked on x)
    order: float = 0.0  # input filters run in increasing order (static maps in [0, 1) as the plant, lag 1)


@dataclass
class Effect:
    """One catalogue entry (see the module docstring)."""

    name: str
    meaning: str
    shape_names: tuple = ()
    shape_grid: tuple = ((),)
    shape_bounds: tuple = ()
    refine: bool = False
    mimics: tuple = field(default_factory=tuple)
    #: what the runs must contain for its regressors not to vanish (the identifiability report's fix)
    excited_by: str = "manoeuvres in which it acts"
    #: shape parameters whose range ends are physical forms (an exponent 1 or 2), not limits of the search: a fit
    #: there is not "at the edge of the catalogue's range"
    physical_ends: tuple = ()
    #: amplitude parameters whose range ends are physical forms (a dead band's ``shift``: 0 the hard band, 1 the
    #: thrust continuous from the band's edge), likewise not "at the edge of the catalogue's range" there
    physical_amplitudes: tuple = ()
    #: (shape parameter, physical value) pairs whose search bound is a tolerance about that value, not a limit of
    #: the physics (a tether's top end, refined down to ``TOP_END_DEPTH_MAX_M`` below the surface, is at the surface,
    #: 0): a fit on that bound is at the edge of its range only when it would go on beyond it, clearly better
    #: (:meth:`udrobot_ctrl.gap.attribute.Attributor.bound_binds`); else the runs cannot place it within the tolerance
    tolerance_ends: tuple = ()
    #: (shape parameters, their default values) groups the search keeps off their defaults only when the fit pays for
    #: them: with the group at its defaults instead (the amplitudes fitted again) the fit-run BIC would rise by more
    #: than ``BIC_STRONG`` counting the group's parameters (:meth:`udrobot_ctrl.gap.attribute.Attributor.
    #: nested_parts`). A tether's attachment point, refined from the CO, otherwise moves a centimetre on noise, and the
    #: moment it adds is replayed against a heading the autopilot holds
    nested: tuple = ()
    #: its regressors read the thrust the actuators deliver, i.e. after the input filters of the other effects in a
    #: set (the plant applies an inflow loss to the lagged thrust): see :meth:`command_filter`
    reads_delivered: ClassVar[bool] = False
    #: a static map of the command (deadband, asymmetry): the thrust it changes passes through the input filters
    #: that follow it in the plant (a lag), see :meth:`change_filter`
    maps_command: ClassVar[bool] = False
    #: its force is a sum over the actuators of a term that reads that actuator's own command only (a thruster map, a
    #: lag, an inflow loss), so each actuator's part is the design on a stack with the others' commands at zero
    #: (:meth:`Stack.only_actuators`)
    per_actuator: ClassVar[bool] = False
    #: the run arrays (keys of ``Stack.runs``: "f", "eta", "nu", "nu_dot") its design reads, besides the stack's
    #: rows, their derivative filter, the actuators and the nominal plant; None: not declared. A declared design is
    #: the same on stacks whose read arrays hold the same values (:func:`content_key`), so it is computed once per
    #: content (:class:`udrobot_ctrl.gap.attribute.DesignStore`: a thruster map's grid in both reconstruction passes,
    #: a restoring term's regressor under each move of the reconstructed velocities)
    reads: ClassVar[tuple | None] = None
    #: its amplitudes are corrections of the nominal plant each acting in its own DOF and 0 at nominal (a damping or
    #: an added-mass scale per DOF): one whose fit ends on its bound can be held at nominal while the others stand
    #: (:func:`udrobot_ctrl.gap.report.hold_at_nominal`)
    per_dof: ClassVar[bool] = False

    def change_filter(self, shape):
        """The linear filter ``(df (n, k), dt) -> df_delivered`` a thrust change made upstream of this effect's input
        filter goes through at a shape (a lag: its small-signal form), else None."""
        return None

    def command_filter(self, shape):
        """The input filter ``(f (n, k), dt) -> f_delivered`` this effect applies to the commands at a shape, when
        the shape alone sets it (no amplitude parameter: a lag), else None. Effects that read the delivered thrust
        (``reads_delivered``) are fitted on commands passed through the filters of the other members of a set."""
        return None

    def default_form(self, s: Stack):
        """The values of the held shape parameters (a zero ``refine_step``, in their order) that form the physical
        default, or None: no default, the best fit wins. With a default, each form's best grid shape within reach
        is refined (their refined fits may rank otherwise than their grid fits: the decay length that suits the
        seabed alone is not the one that suits the seabed and a wall), and the default is kept unless another form
        fits better by more than ``BIC_STRONG`` (:meth:`udrobot_ctrl.gap.attribute.Attributor._search_shape`)."""
        return None

    def search_space(self, s: Stack):
        """(grid, bounds) of the shape search on stack ``s``: the fixed ``shape_grid`` and ``shape_bounds`` unless
        an effect's shape lives where the data are (a tether anchor)."""
        return self.shape_grid, self.shape_bounds

    def refine_step(self, s: Stack, x0):
        """Initial simplex step of the local refinement from shape ``x0``: 30 % of each value (0.05 at zero)."""
        x0 = np.asarray(x0, float)
        return np.where(x0 != 0, 0.3 * np.abs(x0), 0.05)

    # -- to be provided per effect
    def design(self, s: Stack, shape) -> Design:
        """The effect's :class:`Design` (b0 (n,6), A (n,6,k), names (k,), lower (k,), upper (k,)) for a shape."""
        raise NotImplementedError

    def designs(self, s: Stack, shapes) -> list:
        """The :class:`Design` of each of ``shapes`` (a shape grid), in order: each on its own unless an effect
        computes several at once (a tether's anchors)."""
        return [Design(*self.design(s, tuple(sh))) for sh in shapes]

    def hooks(self, params: dict, p: PlantParameters, actuation: Actuation) -> Hooks:
        """How the fitted effect enters a replay: the plant's own definition of it (:func:`plant_hooks`)."""
        return plant_hooks(PlantEffect(self.name, params), p, actuation)


def _comps(a):
    return list(np.moveaxis(np.asarray(a, float), -1, 0))


def _stack(parts):
    """Components (arrays of one broadcast shape, or scalars) stacked along a new last axis (float)."""
    out = np.empty(np.broadcast_shapes(*(np.shape(c) for c in parts)) + (len(parts),))
    for i, c in enumerate(parts):
        out[..., i] = c
    return out


def thruster_capacities(p: PlantParameters, B):
    """Forward and reverse capacity of each actuator (``p.capacities``) when the actuators are the model's thrusters
    (B is its thruster matrix), else None: six virtual wrench actuators of a commanded wrench, symmetric."""
    B = np.asarray(B, float)
    T = np.asarray(p.T, float)
    return p.capacities if B.shape == T.shape and np.array_equal(B, T) else None


def plant_hooks(e: PlantEffect, p: PlantParameters, actuation: Actuation) -> Hooks:
    """Input filter, force and added-mass increment of ``e`` for a replay, from :mod:`udrobot_ctrl.dynamics.effects`
    (the physics the plant simulates; nothing is written twice).

    Parameters
    ----------
    e : PlantEffect
    p : PlantParameters
        Nominal plant.
    actuation : Actuation
        The run's actuators (B, inflow, f_ref) and the nominal added mass.
    """
    B, inflow, f_ref, M_A = actuation
    nominal = replace(p, M_A=np.asarray(M_A, float), effects=())
    if e.name == "thruster_lag":
        lag = pfx.thruster_lag((e,))
        return Hooks(input_filter=lambda f, dt: pfx.first_order_lag(f, dt, lag.T_s,
                                                                   thrust_exponent=lag.thrust_exponent), order=1)
    if e.name in ("thruster_deadband", "thruster_asymmetry"):  # in the plant's order (pfx.STATIC_MAP_ORDER)
        caps = thruster_capacities(p, B)
        return Hooks(input_filter=lambda f, dt: _stack(pfx.static_thrust(pfx.NUMPY, _comps(f), (e,), f_ref, caps)),
                     order=pfx.STATIC_MAP_ORDER[e.name] / len(pfx.STATIC_MAP_ORDER))
    if e.name == "thrust_inflow_loss":
        def inflow_force(x, f, ctx):
            fa = _stack(pfx.inflow_loss(pfx.NUMPY, _comps(f), _comps(x)[6:], (e,), inflow, f_ref))
            return (fa - f) @ np.asarray(B).T
        return Hooks(force=inflow_force)
    if e.name == "tether_drag":
        def tether_force(x, f, ctx):
            X = _comps(x)
            return _stack(pfx.external_force(pfx.NUMPY, X[:6], X[6:], (e,)))
        return Hooks(force=tether_force)
    if e.name == "water_current":
        with_current = replace(nominal, effects=(e,))
        return Hooks(force=lambda x, f, ctx: _stack(effect_forces(_comps(x), with_current)))
    if e.name == "wall_effect":  # the planes are the run's measured surfaces (ctx), not one seabed depth
        key = ("wall_effect", id(e))
        mask = e.params.get("planes_mask")  # a fitted effect's plane subset; a model file's acts on its own planes

        def planes(ctx):
            return on_planes(ctx["surfaces"], mask)

        def action(x, ctx, acting):  # the acting surfaces' suction (summed) and rank-one added mass, once per state
            kept = ctx.get(key)  # (kept in ctx)
            if kept is None or not (kept[0] is x or np.array_equal(kept[0], x)):
                X = _comps(x)
                dist = np.stack([np.where(np.isfinite(d), d, np.inf) for d, _, _ in acting])  # (planes, ...):
                normals = np.asarray([n for _, n, _ in acting], float)  # unmeasured = no surface nearby
                column = (len(normals),) + (1,) * (dist.ndim - 1)
                normal = tuple(normals[:, c].reshape(column) for c in range(3))
                force, a, nb = pfx.surface_action(pfx.NUMPY, X[:6], X[6:], dist, normal, e.params)
                kept = ctx[key] = (x, _stack(force).sum(axis=0), a, _stack(nb))
            return kept[1:]

        def wall_force(x, f, ctx):
            acting = planes(ctx)
            if not acting:
                return np.zeros(np.shape(x)[:-1] + (6,))
            return action(x, ctx, acting)[0]

        def wall_mass(x, ctx):  # sum over the surfaces of a n n^T on the translations
            out = np.zeros(np.shape(x)[:-1] + (6, 6))
            acting = planes(ctx)
            if acting:
                _, a, nb = action(x, ctx, acting)
                out[..., :3, :3] = ((a[..., None] * nb)[..., :, None] * nb[..., None, :]).sum(axis=0)
            return out
        return Hooks(force=wall_force, mass=wall_mass)
    folded = pfx.fold_parameters(nominal, (e,))  # an effect on the nominal matrices
    dM = folded.M - nominal.M

    def folded_force(x, f, ctx):  # the nominal plant's forces are p's (effects=(); M_A does not enter them)
        known = ctx.get(PLANT_FORCES)
        base = known.forces if known is not None and known.plant is p and not p.effects else generalized_forces(
            x, nominal)
        return base - generalized_forces(x, folded)
    return Hooks(force=folded_force,
                 mass=(lambda x, ctx: np.broadcast_to(dM, np.shape(x)[:-1] + (6, 6))) if np.any(dM) else None)


# ------------------------------------------------------------------------------------------- thrusters
class InflowLoss(Effect):
    per_actuator = True
    reads_delivered = True  # the plant's inflow loss acts on the clipped, mapped and lagged thrust

    reads = ("f", "nu")

    def design(self, s, shape):
        def cols(r):
            ua = r["nu"] @ s.inflow  # (n, k) axial advance speed
            af = np.abs(r["f"])
            return np.stack([(-(af * ua)) @ s.B.T, (-(np.sqrt(af * s.f_ref) * ua)) @ s.B.T], -1)
        A = s.full(cols)
        return Design(np.zeros((s.n, 6)), A, ("k1_per_mps", "k2_per_mps"), np.zeros(2), np.array([2.0, 2.0]))



WRENCH_DOF_NOTE = ("a commanded wrench (tau_* inputs) hides the thrusters behind each generalised force, so the "
                   "static thruster maps get one parameter per DOF instead of one shared by identical thrusters")


def _per_dof(s) -> bool:
    """True for virtual wrench actuators (tau_* inputs): thruster maps are parameterised per DOF."""
    return bool(getattr(s, "virtual", False))


PINNED_FRACTION = 0.05


def crossing(s) -> np.ndarray:
    """(k,) float: 1 for actuators whose command takes both signs in at least ``PINNED_FRACTION`` of the samples.

    A static thruster map (the shift of a deadband, a reverse-thrust loss) is a function of the command; on an
    actuator whose command keeps one sign (a thruster holding depth, a trim moment pinned at its limit) it adds
    a constant force, exactly what a buoyancy or CG-CB offset adds, and the data cannot tell them apart. Those
    actuators are left out of the static maps (their parameter has no effect), so that a steady trim command
    is attributed to the restoring terms, which act whatever the command.
    """
    f = np.asarray(s.f, float)
    pos, neg = np.mean(f > 1e-9, axis=0), np.mean(f < -1e-9, axis=0)
    return (np.minimum(pos, neg) >= PINNED_FRACTION).astype(float)


class Deadband(Effect):
    """A deadband in the command (ESC, PWM) domain: the plant's :func:`~udrobot_ctrl.dynamics.effects.deadband_terms`.

    Shape: ``width_fraction`` w of the normalised command u = (|f| / f_ref)^(1/p) and ``command_exponent`` p in
    [1, 2] (the thrust curve's power of the command beyond the deadband; f_ref the thruster's capacity, or for a
    commanded wrench the 99th percentile of the command). Commands u < w give no thrust (``b0``); beyond, the
    amplitude ``shift`` c in [0, 1] blends the hard deadband (c = 0, the nominal curve) and the continuous one
    (c = 1, starting from zero at w: f - w f_ref sign(f) for p = 1, today's form; for p = 2 the PWM-domain
    deadband with thrust ~ offset^2 rescaled to full thrust at full command, reverse commands normalised by the
    reverse capacity).

    The width is bounded by 0.35 of the command range: the T200's ESC deadband is +-25 us of +-400 us PWM (6 %),
    and its bollard thrust beyond it grows as the offset^1.1-1.55 (Blue Robotics' 2019 data, 10-20 V); at p = 2 a
    0.35 deadband is 12 % of the thrust range, at p = 1 35 %, beyond which a "deadband" would be a thrust gain
    error or a constant offset in disguise. For a commanded wrench the shift is per DOF (see ``WRENCH_DOF_NOTE``).
    """

    per_actuator = True
    maps_command = True

    reads = ("f",)

    def design(self, s, shape):
        w, p = shape
        caps = None if _per_dof(s) else thruster_capacities(s.p, s.B)
        x = crossing(s)

        def terms(r):  # b0 and the shift's regressor of one run, in one evaluation of the plant's deadband
            d, unit = pfx.deadband_terms(pfx.NUMPY, r["f"], s.f_ref, w, p, caps)
            inside = np.abs(r["f"]) < d
            b0 = _after(r, np.where(inside, -r["f"], 0.0)) @ s.B.T
            shift = _after(r, np.where(inside, 0.0, -unit) * x)
            col = shift[:, :, None] * np.eye(6)[None] if _per_dof(s) else (shift @ s.B.T)[..., None]
            return np.concatenate([b0[..., None], col], axis=-1)
        both = s.full(terms, held=True)
        b0, col = both[..., 0], both[..., 1:]
        if _per_dof(s):
            return Design(b0, col, tuple(f"shift_{k}" for k in DOF), np.zeros(6), np.ones(6))
        return Design(b0, col, ("shift",), np.zeros(1), np.ones(1))



class Asymmetry(Effect):
    """Reverse thrust ``(1 - reverse_loss) f`` for f < 0, reverse_loss in [-0.5, 0.7] (a reversed propeller
    gives 30 % to 150 % of its forward thrust; the T200's is about 80 %). Per DOF for a commanded wrench."""

    per_actuator = True
    maps_command = True

    reads = ("f",)

    def design(self, s, shape):
        x = crossing(s)
        if _per_dof(s):
            col = s.full(lambda r: _after(r, -np.minimum(r["f"], 0.0) * x)[:, :, None] * np.eye(6)[None], held=True)
            return Design(np.zeros((s.n, 6)), col, tuple(f"reverse_loss_{k}" for k in DOF), np.full(6, -0.5),
                          np.full(6, 0.7))
        col = s.full(lambda r: _after(r, -np.minimum(r["f"], 0.0) * x) @ s.B.T, held=True)
        return Design(np.zeros((s.n, 6)), col[..., None], ("reverse_loss",), np.array([-0.5]), np.array([0.7]))



class Lag(Effect):
    """First-order lag of every actuator: the plant's :func:`~udrobot_ctrl.dynamics.effects.first_order_lag` of
    time constant ``T_lag_s`` on the state s = sign(f) |f|^(1/k), thrust sign(s) |s|^k, k = ``thrust_exponent``
    in [1, 2]: k = 1 lags the thrust, k = 2 the rotor speed (a propeller's thrust ~ n|n|, and the motor's
    first-order dynamics act on n: Yoerger, Cooke & Slotine 1990; Healey et al. 1995). The larger k, the slower
    the thrust's rise from rest for the same T (63 % at 1.59 T for k = 2) and the faster its fall. Shape only
    (both parameters), no amplitude.
    """

    per_actuator = True

    reads = ("f",)

    def command_filter(self, shape):
        T, k = shape
        return lambda f, dt: pfx.first_order_lag(f, dt, T, thrust_exponent=k)

    def change_filter(self, shape):
        """A small thrust change df passes the lag of time constant T whatever k (the state's change ds = df /
        (k |s|^(k-1)) is lagged and mapped back by the same slowly varying factor), from rest."""
        T, _ = shape
        return lambda df, dt: pfx.first_order_lag(df, dt, T, f0=np.zeros(df.shape[1:]))

    def design(self, s, shape):
        lag = self.command_filter(shape)
        b0 = s.full(lambda r: (lag(r["f"], r["dt"]) - r["f"]) @ s.B.T, held=True)
        return Design(b0, np.zeros((s.n, 6, 0)), (), np.zeros(0), np.zeros(0))



# ------------------------------------------------------------------------------------------- environment
#: samples x anchors of a block of :func:`_tether_columns` (its terms are evaluated sample by sample, so a block's
#: numbers are the whole run's): 512 samples x 40 anchors a block ran 1.6-2.2 times faster than 20 000 samples at
#: once (measured on the 2-core machine, each of the four cable forms; the blocks' temporaries stay in the cache)
TETHER_BLOCK = 20_000


def _tether_columns(run, geometry, count) -> np.ndarray:
    """Body-frame generalised force per unit (k_q, k_l) of the tether drag of ``count`` anchors on a run's samples,
    (n, 6, 2 count) (anchor j's two columns at k count + j): the plant's own derivatives,
    :func:`udrobot_ctrl.dynamics.effects.tether_unit_forces`, with the anchor coordinates of ``geometry`` as (count,)
    arrays and its cable form (walk azimuth, walk fraction, cable_taut) as scalars, so that the vehicle's rotation
    and velocity are computed once for all of them (the run's samples as (n, 1) columns, ``TETHER_BLOCK // count`` at a
    time: each component comes out as (block, count), in the layout of the columns written)."""
    n = run["eta"].shape[0]
    out = np.empty((n, 6, 2, count))
    step = max(1, TETHER_BLOCK // max(count, 1))  # samples per block: each term's temporaries stay in the cache
    for a in range(0, n, step):
        # samples down, anchors across
        eta, nu = ([c[:, None] for c in _comps(run[k][a:a + step])] for k in ("eta", "nu"))
        units = pfx.tether_unit_forces(pfx.NUMPY, eta, nu, geometry)
        for k, force in enumerate(units):  # components (block, count), (block, 1) or scalars
            for c, comp in enumerate(force):
                out[a:a + step, c, k, :] = comp
    return out.reshape(n, 6, 2 * count)


#: an anchor this far (m) from the runs is a fixed cable direction (the old template): over runs spanning 10 m
#: its direction turns by 0.01 rad
FAR_ANCHOR_M = 1000.0
#: near anchors searched on a lattice at the surface over the runs' area plus this margin (m), spaced at least
#: ANCHOR_SPACING_M (m) and at most ANCHOR_LATTICE_MAX intervals along the longer side (the search cost)
ANCHOR_MARGIN_M = 3.0
ANCHOR_SPACING_M = 2.0
ANCHOR_LATTICE_MAX = 7
#: walking top ends searched: line azimuths (rad; d and -d are the same line), distances behind (+: ahead) the
#: vehicle along the line (m), and at most this many parallel lines across the runs' area
WALK_AZIMUTHS = tuple(np.radians((0.0, 45.0, 90.0, 135.0)))
WALK_BACK_M = (-4.0, -1.5, 1.5, 4.0)
WALK_LINES = 5
#: the deepest a tether's top end may lie (m below the surface, NED down): a tether is paid out from the surface (a
#: tender's hands, a boat's rail, a pier, a pool deck). Assumed: those sit within half a metre of the water, and an
#: ArduSub depth zeroed at arming carries a few tenths of a metre of datum error. The refinement stops here; a fit
#: that ends on it wants a top end under water, which no tether has (:meth:`Attributor.at_bounds
#: <udrobot_ctrl.gap.attribute.Attributor.at_bounds>` then sets it aside)
TOP_END_DEPTH_MAX_M = 1.0
#: the refinement's first step (m) on each coordinate of a tether's attachment point: a tenth of a small ROV's
#: 0.5 m length (assumed: the hull points a cable is tied to lie 0.1-0.3 m from the CO)
ATTACH_STEP_M = 0.05


def hull_size(s: Stack) -> float:
    """The vehicle's size (m) bounding a point of its hull from the CO on each body axis: the model's
    ``size_m`` (:func:`udrobot_ctrl.dynamics.effects.vehicle_size`), or ``ASSUMED_VEHICLE_SIZE_M`` without it."""
    return float(getattr(s.p, "size_m", None) or pfx.ASSUMED_VEHICLE_SIZE_M)


class TetherDrag(Effect):
    """Cross-flow drag of a tether to an anchor fixed in the pool frame (a deck, a boat, a handler standing
    still): the water resists the velocity component *normal* to the cable, F_ned = -(k_q |V_n| + k_l) V_n, with
    V_n = V - (V.e) e and e the unit vector from the vehicle towards the anchor. The anchor's NED position is the
    shape (``anchor_north_m anchor_east_m anchor_down_m``, in the frame of the logged or dead-reckoned x y and the
    depth z); the direction turns as the vehicle goes around the pool, so surge in one place becomes sway or heave
    drag in another -- the signature that separates it from per-axis damping errors and from an inflow loss.

    The shape is searched where the data are (:meth:`search_space`): anchors at the surface on a lattice over the
    runs' area and its margin, on a ring beyond it, and anchors ``FAR_ANCHOR_M`` away (straight up, or at 15/45
    deg elevation towards eight headings), which are fixed cable directions (a surface float trailing the vehicle,
    a cable straight up); the best is refined locally (Nelder-Mead, steps of 30 % of the anchor's distance). The
    lumped amplitudes do not grow with the distance to the anchor: the paid-out length, not the straight-line
    distance, sets the drag of a cable that is not taut.

    The top end may also walk with the vehicle (``walk_azimuth_rad walk_fraction``,
    :func:`udrobot_ctrl.dynamics.effects.tether_top_end`: a handler following it along the pool edge, a tender
    boat): the cable then keeps its direction along the walk and moves with the vehicle, so motion along the walk
    drags little. These are searched as lines at four azimuths (0, 45, 90, 135 deg), top ends 1.5 or 4 m behind
    or ahead of the vehicle along them, on lines across the runs' area; a fixed anchor has ``walk_fraction`` 0.

    The cable may be slack or taut (``cable_taut``, :func:`udrobot_ctrl.dynamics.effects.cable_length_factor`): a
    slack cable's paid-out length is fixed and its amplitudes are lumped; a taut one is as long as the straight line
    to its top end and drags in proportion. Each near anchor and walking line is searched in both forms (far
    anchors only slack: their distance does not change); the form is held at its grid value in the refinement.

    The cable is tied to the hull at r_a = (``attach_x_m attach_y_m attach_z_m``, body frame, m from the CO; the
    plant's :func:`udrobot_ctrl.dynamics.effects.tether_unit_forces`): the drag acts with that point's position and
    velocity and adds the moment r_a x F (a cable tied at the top rear of a hull pitches the vehicle when it drags).
    The grid searches it at the CO; the refinement moves it with the anchor (steps of ``ATTACH_STEP_M``), each
    coordinate within the vehicle's size (:func:`hull_size`): a point of the hull.
    """

    reads = ("eta", "nu")

    def search_space(self, s):
        xy = s.eta[:, :2]
        lo, hi = np.percentile(xy, 1, axis=0) - ANCHOR_MARGIN_M, np.percentile(xy, 99, axis=0) + ANCHOR_MARGIN_M
        spacing = max(ANCHOR_SPACING_M, float(np.max(hi - lo)) / ANCHOR_LATTICE_MAX)
        axes = [np.linspace(a, b, int(np.ceil((b - a) / spacing)) + 1) for a, b in zip(lo, hi)]
        z_top = 0.0  # anchors at the water surface (z = 0 in NED): a deck, a boat, a handler
        grid = [(n, e, z_top) for n in axes[0] for e in axes[1]]
        c = np.median(xy, axis=0)
        heads = np.radians(np.arange(0, 360, 45))
        rho = 3.0 * float(np.max(hi - lo))  # a deck beyond the area covered
        grid += [(c[0] + rho * np.cos(h), c[1] + rho * np.sin(h), z_top) for h in heads]
        zc = float(np.median(s.eta[:, 2]))
        first_far = len(grid)
        grid.append((c[0], c[1], zc - FAR_ANCHOR_M))
        for el in np.radians((15.0, 45.0)):
            grid += [(c[0] + FAR_ANCHOR_M * np.cos(el) * np.cos(h), c[1] + FAR_ANCHOR_M * np.cos(el) * np.sin(h),
                      zc - FAR_ANCHOR_M * np.sin(el)) for h in heads]
        far = range(first_far, len(grid))  # fixed directions: their distance does not change over the runs
        grid = [g + (0.0, 0.0) for g in grid]  # fixed anchors: walk_azimuth_rad (unused), walk_fraction 0
        for chi in WALK_AZIMUTHS:  # top ends walking along a line at azimuth chi, WALK_BACK_M behind or ahead
            d, n_h = np.array([np.cos(chi), np.sin(chi)]), np.array([-np.sin(chi), np.cos(chi)])
            across = xy @ n_h
            c_lo, c_hi = np.percentile(across, 1) - ANCHOR_MARGIN_M, np.percentile(across, 99) + ANCHOR_MARGIN_M
            lines = np.linspace(c_lo, c_hi, max(2, min(WALK_LINES, int(np.ceil((c_hi - c_lo) / spacing)) + 1)))
            grid += [tuple(back * d + line * n_h) + (z_top, float(chi), 1.0)
                     for back in WALK_BACK_M for line in lines]
        slack = [g + (0.0,) for g in grid]  # cable_taut 0: a fixed paid-out length
        taut = [g + (1.0,) for i, g in enumerate(grid) if i not in far]  # cable_taut 1: as long as the line
        span = 2.0 * FAR_ANCHOR_M
        size = hull_size(s)
        bounds = ((c[0] - span, c[0] + span), (c[1] - span, c[1] + span), (zc - span, TOP_END_DEPTH_MAX_M),
                  (-0.5 * np.pi, np.pi), (0.0, 1.0), (0.0, 1.0)) + ((-size, size),) * len(pfx.TETHER_ATTACH)
        at_co = (0.0,) * len(pfx.TETHER_ATTACH)  # the grid ties the cable at the CO; the refinement moves it
        return tuple(tuple(float(v) for v in g + at_co) for g in slack + taut), bounds

    def refine_step(self, s, x0):
        """30 % of the anchor's distance from the runs' centre on each coordinate (at least 0.5 m), for a walking
        top end 0.3 rad on the walk's azimuth, and ``ATTACH_STEP_M`` on each coordinate of the attachment; the walk
        fraction is held at its grid value (0: a fixed anchor, 1: a top end that walks with the vehicle -- the two
        physical forms; in between, a single-effect fit would use it to soak up what another effect does), and so
        is ``cable_taut`` (slack or taut)."""
        x0 = np.asarray(x0, float)
        centre = np.r_[np.median(s.eta[:, :2], axis=0), np.median(s.eta[:, 2])]
        step = max(0.5, 0.3 * float(np.linalg.norm(x0[:3] - centre)))
        return np.r_[np.full(3, step), 0.3 if x0[4] > 0 else 0.0, 0.0, 0.0,
                     np.full(len(pfx.TETHER_ATTACH), ATTACH_STEP_M)]

    def design(self, s, shape):
        return self.designs(s, [shape])[0]

    def designs(self, s, shapes):
        """The designs of many anchors at once (:func:`_tether_columns`, one call per cable form and attachment
        point); the same numbers as one anchor at a time."""
        shapes = [tuple(float(v) for v in sh) for sh in shapes]
        forms = {}
        for i, sh in enumerate(shapes):
            forms.setdefault(sh[3:], []).append(i)
        out, b0 = [None] * len(shapes), np.zeros((s.n, 6))  # one b0 for all (a tether has no fixed term)
        for form, idx in forms.items():
            anchors = np.array([shapes[i][:3] for i in idx])  # (S, 3)
            geometry = dict(zip(self.shape_names, [anchors[:, j] for j in range(3)] + list(form)))
            A = s.full(partial(_tether_columns, geometry=geometry, count=len(idx))).reshape((s.n, 6, 2, len(idx)))
            for j, i in enumerate(idx):
                out[i] = Design(b0, np.ascontiguousarray(A[..., j]),
                                ("k_quadratic_N_s2_per_m2", "k_linear_N_s_per_m"), np.zeros(2), np.array([1e4, 1e4]))
        return out



def _surface_geometry(eta, nu, nu_dot, dist, normal):
    """What a surface's terms share whatever the decay length: body normal (n, 3), tangential speed^2 (n,), distance
    h (n,; inf where unmeasured) and the acceleration along the normal (n,)."""
    nb = _to_body(_rotation(eta), np.broadcast_to(normal, eta.shape[:-1] + (3,)))
    vn = np.sum(nu[..., :3] * nb, -1)
    vt2 = np.maximum(np.sum(nu[..., :3] ** 2, -1) - vn ** 2, 0.0)
    h = np.where(np.isfinite(dist), np.maximum(dist, 0.0), np.inf)
    return nb, vt2, h, np.sum(nu_dot[:, :3] * nb, -1)


#: a wall effect's plane subsets searched: every non-empty subset of the planes the runs know the distance to up to
#: this many planes; beyond, each plane alone and all together
WALL_SUBSETS_MAX_PLANES = 3


def plane_bit(label: str) -> int:
    """Bit of a surface (its :class:`~udrobot_ctrl.gap.data.Prepared` label) in a wall effect's ``planes_mask``:
    0 the seabed (from the altitude or the sidecar's ``seabed_depth``), ``i + 1`` the sidecar's wall ``i``; -1 for a
    plane a model file names (its wall effect acts on all of them)."""
    if label.startswith("seabed"):
        return 0
    head, _, index = label.partition(" ")
    return int(index) + 1 if head == "wall" and index.isdigit() else -1


def mask_bits(mask) -> frozenset:
    """The plane bits (:func:`plane_bit`) set in a wall effect's ``planes_mask`` (a float in the fitted parameters)."""
    m = int(round(mask))
    return frozenset(b for b in range(m.bit_length()) if m >> b & 1)


def acts_on(mask, bit: int) -> bool:
    """Whether a wall effect of ``planes_mask`` ``mask`` acts on the plane of :func:`plane_bit` ``bit``: its bit is
    set, or ``mask`` is None (a model file's wall effect, whose planes are its own: it acts on all of them)."""
    return mask is None or bit in mask_bits(mask)


def on_planes(surfaces, mask) -> list:
    """The surfaces ``(distance, normal, label)`` a wall effect of ``planes_mask`` ``mask`` acts on (:func:`acts_on`
    their :func:`plane_bit`)."""
    return [sf for sf in surfaces if acts_on(mask, plane_bit(sf[2]))]


def plane_masks(bits) -> tuple:
    """The ``planes_mask`` values searched for the plane bits ``bits``: every non-empty subset when there are at most
    ``WALL_SUBSETS_MAX_PLANES`` planes, else each plane alone and all of them; (0,) without a plane."""
    bits = sorted(set(bits))
    if not bits:
        return (0,)
    if len(bits) <= WALL_SUBSETS_MAX_PLANES:
        subsets = itertools.chain.from_iterable(itertools.combinations(bits, k) for k in range(1, len(bits) + 1))
    else:
        subsets = [(b,) for b in bits] + [tuple(bits)]
    return tuple(sum(1 << b for b in sub) for sub in subsets)


class WallEffect(Effect):
    """Added mass and suction near the planes the runs know the distance to. Which planes act is a shape parameter,
    ``planes_mask`` (bit 0 the seabed, bit ``i + 1`` the sidecar's wall ``i``, :func:`plane_bit`), searched over the
    subsets of the planes (:func:`plane_masks`) and held in the refinement: the seabed and a wall share the decay
    length and the coefficients when both act, but a plane that does not act (a vertical wall beside a hull that
    hovers near the seabed) must not take the same coefficients, which would put a wall's suction on every metre of
    surge."""

    @staticmethod
    def _bits(s):
        """The plane bits of the surfaces stack ``s`` knows the distance to somewhere, once each (a seabed from the
        altitude in some runs and from the sidecar's depth in others is one plane)."""
        return sorted({b for b in (plane_bit(lab) for lab, (dist, _) in s.surfaces.items() if np.isfinite(dist).any())
                       if b >= 0})

    def search_space(self, s):
        masks = plane_masks(self._bits(s))
        grid = tuple((lam, float(m)) for m in masks for (lam,) in self.shape_grid)
        return grid, self.shape_bounds + ((float(min(masks)), float(max(masks))),)  # one plane: no choice to count

    def default_form(self, s):
        """Every plane acts (a surface near a hull changes its flow whatever its orientation): a subset is named
        only when it fits better by more than ``BIC_STRONG``."""
        return (float(sum(1 << b for b in self._bits(s))),)

    def refine_step(self, s, x0):
        """30 % of the decay length (0.05 m at zero); the plane subset is held at its grid value."""
        return np.array([0.3 * abs(x0[0]) if x0[0] != 0 else 0.05, 0.0])

    def design(self, s, shape):
        lam, mask = shape

        def col(r, which):
            out = np.zeros(r["nu"].shape[:1] + (6,))
            for dist, normal, _ in on_planes(r["surfaces"], mask):
                nb, vt2, h, an = s.kept("surface", (r["eta"], r["nu"], r["nu_dot"], dist, normal), _surface_geometry)
                e = np.exp(-h / lam)
                if which == 0:
                    out[:, :3] += -(e * an)[:, None] * nb
                else:
                    out[:, :3] += -(e * vt2)[:, None] * nb
            return out
        A = np.stack([s.full(lambda r: col(r, 0), filt=False), s.full(lambda r: col(r, 1))], -1)
        return Design(np.zeros((s.n, 6)), A, ("added_mass_at_contact_kg", "suction_N_s2_per_m2"), np.zeros(2),
                      np.array([1e4, 1e5]))



def _damping_force(nu, p):
    return nu @ p.D_L.T + (np.abs(nu) * nu) @ p.Q.T


def _rotation(eta):
    """(n, 3, 3) body-to-NED rotations of the attitudes of ``eta`` (n, 6)."""
    return rotation_zyx(eta[..., 3], eta[..., 4], eta[..., 5])


def _current_force(eta, nu, c, p, M_A, R=None):
    """(n, 6) generalised force of a steady NED current ``c`` (3,): the nominal damping and added-mass Coriolis terms
    on the water-relative velocity minus those on ``nu`` (``R``: the rotations of ``eta``, when known)."""
    R = _rotation(eta) if R is None else R
    nu_r = nu.copy()
    nu_r[..., :3] = nu[..., :3] - _to_body(R, np.broadcast_to(c, nu.shape[:-1] + (3,)))
    return (_damping_force(nu, p) - _damping_force(nu_r, p)
            + coriolis_centripetal(M_A, nu) - coriolis_centripetal(M_A, nu_r))


class Current(Effect):
    reads = ("eta", "nu")

    def design(self, s, shape):
        c = np.array(shape, float)
        b0 = s.full(lambda r: _current_force(r["eta"], r["nu"], c, s.p, s.M_A, s.kept("rotation", (r["eta"],),
                                                                                      _rotation)))
        return Design(b0, np.zeros((s.n, 6, 0)), (), np.zeros(0), np.zeros(0))



# ------------------------------------------------------------------------------------------- hydrodynamics
class LinearDamping(Effect):
    reads = ("nu",)
    per_dof = True

    def design(self, s, shape):
        A = s.full(lambda r: -r["nu"][:, :, None] * np.eye(6)[None])
        lo = -np.diag(s.p.D_L).copy()
        return Design(np.zeros((s.n, 6)), A, tuple(f"d_{d}{v}" for d, v in zip(DOF, VEL)), lo, np.full(6, 1e4))



#: a unit speed-norm drag: norm weight 1, every scale and nominal coefficient 1 (:func:`quadratic_drag`)
_UNIT_NORM_DRAG = {"norm_weight": 1.0, **{f"scale_{d}{v}|{v}|": 1.0 for d, v in zip(DOF, VEL)},
                   **dict.fromkeys(pfx.NOMINAL_Q, 1.0)}


def quadratic_drag(nu, norm_weight) -> np.ndarray:
    """(n, 6) quadratic drag per unit coefficient, ((1 - a) |nu_i| + a |nu_g|) nu_i, |nu_g| the norm of the
    translational or rotational velocity (a = ``norm_weight``): the speed-norm part is the plant's own
    :func:`udrobot_ctrl.dynamics.effects.speed_norm_drag`."""
    nu = np.asarray(nu, float)
    on_norm = -_stack(pfx.speed_norm_drag(pfx.NUMPY, _comps(nu), _UNIT_NORM_DRAG))
    return (1.0 - norm_weight) * np.abs(nu) * nu + norm_weight * on_norm


class QuadDampingError(Effect):
    """Q_ii scaled by 1 + s_i; the shape ``norm_weight`` a moves the error's drag from each axis' own speed (0) to
    the translational or rotational speed (1)."""

    reads = ("nu",)
    per_dof = True

    def design(self, s, shape):
        q = np.diag(s.p.Q)
        a = float(shape[0]) if len(shape) else 0.0
        A = s.full(lambda r: -(q * quadratic_drag(r["nu"], a))[:, :, None] * np.eye(6)[None])
        return Design(np.zeros((s.n, 6)), A, tuple(f"scale_{d}{v}|{v}|" for d, v in zip(DOF, VEL)),
                      np.full(6, -0.95), np.full(6, 10.0))



class AddedMassError(Effect):
    reads = ("nu", "nu_dot")
    per_dof = True

    def design(self, s, shape):
        ma = np.diag(s.M_A)
        A = -s.full(lambda r: r["nu_dot"][:, :, None] * np.diag(ma)[None], filt=False)

        def cor(r):
            out = np.zeros(r["nu"].shape[:1] + (6, 6))
            for i in range(6):
                Mi = np.zeros((6, 6))
                Mi[i, i] = ma[i]
                out[:, :, i] = coriolis_centripetal(Mi, r["nu"])
            return out
        A = A - s.full(cor)
        return Design(np.zeros((s.n, 6)), A, tuple(f"scale_{d}d{v}" for d, v in zip(DOF, VEL)), np.full(6, -0.9),
                      np.full(6, 10.0))



CROSS_PAIRS = tuple((i, j) for i in range(6) for j in range(6) if i != j)


class CrossDamping(Effect):
    reads = ("nu",)

    def design(self, s, shape):
        names = []
        for i, j in CROSS_PAIRS:
            names += [f"D_{DOF[i]}{VEL[j]}", f"Q_{DOF[i]}{VEL[j]}|{VEL[j]}|"]

        vel = [j for _, j in CROSS_PAIRS]

        def cols(r):  # pair k's two regressors (columns 2k, 2k + 1), each acting on one DOF, DOF i of the pair
            nu_j = r["nu"][:, vel]
            out = np.empty(nu_j.shape[:1] + (2 * len(CROSS_PAIRS),))
            out[:, 0::2] = -nu_j
            out[:, 1::2] = -np.abs(nu_j) * nu_j
            return out
        # filtered as they are (the filter acts column by column), then placed in their DOF's row: not a (n, 6, k)
        # block whose other five rows are zero at the full rate
        pairs = s.full(cols)
        k = pairs.shape[-1]
        A = np.zeros((s.n, 6, k))
        for c, (i, _) in enumerate(CROSS_PAIRS):
            A[:, i, 2 * c: 2 * c + 2] = pairs[:, 2 * c: 2 * c + 2]
        return Design(np.zeros((s.n, 6)), A, tuple(names), np.full(k, -1e4), np.full(k, 1e4))



class BuoyancyOffset(Effect):
    reads = ("eta",)

    def design(self, s, shape):
        A = -s.full(lambda r: restoring_gradient(r["eta"], s.p, "B"))[..., None]
        return Design(np.zeros((s.n, 6)), A, ("dB_N",), np.array([-0.5 * s.p.weight]), np.array([0.5 * s.p.weight]))



class CgCbOffset(Effect):
    """Restoring moments (x_g W - x_b B, ...) changed by dBG (N m), each within +-0.1 W (a CG shift of 10 cm);
    the righting moment z_g W - z_b B keeps at least 10 % of its modelled value (the vehicle floats upright)."""

    reads = ("eta",)

    def design(self, s, shape):
        A = -s.full(lambda r: np.stack([restoring_gradient(r["eta"], s.p, k) for k in ("BG_x", "BG_y", "BG_z")], -1))
        lo, hi = np.full(3, -0.1 * s.p.weight), np.full(3, 0.1 * s.p.weight)
        bgz = float(s.p.r_g[2] * s.p.weight - s.p.r_b[2] * s.p.buoyancy)
        if bgz > 0:  # a vehicle that floats upright keeps a righting moment: at least 10 % of the modelled one
            lo[2] = -0.9 * bgz
        return Design(np.zeros((s.n, 6)), A, ("dBG_x_Nm", "dBG_y_Nm", "dBG_z_Nm"), lo, hi)



def _skew(a) -> np.ndarray:
    """(n, 3, 3) matrices S(a) with S(a) b = a x b, for vectors a (n, 3)."""
    S = np.zeros(a.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = a[..., 2], -a[..., 1], a[..., 0]
    return S


class DragCentre(Effect):
    """The nominal translational drag acting at a centre of pressure r_cp = (``x_cp_m y_cp_m z_cp_m``) off the CO:
    the plant's :func:`~udrobot_ctrl.dynamics.effects.drag_centre_force`, [F(v + omega x r) - F(v); r x F(v + omega x
    r)] with F(v) = -(D v + Q |v| v) the u v w block of the nominal damping. Its template is the expansion to first
    order in r, linear in r (amplitudes, bounded least squares, no shape search):

        [J(v) S(omega) r ; -S(F(v)) r],    J = dF/dv = -(D + 2 Q diag|v|),  S(a) b = a x b.

    The second-order term it leaves out, r x (J (omega x r)), is |r| |omega| |J| |r| against |r| |F|: 2 % of the
    moment for r = 3 cm on a BlueROV2 turning at 0.1 rad/s at 0.2 m/s. Bounds: each coordinate within the vehicle's
    size (:func:`udrobot_ctrl.dynamics.effects.vehicle_size`, the largest distance of a thruster from the CO; 0.5 m
    assumed for a model without thrusters): the centre of pressure is a point of the hull.
    """

    reads = ("nu",)

    def design(self, s, shape):
        D, Q = np.asarray(s.p.D_L, float)[:3, :3], np.asarray(s.p.Q, float)[:3, :3]
        size = hull_size(s)

        def cols(r):
            v, w = r["nu"][:, :3], r["nu"][:, 3:6]
            F = -(v @ D.T + (np.abs(v) * v) @ Q.T)
            J = -(D[None] + 2.0 * Q[None] * np.abs(v)[:, None, :])
            return np.concatenate([J @ _skew(w), -_skew(F)], axis=1)  # (n, 6, 3)
        A = s.full(cols)
        return Design(np.zeros((s.n, 6)), A, pfx.DRAG_CENTRE, np.full(3, -size), np.full(3, size))



THRUSTERS_MOVING = "thruster commands that vary (armed thrusters driven through a range of commands)"


def catalogue() -> dict:
    """Name -> :class:`Effect`, in the spec's order."""
    lag_grid = tuple((T, k) for T in (0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, 1.0) for k in (1.0, 1.5, 2.0))
    db_grid = tuple((w, p) for w in (0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.25, 0.3) for p in (1.0, 1.5, 2.0))
    wall_grid = tuple((lam,) for lam in (0.03, 0.06, 0.1, 0.15, 0.22, 0.33, 0.5, 0.8))
    cur = tuple((cn, ce, 0.0) for cn in (-0.1, 0.0, 0.1) for ce in (-0.1, 0.0, 0.1))
    effects = [
        InflowLoss("thrust_inflow_loss", "thrust falls with the axial inflow speed through the thruster",
                   mimics=("quadratic_damping_error", "linear_damping", "tether_drag"),
                   excited_by="thrust while the vehicle moves along a thruster's axis"),
        Deadband("thruster_deadband", "small commands produce no thrust", ("width_fraction", "command_exponent"),
                 db_grid, ((0.005, 0.35), pfx.EXPONENT_RANGE), refine=True, excited_by=THRUSTERS_MOVING,
                 physical_ends=("command_exponent",),
                 physical_amplitudes=("shift", *(f"shift_{k}" for k in DOF))),
        Asymmetry("thruster_asymmetry", "reverse thrust weaker than modelled, relative to forward",
                  excited_by="thruster commands of both signs (reverse thrust on an armed thruster)"),
        Lag("thruster_lag", "thrust follows the command with a first-order lag", ("T_lag_s", "thrust_exponent"),
            lag_grid, ((0.005, 1.0), pfx.EXPONENT_RANGE), refine=True, mimics=("added_mass_error",),
            excited_by=THRUSTERS_MOVING, physical_ends=("thrust_exponent",)),
        TetherDrag("tether_drag", "umbilical cross-flow drag, normal to the cable",
                   pfx.TETHER_ANCHOR + pfx.TETHER_WALK + (pfx.TETHER_TAUT,) + pfx.TETHER_ATTACH, (), (),
                   refine=True, mimics=("quadratic_damping_error", "linear_damping", "thrust_inflow_loss"),
                   tolerance_ends=(("anchor_down_m", 0.0),),
                   nested=((pfx.TETHER_ATTACH, (0.0,) * len(pfx.TETHER_ATTACH)),)),
        WallEffect("wall_effect", "extra added mass and suction near the seabed or a wall",
                   ("decay_length_m", "planes_mask"),
                   wall_grid, ((0.01, 2.0),), refine=True,
                   excited_by="a known distance to a surface: log altitude, or give seabed_depth, or walls with "
                              "logged x, y, in the sidecar"),
        Current("water_current", "steady current; damping on the velocity relative to the water",
                ("current_north_mps", "current_east_mps", "current_down_mps"), cur,
                ((-1.0, 1.0), (-1.0, 1.0), (-0.3, 0.3)), refine=True, mimics=("buoyancy_offset",)),
        LinearDamping("linear_damping", "linear damping missing or wrong",
                      mimics=("quadratic_damping_error", "tether_drag")),
        QuadDampingError("quadratic_damping_error", "quadratic damping wrong in scale", ("norm_weight",),
                         ((0.0,), (1.0,)), ((0.0, 1.0),), refine=True,
                         mimics=("thrust_inflow_loss", "tether_drag", "linear_damping"),
                         physical_ends=("norm_weight",)),
        AddedMassError("added_mass_error", "added mass wrong in scale", mimics=("thruster_lag",)),
        CrossDamping("cross_coupled_damping", "off-diagonal damping couples DOFs"),
        BuoyancyOffset("buoyancy_offset", "net buoyancy differs from the model"),
        CgCbOffset("cg_cb_offset", "restoring moment (CG-CB separation) differs from the model"),
        DragCentre("drag_centre_offset", "the translational drag acts at a centre of pressure off the CO",
                   mimics=("cross_coupled_damping", "cg_cb_offset"),
                   excited_by="translational motion through the water (surge, sway or heave at speed): its moment is "
                              "the drag times the lever arm"),
    ]
    return {e.name: e for e in effects}


# which manoeuvre separates two look-alike effects
DISCRIMINATING_MANOEUVRE = {
    frozenset({"quadratic_damping_error", "thrust_inflow_loss"}):
        "coast-downs: cut the thrust at speed (inflow loss vanishes with zero thrust, damping does not), or hold "
        "one speed with two different thrusts",
    frozenset({"quadratic_damping_error", "tether_drag"}):
        "repeat the speed runs with a different paid-out tether length, and add sway/heave/yaw motion "
        "(tether drag acts on the velocity normal to the cable towards its anchor in the pool, whatever the "
        "heading; a damping error acts per body axis), and go around the anchor (the cable's direction turns)",
    frozenset({"linear_damping", "tether_drag"}):
        "repeat the speed runs with a different paid-out tether length",
    frozenset({"thrust_inflow_loss", "tether_drag"}):
        "coast-downs at speed (tether drag remains with zero thrust, inflow loss does not)",
    frozenset({"linear_damping", "quadratic_damping_error"}):
        "steady runs at three or more well separated speeds (linear vs quadratic growth)",
    frozenset({"linear_damping", "thrust_inflow_loss"}):
        "coast-downs at speed, and steady runs at several speeds",
    frozenset({"added_mass_error", "thruster_lag"}):
        "open-loop thrust steps and reversals, or sine sweeps at two or more frequencies (a lag delays the "
        "response onset and adds phase; an added-mass error scales the acceleration without delay)",
    frozenset({"water_current", "buoyancy_offset"}):
        "hold station and reverse the heading (a current turns with the vehicle's heading, buoyancy does not)",
    frozenset({"buoyancy_offset", "thruster_deadband"}):
        "vertical steps of equal size up and down from the hover command, and a hover with a known added weight "
        "(a buoyancy offset shifts the hover command and acts at zero command; a deadband shift flips with the "
        "command's sign and vanishes at zero)",
    frozenset({"cg_cb_offset", "thruster_asymmetry"}):
        "pitch/roll steps of both signs from the trim command (a restoring offset acts whatever the command; a "
        "reverse-thrust loss only on one sign)",
    frozenset({"thruster_deadband", "thruster_asymmetry"}):
        "slow ramps of the command through zero in both directions",
    frozenset({"wall_effect", "added_mass_error"}):
        "heave steps at two or more heights above the seabed, with the altitude logged (a wall's added mass decays "
        "with the distance; an added-mass error is the same everywhere; within a decay length of the seabed the two "
        "are one heave added mass)",
    frozenset({"added_mass_error", "cg_cb_offset"}):
        "forced pitch and roll steps held at an angle, besides free oscillations (the restoring moment acts on the "
        "held angle, an added-mass error only while the rate changes; in a lightly damped free oscillation the "
        "angular acceleration follows -sin(angle) and the two cannot be told apart)",
    frozenset({"cross_coupled_damping", "quadratic_damping_error"}):
        "combined surge and heave runs at several ratios of the two speeds, besides single-axis runs (a drag on the "
        "vehicle's speed grows with the total speed, a cross-coupled term with the product of the two)",
    frozenset({"drag_centre_offset", "cg_cb_offset"}):
        "hold station, then runs at two or more speeds at the same attitude (a centre of pressure's moment grows with "
        "the drag, a restoring offset acts at rest and follows the attitude)",
    frozenset({"drag_centre_offset", "cross_coupled_damping"}):
        "speed runs along two axes, surge and heave (one lever arm ties every moment to every drag: surge drag at a "
        "height pitches, heave drag ahead pitches the other way; a cross-coupled term has one free coefficient each)",
    frozenset({"thruster_lag", "thruster_deadband"}):
        "small command steps around zero and large steps (a deadband removes the small ones, a lag delays all)",
}


def discriminating_manoeuvre(a: str, b: str) -> str:
    """Manoeuvre that tells effects a and b apart."""
    return DISCRIMINATING_MANOEUVRE.get(frozenset({a, b}),
                                        f"a manoeuvre in which the regressors of {a} and {b} differ (excite the "
                                        f"channels where one acts and the other does not)")
