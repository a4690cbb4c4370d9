"""Second, independent truth generator for the gap diagnoser: literature forms that depart from both the diagnoser's
templates (``udrobot_ctrl/gap/effects.py``, ``udrobot_ctrl/dynamics/effects.py``) and the first truth generator
(``truth.py``).

It is a *scoring* generator only (``bench/blind_score.py --generator independent``): no threshold of the diagnoser
may be fitted to it. It shares nothing with ``truth.py`` but the vehicle model and the plant's textbook terms
(rigid-body and added-mass Coriolis from an inertia matrix, restoring forces, kinematics; Fossen 2021). Each effect
is written in its own physical form:

* ``thrust_inflow_loss``: a propeller open-water curve ``K_T(J) = K_T0 (1 - sign(J) |J / J0|^1.3)`` (clipped to
  ``[0, 1.4 K_T0]``) of the advance ratio ``J = u_a / (n D)``, where ``u_a = (1 - w_t) d_i . (v + omega x r_i)`` is
  the axial inflow at each thruster *including the rotation of the hull* (a vertical thruster 0.15 m off the centre
  line sees ``0.15 p`` in roll), wake fraction ``w_t`` (Carlton, *Marine Propellers and Propulsion*, ch. 6;
  Healey et al. 1995, IEEE JOE 20(4));
* ``thruster_deadband``: an ESC dead band with a *soft* edge (motor start-up/cogging torque): the normalised command
  ``s`` becomes ``sign(s) w softplus((|s| - delta) / w) / (1 - delta)``, thrust quadratic in the rotor command;
* ``thruster_asymmetry``: per-thruster reverse efficiency (a cambered propeller run backwards; each blade set
  differs by up to +-10 % around the drawn ratio), reverse thrust ``ratio_i`` times the forward curve;
* ``thruster_lag``: Yoerger et al.'s (1990, IEEE JOE 15(3)) one-state rotor model, ``2 T_m g_dot = g_c |g_c| -
  g |g| + eps (g_c - g)`` (``eps`` 1) for the normalised rotor speed ``g`` (thrust ``F g |g|``): its small-signal
  time constant ``2 T_m / (2 |g| + eps)`` grows at low thrust, unlike a first-order lag of the thrust or of
  the rotor speed;
* ``tether_drag``: a cable from a fixed deck anchor to an attachment point on the hull (top rear,
  ``TETHER_ATTACH``), paid out 15 % longer than the straight line, Morison normal drag *and* tangential skin friction
  on 20 segments, each moving with its share of the attachment point's velocity ``v + omega x r_att``; the force
  acts at the attachment point, so it also gives the moment ``r_att x F`` (Driscoll et al. 2000, Ocean Eng.
  27(9));
* ``wall_effect``: seabed laws in the gap ratio ``G = h / H`` (``h`` the body origin's height above the seabed,
  ``H`` the hull height): a heave added mass ``Z_wdot (1 + c_m / G^2)`` (potential flow of a cylinder near a plane,
  Yamamoto et al. 1974, J. Hydronautics), a suction (lift towards the bed) ``0.5 rho A c_l exp(-G) U_t^2`` (Zdravkovich
  1985), and a squeeze-film heave damping ``D_Z (1 + c_s / G)`` (Brenner 1961);
* ``water_current``: a logarithmic boundary layer over the pool floor, ``V(h) = V0 ln(h / z0) / ln(H_w / z0)``
  (roughness ``z0`` 5 mm), damping and added-mass Coriolis on the velocity relative to the water;
* ``linear_damping``: a full symmetric positive-definite linear damping matrix (diagonal plus Z-M and Y-N
  couplings, Lamb's laminar damping with a centre of pressure off the origin);
* ``quadratic_damping_error``: Allen et al.'s / Fossen's strip-theory cross-flow drag on the hull's local velocity
  ``w - x q``, ``v + x r`` integrated along its length (so heave and pitch, sway and yaw drags couple), plus an
  axial drag error on surge;
* ``added_mass_error``: a strip-theory added mass with a bow-stern asymmetry: diagonal scales *and* the coupling
  ``Z_qdot = M_wdot = x_c Z_wdot``, with its Coriolis part;
* ``cross_coupled_damping``: hull lift at incidence (Prestero 2001, REMUS: ``Z_uw u w``, ``M_uw u w``, ``Y_uv u v``,
  ``N_uv u v``), bilinear in the two speeds (the template has ``u|u|`` and linear terms);
* ``buoyancy_offset``: positive, an air pocket compressed with depth by Boyle's law, ``dB = rho g V0 p_a / (p_a +
  rho g z)``; negative, an added weight (constant);
* ``cg_cb_offset``: a ballast mass ``m_b`` moved by ``(dx, 0, dz)`` inside the hull: the CG moves by
  ``m_b d / m`` *and* the rigid-body inertia about the origin changes by the parallel-axis terms of the moved mass
  (M_RB and its Coriolis rebuilt);
* outside the catalogue, ``periodic_disturbance``: a linear (Airy) deep-water wave's orbital flow, Froude-Krylov and
  added-mass force on its acceleration and drag on the relative velocity (Morison), decaying with ``exp(-k z)``.
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.dynamics.plant import (
    coriolis_centripetal,
    kinematics,
    plant_parameters,
    restoring_forces,
    rotation_zyx,
    skew,
)
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model

RHO = 1000.0  # kg/m^3
GRAVITY = 9.81  # m/s^2
P_ATM = 101325.0  # Pa
SEABED = 3.0  # pool depth, m
WALL_Y = 0.0  # pool wall plane y = 0 (sidecar only: no effect of this generator acts on it)
HULL_HEIGHT = 0.25  # m, H of the seabed gap ratio
HULL_LENGTH = 0.5  # m, strip theory
HULL_BREADTH = 0.3  # m
PLAN_AREA = HULL_LENGTH * HULL_BREADTH  # m^2, seabed suction
PROP_D = 0.076  # m, T200 propeller diameter
KT0 = 0.32
WAKE = 0.1  # wake fraction at the thrusters
TETHER_ATTACH = np.array([-0.15, 0.0, -0.06])  # m, body frame: top rear of the hull
BALLAST_AT = np.array([0.0, 0.0, 0.08])  # m, where the moved ballast sits nominally (low in the hull)
#: stock accelerometer (an MPU-6000 class MEMS, as truth.py assumes): white noise per sample and a residual bias
ACCEL_NOISE = 0.03
ACCEL_BIAS = 0.03
NOISE = {"x": 0.03, "y": 0.03, "z": 0.005, "phi": 0.003, "theta": 0.003, "psi": 0.005, "u": 0.008, "v": 0.008,
         "w": 0.008, "p": 0.005, "q": 0.005, "r": 0.005}
Z_RATE = 0.2  # m/s, the pilot's depth reference moves at most this fast (no overshoot onto the seabed)
STATES = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")


def random_magnitudes(name, rng):
    """Randomised truth parameters of an effect (ranges documented in the module docstring's sources; large enough
    to matter in a pool run, as physical as the literature makes them)."""
    u = rng.uniform
    sign = rng.choice([-1.0, 1.0])
    return {
        "thrust_inflow_loss": {"J0": u(0.4, 0.6)},
        "thruster_deadband": {"delta": u(0.15, 0.28), "soft": u(0.02, 0.05)},
        "thruster_asymmetry": {"ratio": u(0.45, 0.65)},
        "thruster_lag": {"T_m": u(0.15, 0.3)},
        "tether_drag": {"d": u(0.012, 0.02), "cd": u(1.0, 1.2), "ct": u(0.01, 0.02),
                        "anchor": (-u(2.5, 3.5), WALL_Y, -0.3)},
        "wall_effect": {"c_m": u(0.4, 0.7), "c_l": u(0.4, 0.7), "c_s": u(0.5, 1.0)},
        "water_current": {"V0": u(0.08, 0.14), "dir": u(0, 2 * np.pi)},
        "linear_damping": {"dX": u(8, 14), "dY": u(6, 10), "dZ": u(8, 14), "dK": u(0.05, 0.1), "dM": u(0.05, 0.1),
                           "dN": u(0.15, 0.3), "c": u(0.2, 0.4)},
        # a negative error keeps the total drag positive: the strip drag is ~75 N s^2/m^2 in heave (nominal 56) and
        # ~0.29 N m s^2 in pitch (nominal 0.115)
        "quadratic_damping_error": {"s_cf": u(0.5, 0.9) if sign > 0 else -u(0.2, 0.35), "s_x": u(0.3, 0.6) * sign},
        "added_mass_error": {"sX": u(0.6, 1.0), "sZ": u(0.6, 1.0), "sN": u(0.6, 1.0), "x_c": u(0.02, 0.04)},
        "cross_coupled_damping": {"Z_uw": u(25, 40), "M_uw": u(2, 4), "Y_uv": u(20, 30), "N_uv": u(3, 6)},
        "buoyancy_offset": {"dB0": u(1.0, 2.5) * sign},
        "cg_cb_offset": {"m_b": u(1.0, 1.5), "dz": u(0.05, 0.09) * sign, "dx": u(-0.03, 0.03)},
        "periodic_disturbance": {"a": u(0.15, 0.3), "period": u(3.0, 6.0)},
    }[name]


def _allocation(T):
    rows = [0, 2, 3, 5]  # X Z K N are actuated on UDrobot
    return np.linalg.pinv(T[rows])


def ballast_move(p, mass, m_b, d):
    """CG and inertia about the origin after a ballast mass ``m_b`` (kg) moves by ``d`` (m, body) from
    :data:`BALLAST_AT`: returns ``(r_g_new, M_RB_old, M_RB_new)`` (m; 6x6 about the origin, kg, kg m, kg m^2).

    The inertia about the origin changes by the parallel-axis terms of the moved point mass,
    ``m_b (|r|^2 I - r r^T)`` at its new place minus at its old one; the total mass is unchanged.
    """
    M_RB = np.asarray(p.M, float) - np.asarray(p.M_A, float)
    r0 = BALLAST_AT
    r1 = BALLAST_AT + np.asarray(d, float)
    par = lambda r: m_b * (r @ r * np.eye(3) - np.outer(r, r))  # noqa: E731
    r_g = np.asarray(p.r_g, float) + m_b * np.asarray(d, float) / mass
    M_new = M_RB.copy()
    M_new[:3, 3:] = -mass * skew(r_g)
    M_new[3:, :3] = mass * skew(r_g)
    M_new[3:, 3:] = M_RB[3:, 3:] + par(r1) - par(r0)
    return r_g, M_RB, M_new


class IndependentTruth:
    """Truth plant: the nominal vehicle plus withheld effects (name -> params), forms of the module docstring."""

    def __init__(self, model="pendulum:chin", effects=None):
        self.v = load_model(model)
        self.p = plant_parameters(self.v)
        p = self.p
        self.eff = dict(effects or {})
        self.T = p.T
        self.fmax, self.frev = np.asarray(p.f_max, float), -np.asarray(p.f_min, float)
        self.pos = np.array([t.position for t in self.v.thrusters], float)
        self.dirs = np.array([t.direction for t in self.v.thrusters], float)
        self.dirs /= np.linalg.norm(self.dirs, axis=1, keepdims=True)
        self.mass = float(self.v.mass)
        M_A = np.asarray(p.M_A, float).copy()
        if "added_mass_error" in self.eff:
            e = self.eff["added_mass_error"]
            for i, k in ((0, "sX"), (2, "sZ"), (5, "sN")):
                M_A[i, i] *= 1 + e[k]
            M_A[2, 4] = M_A[4, 2] = e["x_c"] * M_A[2, 2]  # Z_qdot = M_wdot = x_c Z_wdot (bow-stern asymmetry)
        self.M_A_true = M_A
        self.M_RB_nom = np.asarray(p.M, float) - np.asarray(p.M_A, float)
        self.M_RB_true = self.M_RB_nom.copy()
        self.r_g_true = np.asarray(p.r_g, float).copy()
        if "cg_cb_offset" in self.eff:
            c = self.eff["cg_cb_offset"]
            self.r_g_true, _, self.M_RB_true = ballast_move(p, self.mass, c["m_b"], (c["dx"], 0.0, c["dz"]))
        self.M_true = self.M_RB_true + self.M_A_true
        self.D_L_true = np.asarray(p.D_L, float).copy()
        if "linear_damping" in self.eff:
            c = self.eff["linear_damping"]
            d = np.array([c["dX"], c["dY"], c["dZ"], c["dK"], c["dM"], c["dN"]])
            D = np.diag(d)
            for i, j in ((2, 4), (1, 5)):  # centre of pressure off the origin: Z-M and Y-N couplings
                D[i, j] = D[j, i] = c["c"] * np.sqrt(d[i] * d[j]) * (1 if i == 2 else -1)
            self.D_L_true = self.D_L_true + D

    # ------------------------------------------------------------------ thrusters
    def thrust(self, fc, g, x, dt):
        """Delivered thrust (R, n) from commanded ``fc`` (N); ``g`` is the normalised rotor speed state."""
        F = np.where(fc >= 0, self.fmax, self.frev)
        s = np.sign(fc) * np.sqrt(np.abs(fc) / F)  # normalised rotor command in [-1, 1]
        if "thruster_deadband" in self.eff:
            d, w = self.eff["thruster_deadband"]["delta"], self.eff["thruster_deadband"]["soft"]
            s = np.sign(s) * w * np.logaddexp(0.0, (np.abs(s) - d) / w) / (1 - d)
            s = np.clip(s, -1.0, 1.0)
        if "thruster_lag" in self.eff:  # Yoerger's one-state rotor model, integrated in 4 sub-steps
            Tm, eps = self.eff["thruster_lag"]["T_m"], 1.0
            h = dt / 4
            for _ in range(4):
                g = g + h * (s * np.abs(s) - g * np.abs(g) + eps * (s - g)) / (2 * Tm)
            s_eff = g
        else:
            s_eff = s
        Fd = np.where(s_eff >= 0, self.fmax, self.frev)
        f = Fd * s_eff * np.abs(s_eff)
        if "thruster_asymmetry" in self.eff:
            ratio = self.eff["thruster_asymmetry"]["ratio"] * (1 + 0.1 * np.array([-1.0, 1.0, -0.5, 0.5]))
            f = np.where(f < 0, ratio * f, f)
        if "thrust_inflow_loss" in self.eff:
            J0 = self.eff["thrust_inflow_loss"]["J0"]
            nu = x[:, 6:]
            v_at = nu[:, None, :3] + np.cross(nu[:, None, 3:], self.pos[None])  # (R, n, 3) v + omega x r_i
            ua = (1 - WAKE) * np.sum(v_at * self.dirs[None], -1)
            n = np.sqrt(np.abs(f) / (RHO * PROP_D ** 4 * KT0)) + 1e-6  # rev/s at the bollard point
            J = np.sign(f) * ua / (n * PROP_D)
            KT = np.clip(KT0 * (1 - np.sign(J) * np.abs(J / J0) ** 1.3), 0.0, 1.4 * KT0)
            f = np.sign(f) * RHO * n ** 2 * PROP_D ** 4 * KT
        return f, g

    # ------------------------------------------------------------------ environment & hydrodynamics
    def extra(self, x, t):
        """Extra generalised force (R, 6), N and N m, and mass increment (R, 6, 6) of the withheld effects."""
        R_ = x.shape[0]
        F = np.zeros((R_, 6))
        dM = np.zeros((R_, 6, 6))
        nu = x[:, 6:]
        Rm = rotation_zyx(x[:, 3], x[:, 4], x[:, 5])
        e, p = self.eff, self.p
        if "tether_drag" in e:
            c = e["tether_drag"]
            r_att = TETHER_ATTACH
            att = x[:, :3] + np.einsum("nij,j->ni", Rm, r_att)
            v_att = np.einsum("nij,nj->ni", Rm, nu[:, :3] + np.cross(nu[:, 3:], r_att))
            vec = att - np.asarray(c["anchor"], float)
            L = np.linalg.norm(vec, axis=1, keepdims=True)
            eh = vec / L
            s = ((np.arange(20) + 0.5) / 20)[None, :, None]
            ve = s * v_att[:, None]  # the anchor is fixed
            vt = np.sum(ve * eh[:, None], -1, keepdims=True)
            vn = ve - vt * eh[:, None]
            seg = 1.15 * L[:, None] / 20  # paid out 15 % longer than the straight line
            dF = -0.5 * RHO * c["d"] * seg * (c["cd"] * np.linalg.norm(vn, axis=-1, keepdims=True) * vn
                                             + np.pi * c["ct"] * np.abs(vt) * vt * eh[:, None])
            tot = np.einsum("nji,nj->ni", Rm, np.sum(s * dF, axis=1))  # vehicle's share, body frame
            F[:, :3] += tot
            F[:, 3:] += np.cross(r_att, tot)
        if "wall_effect" in e:
            c = e["wall_effect"]
            G = np.maximum(SEABED - x[:, 2], 0.3 * HULL_HEIGHT) / HULL_HEIGHT
            nb = Rm[:, 2, :]  # NED down in body axes (the seabed's normal into the water is -down)
            dM[:, :3, :3] += (c["c_m"] * p.M_A[2, 2] / G ** 2)[:, None, None] * nb[:, :, None] * nb[:, None, :]
            wn = np.sum(nu[:, :3] * nb, 1)  # speed towards the bed
            ut2 = np.maximum(np.sum(nu[:, :3] ** 2, 1) - wn ** 2, 0.0)
            suction = 0.5 * RHO * PLAN_AREA * c["c_l"] * np.exp(-G) * ut2
            squeeze = c["c_s"] * p.D_L[2, 2] / G * wn
            F[:, :3] += (suction - squeeze)[:, None] * nb
        if "water_current" in e:
            c = e["water_current"]
            h = np.clip(SEABED - x[:, 2], 0.05, SEABED)
            prof = np.log(h / 0.005) / np.log(SEABED / 0.005)
            vc = c["V0"] * prof[:, None] * np.array([np.cos(c["dir"]), np.sin(c["dir"]), 0.0])
            nu_r = nu.copy()
            nu_r[:, :3] -= np.einsum("nji,nj->ni", Rm, vc)
            damp = lambda v: v @ p.D_L.T + (np.abs(v) * v) @ p.Q.T  # noqa: E731
            F += damp(nu) - damp(nu_r) + coriolis_centripetal(p.M_A, nu) - coriolis_centripetal(p.M_A, nu_r)
        if "linear_damping" in e:
            F += -(nu @ (self.D_L_true - p.D_L).T)
        if "quadratic_damping_error" in e:
            c = e["quadratic_damping_error"]
            xs = (np.arange(10) + 0.5) / 10 * HULL_LENGTH - HULL_LENGTH / 2  # strip centres, m
            dx = HULL_LENGTH / 10
            k = 0.5 * RHO * 1.0 * dx  # C_d 1 per strip, times its width below
            wl = nu[:, 2:3] - xs[None] * nu[:, 4:5]  # local heave speed of each strip
            vl = nu[:, 1:2] + xs[None] * nu[:, 5:6]  # local sway speed
            fz = -k * HULL_BREADTH * np.abs(wl) * wl
            fy = -k * HULL_HEIGHT * np.abs(vl) * vl
            F[:, 2] += c["s_cf"] * fz.sum(1)
            F[:, 4] += c["s_cf"] * (-(xs[None] * fz)).sum(1)
            F[:, 1] += c["s_cf"] * fy.sum(1)
            F[:, 5] += c["s_cf"] * (xs[None] * fy).sum(1)
            F[:, 0] += -c["s_x"] * p.Q[0, 0] * np.abs(nu[:, 0]) * nu[:, 0]
        if "added_mass_error" in e:
            F += coriolis_centripetal(p.M_A, nu) - coriolis_centripetal(self.M_A_true, nu)
        if "cross_coupled_damping" in e:
            c = e["cross_coupled_damping"]
            u, v, w = nu[:, 0], nu[:, 1], nu[:, 2]
            F[:, 2] += -c["Z_uw"] * u * w
            F[:, 4] += -c["M_uw"] * u * w  # the stabilising (fin) sign: nose-up incidence, nose-down moment
            F[:, 1] += -c["Y_uv"] * u * v
            F[:, 5] += c["N_uv"] * u * v  # stabilising in yaw
        if "buoyancy_offset" in e:
            dB0 = e["buoyancy_offset"]["dB0"]
            if dB0 > 0:  # an air pocket at the CB, compressed with depth (Boyle)
                dB = dB0 * P_ATM / (P_ATM + RHO * GRAVITY * np.maximum(x[:, 2], 0.0))
            else:  # an added weight
                dB = np.full(R_, dB0)
            F += -dB[:, None] * restoring_forces(x[:, :6], 0.0, 1.0, p.r_g, p.r_b)
        if "cg_cb_offset" in e:
            F += restoring_forces(x[:, :6], p.weight, p.buoyancy, p.r_g, p.r_b) - \
                restoring_forces(x[:, :6], p.weight, p.buoyancy, self.r_g_true, p.r_b)
            F += coriolis_centripetal(self.M_RB_nom, nu) - coriolis_centripetal(self.M_RB_true, nu)
        if "periodic_disturbance" in e:
            c = e["periodic_disturbance"]
            om = 2 * np.pi / c["period"]
            kw = om ** 2 / GRAVITY
            decay = c["a"] * om * np.exp(-kw * np.maximum(x[:, 2], 0.0))
            ph = kw * x[:, 0] - om * t
            v_w = np.stack([decay * np.cos(ph), np.zeros(R_), -decay * np.sin(ph)], 1)  # orbital flow, NED
            a_w = np.stack([decay * om * np.sin(ph), np.zeros(R_), decay * om * np.cos(ph)], 1)
            vb = np.einsum("nji,nj->ni", Rm, v_w)
            ab = np.einsum("nji,nj->ni", Rm, a_w)
            disp = p.buoyancy / GRAVITY  # displaced mass, kg (Froude-Krylov)
            F[:, :3] += (disp + np.diag(p.M_A)[:3]) * ab
            ur = nu[:, :3] - vb
            F[:, :3] += -(np.abs(ur) * ur - np.abs(nu[:, :3]) * nu[:, :3]) * np.diag(p.Q)[:3]
        return F, dM

    def nominal_forces(self, x):
        """C(nu) nu + D(nu) nu + g(eta) of the nominal plant (N, N m) with the nominal inertia."""
        p, nu = self.p, x[:, 6:]
        return (coriolis_centripetal(p.M, nu) + nu @ p.D_L.T + (np.abs(nu) * nu) @ p.Q.T
                + restoring_forces(x[:, :6], p.weight, p.buoyancy, p.r_g, p.r_b))

    def deriv(self, x, f, t):
        """State derivative (R, 12) with delivered thrusts ``f`` (R, n) at time ``t``."""
        tau = f @ self.T.T
        F, dM = self.extra(x, t)
        M = self.M_true + dM
        nd = np.linalg.solve(M, (tau + F - self.nominal_forces(x))[..., None])[..., 0]
        return np.concatenate([kinematics(x[:, :6], x[:, 6:]), nd], 1)


def schedule(t, prm):
    """References (u_ref, psi_ref, z_ref, surge_on) of a 60 s pool run: two surge legs with a coast between, a
    reverse leg, a heading step, a dive to near the seabed with surge, then sines on speed, depth and heading."""
    a1, a2, a3, dpsi, z0, zdeep = prm
    u_ref = np.zeros_like(a1)
    on = np.ones_like(a1, bool)
    psi = np.zeros_like(a1)
    z = z0.copy()
    if 3 <= t < 13:
        u_ref = a1
    elif 13 <= t < 17:
        on[:] = False
    elif 17 <= t < 27:
        u_ref = a2
        if 20 <= t < 25:
            psi = psi + 0.5
    elif 27 <= t < 31:
        u_ref = -0.2 * np.ones_like(a1)
    elif 31 <= t < 36:
        psi = dpsi
    elif 36 <= t < 46:
        u_ref, z = a3, zdeep
    elif t >= 46:
        u_ref = a3 + 0.15 * np.sin(2 * np.pi * t / 7.0)
        z = z0 + 0.3 * np.sin(2 * np.pi * t / 11.0)
        psi = 0.3 * np.sin(2 * np.pi * t / 13.0)
    return u_ref, psi, z, on


def specific_force(x, nu_dot, g=GRAVITY):
    """Accelerometer reading at the body origin (m/s^2, body FRD): ``v_dot + omega x v - R^T [0, 0, g]``."""
    phi, th = x[..., 3], x[..., 4]
    g_body = g * np.stack([-np.sin(th), np.cos(th) * np.sin(phi), np.cos(th) * np.cos(phi)], -1)
    return nu_dot[..., :3] + np.cross(x[..., 9:12], x[..., 6:9]) - g_body


def generate(effects=None, n_runs=3, duration=60.0, rate=20.0, seed=0, model="pendulum:chin", noise_scale=1.0,
             sensors="full", altitude=None, wall_distance=None, **_ignored):
    """Simulate ``n_runs`` closed-loop pool runs of :class:`IndependentTruth` with the withheld ``effects``.

    Parameters
    ----------
    effects : dict, optional
        Effect name -> params (:func:`random_magnitudes`).
    n_runs, duration, rate, seed : int, float (s), float (Hz), int
    sensors : {"full", "stock"}
        ``"full"``: pose, body velocities and altitude; ``"stock"``: depth, attitude, gyro rates and the accelerometer
        (specific force, white noise :data:`ACCEL_NOISE`, a bias per axis and run within +-:data:`ACCEL_BIAS`).
    altitude : bool, optional
        Log the altitude above the seabed (1 cm noise; default: with full sensors only).
    wall_distance : float or array, optional
        Start distance from the (inert) wall plane, m; default 0.5-2 m.

    Returns
    -------
    list of udrobot_ctrl.io.runlog.Run
        ``thrust_i`` inputs at the logged rate (the controller runs at it), noisy sensors, sidecar metadata with the
        seabed depth; stock runs carry the truth state as ignored ``true_*`` columns.
    """
    if sensors not in ("full", "stock"):
        raise ValueError(f"sensors must be 'full' or 'stock', got {sensors!r}")
    altitude = sensors == "full" if altitude is None else bool(altitude)
    rng = np.random.default_rng(seed)
    tr = IndependentTruth(model, effects)
    R_ = n_runs
    dt = 0.01
    n = int(round(duration / dt))
    log_every = max(1, int(round(1 / (rate * dt))))
    a1, a2, a3 = rng.uniform(0.25, 0.4, R_), rng.uniform(0.45, 0.65, R_), rng.uniform(0.25, 0.4, R_)
    dpsi = rng.uniform(0.8, 1.4, R_) * rng.choice([-1, 1], R_)
    z0 = rng.uniform(0.8, 1.4, R_)
    zdeep = SEABED - rng.uniform(0.28, 0.4, R_)
    wd = rng.uniform(0.5, 2.0, R_) if wall_distance is None else np.asarray(wall_distance, float) * np.ones(R_)
    prm = (a1, a2, a3, dpsi, z0, zdeep)
    x = np.zeros((R_, 12))
    x[:, 2] = z0
    x[:, 1] = WALL_Y - wd
    g = np.zeros((R_, tr.T.shape[1]))
    A = _allocation(tr.T)
    p = tr.p
    iz, iu = np.zeros(R_), np.zeros(R_)
    logs = {k: [] for k in ("t", "x", "f", "nu_dot")}
    ff_z = -(p.weight - p.buoyancy)
    fc = np.zeros((R_, tr.T.shape[1]))
    z_ref = z0.copy()
    for k in range(n):
        t = k * dt
        if k % log_every == 0:  # the controller runs at the logging rate (commands held in between)
            u_ref, psi_ref, z_goal, on = schedule(t, prm)
            z_ref = z_ref + np.clip(z_goal - z_ref, -Z_RATE * dt * log_every, Z_RATE * dt * log_every)
            u, w, r, phi, pp = x[:, 6], x[:, 8], x[:, 11], x[:, 3], x[:, 9]
            ez = z_ref - x[:, 2]
            iz = np.clip(iz + ez * dt * log_every, -2, 2)
            iu = np.clip(iu + (u_ref - u) * dt * log_every * on, -1, 1)
            X = (35 * (u_ref - u) + 12 * iu + p.Q[0, 0] * np.abs(u_ref) * u_ref + p.D_L[0, 0] * u_ref) * on
            Z = 55 * ez + 12 * iz - 28 * w + ff_z
            epsi = (psi_ref - x[:, 5] + np.pi) % (2 * np.pi) - np.pi
            N = 2.5 * epsi - 1.2 * r
            K = -2.0 * phi - 0.5 * pp
            fc = np.clip(np.stack([X, Z, K, N], 1) @ A.T, p.f_min, p.f_max)
            logs["t"].append(t)
            logs["x"].append(x.copy())
            logs["f"].append(fc.copy())
        f, g = tr.thrust(fc, g, x, dt)
        k1 = tr.deriv(x, f, t)
        if k % log_every == 0:
            logs["nu_dot"].append(k1[:, 6:].copy())
        k2 = tr.deriv(x + dt / 2 * k1, f, t + dt / 2)
        k3 = tr.deriv(x + dt / 2 * k2, f, t + dt / 2)
        k4 = tr.deriv(x + dt * k3, f, t + dt)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    tl = np.array(logs["t"])
    X_, Fc, ND = np.array(logs["x"]), np.array(logs["f"]), np.array(logs["nu_dot"])
    runs = []
    for j in range(R_):
        ch = {c: X_[:, j, i] + rng.normal(0, noise_scale * NOISE[c], tl.size) for i, c in enumerate(STATES)}
        if altitude:
            ch["altitude"] = SEABED - X_[:, j, 2] + rng.normal(0, 0.01, tl.size)
        extra = {}
        if sensors == "stock":
            sf = specific_force(X_[:, j, :], ND[:, j, :])
            bias = rng.uniform(-ACCEL_BIAS, ACCEL_BIAS, 3)
            for i, c in enumerate(("ax", "ay", "az")):
                ch[c] = sf[:, i] + bias[i] + rng.normal(0, noise_scale * ACCEL_NOISE, tl.size)
            for c in ("u", "v", "w", "x", "y"):
                ch.pop(c)
            extra = {f"true_{c}": X_[:, j, i].copy() for i, c in enumerate(STATES)}
        meta = {"format": "udrobot-run/1", "vehicle": "udrobot", "water_density": RHO, "seabed_depth": SEABED,
                "walls": [{"point": [0.0, WALL_Y, 0.0], "normal": [0.0, -1.0, 0.0]}]}
        runs.append(Run(path=f"indep_{j}.csv", t=tl.copy(), channels=ch, input_kind="thrust", inputs=Fc[:, j, :],
                        extra=extra, metadata=meta))
    return runs
