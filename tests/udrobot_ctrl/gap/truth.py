"""Truth generator for the gap diagnoser: closed-loop pool runs of a plant with a withheld effect.

The effects are written in forms *different* from the diagnoser's templates, so that a passing test
means the physics was recovered, not a formula matched:

* thrust_inflow_loss: propeller K_T(J) = K_T0 - a1 J - a2 J^2 with the rotor speed set by the command
  (the template is linear in |f| u and sqrt(|f|) u);
* thruster_deadband: a deadband in the ESC's PWM domain with a quadratic thrust curve;
* thruster_asymmetry: a reverse thrust curve with its own power law;
* thruster_lag: first-order dynamics of the rotor speed (thrust ~ n|n|), not of the thrust;
* tether_drag: a straight cable from a handler walking along the pool edge, normal drag integrated along
  20 nodes with each node's velocity, weighted by its share carried by the vehicle end; or (``anchor`` given,
  :func:`anchored_tether`) the same cable from a fixed point on a deck at the pool edge, its drag growing with the
  straight-line length (a taut cable); with ``slack_length`` given, that paid-out length (m) instead, whatever the
  distance (the template: a drag per metre of the straight line, or lumped, integrated over 3 Gauss points); with
  ``attach`` given (body frame, m), tied at that hull point: its position and velocity, and the moment r_a x F;
* wall_effect: method-of-images sphere laws, added mass ~ (a/h)^3, suction ~ (a/h)^4;
* water_current: a 1/7-power boundary-layer profile over the pool depth;
* linear_damping: a |nu|^1.1 skin-friction law; quadratic_damping_error: drag on the speed *norm*;
* added_mass_error: scaled M_A (with its Coriolis part); cross_coupled_damping: u|u| lift and yaw terms and a
  Munk u w moment; buoyancy_offset: compressible foam, dB(z); cg_cb_offset: a shifted ballast (r_g moved).
* drag_centre_offset: the *quadratic* (form) drag alone acts at a centre of pressure r, with that point's velocity,
  while the linear (skin-friction) drag stays at the CO (the template moves the whole translational drag, linear
  and quadratic, to one point);
* outside the catalogue: a periodic (wave) disturbance, a sensor delay, and a neutral offset (the horizontal
  thrusters' ESCs trimmed off their neutral: a constant surge force ``X`` in the body frame; no random draw).
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.dynamics.plant import (
    coriolis_centripetal,
    generalized_forces,
    kinematics,
    plant_parameters,
    restoring_forces,
    rotation_zyx,
)
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model

RHO = 1000.0
SEABED = 3.0
WALL_Y = 0.0  # wall plane y = 0, water on y < 0 (normal (0, -1, 0))
GRAVITY = 9.81  # m/s^2
# accelerometer of the stock sensor set (assumed): white noise 0.03 m/s^2 per logged sample (an MPU-6000 class
# MEMS, 400 ug/sqrt(Hz) over a ~20 Hz band plus thruster vibration) and a residual bias after calibration
ACCEL_NOISE = 0.03
ACCEL_BIAS = 0.03


def random_magnitudes(name, rng):
    """Randomised truth parameters of an effect (documented ranges; large enough to matter in a pool)."""
    u = rng.uniform
    table = {
        "thrust_inflow_loss": {"J0": u(0.35, 0.55)},
        "thruster_deadband": {"delta": u(0.18, 0.3)},
        "thruster_asymmetry": {"ratio": u(0.45, 0.65), "gamma": u(1.05, 1.2)},
        "thruster_lag": {"T_m": u(0.35, 0.6)},
        "tether_drag": {"d": u(0.010, 0.016), "back": u(3.0, 5.0), "cd": u(1.0, 1.2)},
        "wall_effect": {"a": u(0.17, 0.22), "kappa": u(2.0, 3.0)},
        "water_current": {"V0": u(0.08, 0.14), "dir": u(0, 2 * np.pi)},
        "linear_damping": {"dX": u(8, 14), "dZ": u(8, 14), "dN": u(0.15, 0.3), "dK": u(0.05, 0.1)},
        "quadratic_damping_error": {"s_t": u(0.5, 0.9) * rng.choice([-0.7, 1.0]), "s_r": u(0.5, 1.0)},
        "added_mass_error": {"sX": u(0.6, 1.0), "sZ": u(0.6, 1.0), "sN": u(0.6, 1.0)},
        "cross_coupled_damping": {"c_zu": u(12, 20), "c_nu": u(1.0, 2.0), "c_mw": u(1.0, 2.0)},
        "buoyancy_offset": {"dB0": u(1.0, 2.5) * rng.choice([-1, 1]), "beta": u(0.05, 0.15)},
        "cg_cb_offset": {"dz": u(0.006, 0.012) * rng.choice([-1, 1]), "dx": u(-0.004, 0.004)},
        "periodic_disturbance": {"A": u(1.5, 3.0), "period": u(3.0, 6.0)},
        "sensor_delay": {"delay": u(0.25, 0.4)},
    }
    if name != "drag_centre_offset":
        return table[name]
    # drawn after the table, so that adding this effect left every other effect's draws (and the cases built on
    # them) as they were.
    # the form drag's centre 0.8-1.5 cm above or below the CO, 0.6-1.2 cm ahead or behind, within 0.4 cm sideways
    # (an asymmetric frame; as large as the cg_cb_offset's CG shift): UDrobot's pitch stiffness is 1.8 N m/rad,
    # and a heave drag centre 2-4 cm ahead of the CO pitches it by 1-1.6 rad in these runs (the drag ahead of the
    # CO is statically unstable in forward flight), beyond any pool test
    return {"r": (u(0.006, 0.012) * rng.choice([-1, 1]), u(-0.004, 0.004),
                  u(0.008, 0.015) * rng.choice([-1, 1]))}


def anchored_tether(rng):
    """Truth parameters of a tether to a fixed anchor on a deck at the pool edge (wall line y = 0), 0.3 m above the
    water and 2.5-3.5 m behind the runs' start: a 12-20 mm cable (Li et al.'s is 12 mm) with a cylinder's
    normal drag coefficient 1.0-1.2."""
    u = rng.uniform
    return {"d": u(0.012, 0.020), "cd": u(1.0, 1.2), "anchor": (-u(2.5, 3.5), WALL_Y, -0.3)}


def _allocation(T):
    rows = [0, 2, 3, 5]  # X Z K N are actuated on UDrobot
    return np.linalg.pinv(T[rows])


class Truth:
    """Truth plant: nominal UDrobot plus withheld effects with given parameters (dict name -> params)."""

    def __init__(self, model="pendulum:chin", effects=None):
        self.v = load_model(model)
        self.p = plant_parameters(self.v)
        self.M_A = np.asarray(self.v.added_mass, float)
        self.eff = dict(effects or {})
        self.T = self.p.T
        self.fmax = self.p.f_max
        self.frev = -self.p.f_min
        M_A = self.M_A.copy()
        if "added_mass_error" in self.eff:
            e = self.eff["added_mass_error"]
            for i, k in ((0, "sX"), (2, "sZ"), (5, "sN")):
                M_A[i, i] *= 1 + e[k]
        self.M_A_true = M_A
        self.M_true = self.p.M - self.M_A + M_A
        self.r_g_true = np.array(self.p.r_g, float)
        if "cg_cb_offset" in self.eff:
            c = self.eff["cg_cb_offset"]
            self.r_g_true = self.r_g_true + np.array([c["dx"], 0, c["dz"]])

    # ------------------------------------------------------------------ thrusters
    def thrust(self, fc, s_state, x, dt):
        """Actual thrust from commanded fc (R,4); s_state is the rotor state (signed sqrt thrust)."""
        F = np.where(fc >= 0, self.fmax, self.frev)
        s = np.sign(fc) * np.sqrt(np.abs(fc) / F)  # normalised PWM-like command in [-1, 1]
        if "thruster_deadband" in self.eff:
            d = self.eff["thruster_deadband"]["delta"]
            s = np.sign(s) * np.maximum(np.abs(s) - d, 0.0) / (1 - d)
        f = F * s * np.abs(s)
        if "thruster_asymmetry" in self.eff:
            e = self.eff["thruster_asymmetry"]
            f = np.where(f < 0, -e["ratio"] * self.frev * (np.abs(f) / self.frev) ** e["gamma"], f)
        if "thruster_lag" in self.eff:
            Tm = self.eff["thruster_lag"]["T_m"]
            target = np.sign(f) * np.sqrt(np.abs(f))
            a = np.exp(-dt / Tm)
            s_state = a * s_state + (1 - a) * target
            f = s_state * np.abs(s_state)
        if "thrust_inflow_loss" in self.eff:
            J0 = self.eff["thrust_inflow_loss"]["J0"]
            D, KT0 = 0.076, 0.32
            n = np.sqrt(np.abs(f) / (RHO * D ** 4 * KT0)) + 1e-6  # rev/s at the bollard point
            ua = x[:, 6:] @ self.T  # axial speed along each thruster
            J = np.sign(f) * ua / (n * D)
            KT = KT0 * (1 - 0.8 * J / J0 - 0.2 * (J / J0) ** 2 * np.sign(J))
            KT = np.clip(KT, 0.0, 1.6 * KT0)
            f = np.sign(f) * RHO * n ** 2 * D ** 4 * KT
        return f, s_state

    # ------------------------------------------------------------------ environment & hydrodynamics
    def extra(self, x, t, nu_dot_guess=None):
        """Extra generalised force (R,6) and mass increment (R,6,6) of the environment/hydrodynamic effects."""
        R_ = x.shape[0]
        F = np.zeros((R_, 6))
        dM = np.zeros((R_, 6, 6))
        nu = x[:, 6:]
        Rm = rotation_zyx(x[:, 3], x[:, 4], x[:, 5])
        vned = np.einsum("nij,nj->ni", Rm, nu[:, :3])
        e = self.eff
        if "tether_drag" in e:
            c = e["tether_drag"]
            if "anchor" in c:  # fixed on a deck: the cable's direction follows the vehicle around the pool
                anchor = np.broadcast_to(np.asarray(c["anchor"], float), (R_, 3))
                a_dot = np.zeros((R_, 3))
            else:  # a handler walking along the pool edge, c["back"] m behind the vehicle
                anchor = np.stack([x[:, 0] - c["back"], np.full(R_, WALL_Y), np.zeros(R_)], 1)
                a_dot = np.stack([vned[:, 0], np.zeros(R_), np.zeros(R_)], 1)
            r_a = np.asarray(c.get("attach", (0.0, 0.0, 0.0)), float)  # where the cable is tied (body, m)
            tied = x[:, :3] + Rm @ r_a  # that hull point's NED position and velocity
            v_tied = vned + np.einsum("nij,nj->ni", Rm, np.cross(nu[:, 3:6], r_a))
            vec = tied - anchor
            L = np.linalg.norm(vec, axis=1, keepdims=True)
            eh = vec / L
            s = ((np.arange(20) + 0.5) / 20)[None, :, None]  # 20 nodes from the anchor (0) to the vehicle (1)
            ve = a_dot[:, None] + s * (v_tied - a_dot)[:, None]
            vn = ve - np.sum(ve * eh[:, None], -1, keepdims=True) * eh[:, None]
            length = L if "slack_length" not in c else np.full_like(L, c["slack_length"])
            speed = np.linalg.norm(vn, axis=-1, keepdims=True)
            dF = -0.5 * RHO * c["cd"] * c["d"] * (length[:, None] / 20) * speed * vn
            tot = np.einsum("nji,nj->ni", Rm, np.sum(s * dF, axis=1))  # body frame, at the hull point
            F[:, :3] += tot
            F[:, 3:] += np.cross(r_a, tot)
        if "wall_effect" in e:
            c = e["wall_effect"]
            a = c["a"]
            m_ref = RHO * 2 / 3 * np.pi * a ** 3
            for h, nrm in ((SEABED - x[:, 2], np.array([0, 0, -1.0])), (WALL_Y - x[:, 1], np.array([0, -1.0, 0]))):
                hh = np.maximum(h, 1.2 * a)  # gap ratio >= 1.2: the body never touches
                nb = np.einsum("nji,j->ni", Rm, nrm)
                ratio = (a / hh) ** 3
                P = nb[:, :, None] * nb[:, None, :]
                dM[:, :3, :3] += c["kappa"] * m_ref * (ratio[:, None, None] * (3 / 8 * P + 3 / 16 * (np.eye(3) - P)))
                vn = np.sum(nu[:, :3] * nb, 1)
                vt2 = np.maximum(np.sum(nu[:, :3] ** 2, 1) - vn ** 2, 0)
                F[:, :3] += -(c["kappa"] * 3 / 8 * RHO * np.pi * a ** 2 * vt2 * (a / hh) ** 4)[:, None] * nb
        if "water_current" in e:
            c = e["water_current"]
            prof = np.clip((SEABED - x[:, 2]) / SEABED, 0, 1) ** (1 / 7)
            vc = c["V0"] * prof[:, None] * np.array([np.cos(c["dir"]), np.sin(c["dir"]), 0.0])
            nu_r = nu.copy()
            nu_r[:, :3] -= np.einsum("nji,nj->ni", Rm, vc)
            p = self.p
            damp = lambda v: v @ p.D_L.T + (np.abs(v) * v) @ p.Q.T  # noqa: E731
            F += damp(nu) - damp(nu_r) + coriolis_centripetal(self.M_A, nu) - coriolis_centripetal(self.M_A, nu_r)
        if "linear_damping" in e:
            c = e["linear_damping"]
            d = np.array([c["dX"], 0, c["dZ"], c["dK"], 0, c["dN"]])
            ref = np.array([0.3, 0.3, 0.3, 0.5, 0.5, 0.5])
            F += -d * ref * np.sign(nu) * np.abs(nu / ref) ** 1.1
        if "quadratic_damping_error" in e:
            c = e["quadratic_damping_error"]
            q = np.diag(self.p.Q)
            F[:, :3] += -c["s_t"] * q[:3] * np.linalg.norm(nu[:, :3], axis=1, keepdims=True) * nu[:, :3]
            F[:, 3:] += -c["s_r"] * q[3:] * np.linalg.norm(nu[:, 3:], axis=1, keepdims=True) * nu[:, 3:]
        if "added_mass_error" in e:
            F += coriolis_centripetal(self.M_A, nu) - coriolis_centripetal(self.M_A_true, nu)
        if "cross_coupled_damping" in e:
            c = e["cross_coupled_damping"]
            u, w = nu[:, 0], nu[:, 2]
            F[:, 2] += -c["c_zu"] * u * np.abs(u)
            F[:, 5] += -c["c_nu"] * u * np.abs(u)
            F[:, 4] += c["c_mw"] * u * w
        if "buoyancy_offset" in e:
            c = e["buoyancy_offset"]
            dB = c["dB0"] * (1 - c["beta"] * x[:, 2])
            F += -dB[:, None] * restoring_forces(x[:, :6], 0.0, 1.0, self.p.r_g, self.p.r_b)
        if "cg_cb_offset" in e:
            p = self.p
            F += restoring_forces(x[:, :6], p.weight, p.buoyancy, p.r_g, p.r_b) - \
                restoring_forces(x[:, :6], p.weight, p.buoyancy, self.r_g_true, p.r_b)
        if "drag_centre_offset" in e:
            r_cp = np.asarray(e["drag_centre_offset"]["r"], float)
            q = np.diag(self.p.Q)[:3]
            v_cp = nu[:, :3] + np.cross(nu[:, 3:6], r_cp)  # the centre's own velocity
            f_cp = -q * np.abs(v_cp) * v_cp
            F[:, :3] += f_cp + q * np.abs(nu[:, :3]) * nu[:, :3]  # replaces the quadratic drag at the CO
            F[:, 3:] += np.cross(r_cp, f_cp)
        if "periodic_disturbance" in e:
            c = e["periodic_disturbance"]
            wv = c["A"] * np.sin(2 * np.pi * t / c["period"]) * np.exp(-x[:, 2] / 2.0)
            F[:, 0] += wv
            F[:, 2] += 0.7 * c["A"] * np.cos(2 * np.pi * t / c["period"]) * np.exp(-x[:, 2] / 2.0)
        if "neutral_offset" in e:  # the horizontal thrusters' ESCs trimmed off neutral: a constant body-fixed push
            F[:, 0] += e["neutral_offset"]["X"]
        return F, dM

    def deriv(self, x, f, t):
        tau = f @ self.T.T
        F, dM = self.extra(x, t)
        tot = tau + F - generalized_forces(x, self.p)
        M = self.p.M + (self.M_true - self.p.M) + dM
        nd = np.linalg.solve(M, tot[..., None])[..., 0]
        return np.concatenate([kinematics(x[:, :6], x[:, 6:]), nd], 1)


def schedule(t, prm, turn_rate=0.0):
    """References (u_ref, psi_ref, z_ref, surge_on) for a pool test of 90 s with randomised magnitudes.

    ``turn_rate`` (rad/s) adds a steady heading ramp from t = 4 s: the surge legs become arcs and the vehicle
    loops around the pool (``generate(path="loop")``).
    """
    a1, a2, a3, dpsi, z0, zdeep = prm
    u_ref = np.zeros_like(a1)
    on = np.ones_like(a1, bool)
    psi = np.zeros_like(a1)
    z = z0.copy()
    if 4 <= t < 18:
        u_ref = a1
    elif 18 <= t < 24:
        on[:] = False
    elif 24 <= t < 38:
        u_ref = a2
    elif 38 <= t < 44:
        u_ref = -0.25 * np.ones_like(a1)
    elif 44 <= t < 50:
        psi = dpsi
    elif 50 <= t < 62:
        u_ref, z = a3, zdeep
    elif 62 <= t < 70:
        u_ref = 0.2 * np.ones_like(a1)
    elif t >= 70:
        u_ref = a3 + 0.15 * np.sin(2 * np.pi * t / 9.0)
        z = z0 + 0.3 * np.sin(2 * np.pi * t / 13.0)
        psi = 0.3 * np.sin(2 * np.pi * t / 17.0)
    if 28 <= t < 34:
        psi = psi + 0.5
    if turn_rate and t >= 4:
        psi = psi + turn_rate * (t - 4)
    return u_ref, psi, z, on


#: heading rate of the loop path (rad/s): one turn in 40 s, i.e. circles of 2-4 m radius at 0.3-0.6 m/s, turning
#: away from the wall (towards -y, into the pool)
LOOP_TURN_RATE = -2 * np.pi / 40.0


def specific_force(x, nu_dot, g=GRAVITY):
    """Accelerometer reading (specific force at the body origin, body FRD, m/s^2) of states x (..., 12) with body
    accelerations nu_dot (..., 6): f = v_dot + omega x v - R^T [0, 0, g] (run-log format)."""
    phi, th = x[..., 3], x[..., 4]
    g_body = g * np.stack([-np.sin(th), np.cos(th) * np.sin(phi), np.cos(th) * np.cos(phi)], -1)
    return nu_dot[..., :3] + np.cross(x[..., 9:12], x[..., 6:9]) - g_body


def generate(effects=None, n_runs=3, duration=90.0, rate=20.0, seed=0, model="pendulum:chin", partial=False,
             wall_distance=None, noise_scale=1.0, path="legs", sensors="full", headings=None):
    """Simulate ``n_runs`` closed-loop pool runs with the withheld ``effects`` (name -> params dict).

    ``path``: ``"legs"`` (surge legs along the pool with yaw turns) or ``"loop"`` (the same legs as arcs of a steady
    turn, :data:`LOOP_TURN_RATE`: the vehicle goes around, so a cable to a fixed anchor turns with it).
    ``sensors``: ``"full"`` logs pose, body velocities and altitude (a pool vehicle with DVL and positioning);
    ``"stock"`` logs what a stock small ROV has: depth, attitude, gyro rates and the accelerometer ``ax ay az``
    (specific force of the truth state, white noise ``ACCEL_NOISE`` plus a constant bias per axis and run drawn
    uniformly in +-``ACCEL_BIAS``), no u v w x y altitude.
    ``headings``: each run's base heading (rad, default 0: every run flies its legs north along the wall); the
    references turn by as much, so a run with pi flies the reverse transect.

    Returns a list of :class:`udrobot_ctrl.io.runlog.Run` (thrust_i inputs, noisy sensors, sidecar metadata
    with the seabed depth and the wall) -- the diagnoser sees nothing else.
    """
    if sensors not in ("full", "stock"):
        raise ValueError(f"sensors must be 'full' or 'stock', got {sensors!r}")
    rng = np.random.default_rng(seed)
    tr = Truth(model, effects)
    R_ = n_runs
    dt = 0.01
    n = int(round(duration / dt))
    log_every = int(round(1 / (rate * dt)))
    a1 = rng.uniform(0.25, 0.4, R_)
    a2 = rng.uniform(0.5, 0.7, R_)
    a3 = rng.uniform(0.25, 0.4, R_)
    dpsi = rng.uniform(0.8, 1.5, R_) * rng.choice([-1, 1], R_)
    z0 = rng.uniform(0.8, 1.4, R_)
    zdeep = SEABED - rng.uniform(0.25, 0.4, R_)
    if wall_distance is None:  # runs alternate near (0.2-0.35 m) and far (1.2-2 m) from the wall
        near = np.arange(R_) % 2 == 0
        wall_distance = np.where(near, rng.uniform(0.2, 0.35, R_), rng.uniform(1.2, 2.0, R_))
    ywall = -np.asarray(wall_distance, float) * np.ones(R_)
    prm = (a1, a2, a3, dpsi, z0, zdeep)
    if path not in ("legs", "loop"):
        raise ValueError(f"path must be 'legs' or 'loop', got {path!r}")
    turn_rate = LOOP_TURN_RATE if path == "loop" else 0.0
    psi0 = np.zeros(R_) if headings is None else np.asarray(headings, float) * np.ones(R_)
    x = np.zeros((R_, 12))
    x[:, 2] = z0
    x[:, 5] = psi0
    x[:, 1] = WALL_Y + ywall
    s_state = np.zeros((R_, 4))
    A = _allocation(tr.T)
    p = tr.p
    iz = np.zeros(R_)
    iu = np.zeros(R_)
    logs = {k: [] for k in ("t", "x", "f", "nu_dot")}
    ff_z = -(p.weight - p.buoyancy)  # thrust that holds depth on the nominal model
    for k in range(n):
        t = k * dt
        u_ref, psi_ref, z_ref, on = schedule(t, prm, turn_rate)
        psi_ref = psi_ref + psi0
        u, w, r, phi, pp = x[:, 6], x[:, 8], x[:, 11], x[:, 3], x[:, 9]
        ez = z_ref - x[:, 2]
        iz = np.clip(iz + ez * dt, -2, 2)
        iu = np.clip(iu + (u_ref - u) * dt * on, -1, 1)
        X = (40 * (u_ref - u) + 15 * iu + p.Q[0, 0] * np.abs(u_ref) * u_ref + p.D_L[0, 0] * u_ref) * on
        Z = 60 * ez + 15 * iz - 30 * w + ff_z
        epsi = (psi_ref - x[:, 5] + np.pi) % (2 * np.pi) - np.pi
        N = 3.0 * epsi - 1.5 * r
        K = -2.0 * phi - 0.5 * pp
        logging = k % log_every == 0
        if logging:  # the controller runs at the logging rate (commands held in between)
            fc = np.clip(np.stack([X, Z, K, N], 1) @ A.T, p.f_min, p.f_max)
            logs["t"].append(t)
            logs["x"].append(x.copy())
            logs["f"].append(fc.copy())
        f, s_state = tr.thrust(fc, s_state, x, dt)
        k1 = tr.deriv(x, f, t)
        if logging:
            logs["nu_dot"].append(k1[:, 6:].copy())
        k2 = tr.deriv(x + dt / 2 * k1, f, t + dt / 2)
        k3 = tr.deriv(x + dt / 2 * k2, f, t + dt / 2)
        k4 = tr.deriv(x + dt * k3, f, t + dt)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    tl = np.array(logs["t"])
    X_ = np.array(logs["x"])  # (n, R, 12)
    Fc = np.array(logs["f"])
    ND = np.array(logs["nu_dot"])  # (n, R, 6) truth body accelerations at the logged samples
    delay = effects.get("sensor_delay", {}).get("delay", 0.0) if effects else 0.0
    runs = []
    noise = {"x": 0.03, "y": 0.03, "z": 0.005, "phi": 0.003, "theta": 0.003, "psi": 0.005, "u": 0.008, "v": 0.008,
             "w": 0.008, "p": 0.005, "q": 0.005, "r": 0.005}
    names = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
    for j in range(R_):
        ch = {}
        for i, c in enumerate(names):
            y = X_[:, j, i]
            if delay:
                y = np.interp(tl - delay, tl, y)
            ch[c] = y + rng.normal(0, noise_scale * noise[c], tl.size)
        ch["altitude"] = SEABED - ch["z"] + rng.normal(0, 0.01, tl.size)
        if partial:
            del ch["x"], ch["y"]
            for c in ("u", "v", "w"):
                for g0 in rng.integers(0, tl.size - 40, 3):
                    ch[c][g0:g0 + int(rate * 1.5)] = np.nan
        if sensors == "stock":
            sf = specific_force(X_[:, j, :], ND[:, j, :])
            bias = rng.uniform(-ACCEL_BIAS, ACCEL_BIAS, 3)
            for i, c in enumerate(("ax", "ay", "az")):
                ch[c] = sf[:, i] + bias[i] + rng.normal(0, noise_scale * ACCEL_NOISE, tl.size)
            for c in ("u", "v", "w", "x", "y", "altitude"):
                ch.pop(c, None)
        meta = {"format": "udrobot-run/1", "vehicle": "udrobot", "water_density": RHO, "seabed_depth": SEABED,
                "walls": [{"point": [0.0, WALL_Y, 0.0], "normal": [0.0, -1.0, 0.0]}]}
        # stock runs carry the noiseless truth state as unknown columns true_* (kept and ignored by the diagnoser)
        extra = {f"true_{c}": X_[:, j, i].copy() for i, c in enumerate(names)} if sensors == "stock" else {}
        runs.append(Run(path=f"truth_{j}.csv", t=tl.copy(), channels=ch, input_kind="thrust", inputs=Fc[:, j, :],
                        extra=extra, metadata=meta))
    return runs
