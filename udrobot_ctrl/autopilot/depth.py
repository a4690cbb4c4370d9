"""ArduSub's depth loop: ``AC_PosControl``'s z axis as ArduSub 4.1-4.5 runs it, in SI on the NED *down* axis.

Source: ``libraries/AC_AttitudeControl/AC_PosControl.cpp`` (4.1+ rewrite), ``update_z_controller``::

    vel_target  = P_1D(pos_target, pos)            AC_P_1D::update_all: sqrt_controller(err, PSC_POSZ_P,
                                                   accel_max, dt), err limited by inv_sqrt_controller(speed)
                + vel_desired                      feed-forward from the shaped/commanded trajectory
    accel_target = PID_Basic(vel_target, vel)      PSC_VELZ (P, I, D, FLTE, FLTD; I one-sided at the throttle
                + accel_desired                    limits: throttle_lower / throttle_upper)
    imax_accel = max(PSC_ACCZ_IMAX, hover * 1000)  "ensure imax is always large enough to overpower hover"
    thr = PID(accel_target, accel_meas) * 0.001    PSC_ACCZ (P, I, D, FLTE 20 Hz), limit = any throttle limit
        + get_ff() * 0.001 + MOT_THST_HOVER
    attitude_control.set_throttle_out(thr, true, POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ)   (Sub ignores the boost)

ArduSub's z axis is *up* in cm (4.1-4.5: ``get_position_z_up_cm``, ``get_z_accel_cmss = -(accel_ef.z + g) 100``).
Here it is written on the down axis in metres, which is how the dive's PSCD and PIDA log it (PIDA.Tar =
PSCD.TAD, positive down; CTUN.ThI = hover - (P + I + D)): the PID outputs are the same up to sign, so
``throttle = hover - PID_down(...)``. The 0.001 throttle per cm/s^2 scaling is folded into the SI gains
(:mod:`.params`).

Version differences (``AC_PosControl``):

* 3.x-4.0 (not covered): ``pos_to_rate_z`` / ``rate_to_accel_z`` / ``accel_to_throttle`` with leash lengths, a
  ``PSC_VELZ_P``-only velocity loop (AC_P) and an error low-pass ``POSCONTROL_VEL_ERROR_CUTOFF_FREQ``.
* 4.1-4.4: the structure above; ``PSC_VELZ`` became an ``AC_PID_Basic`` (I, D, FF usable, defaults 0); the pilot's
  climb rate is shaped by ``input_vel_accel_z`` (jerk-limited, ``shape_vel_accel`` in ``control.cpp``).
* 4.5: unchanged in the loop; ``PSC_JERK_Z`` shaping default 5 m/s^3 and the D-axis logging (PSCD).
  Here the pilot's climb-rate shaping is simplified to an acceleration-limited ramp of ``vel_desired``
  (``PILOT_ACCEL_Z``) integrated into ``pos_target`` -- exact in the steady state (sticks centred: the target
  holds), approximate during stick transients. GUIDED and SURFTRAK take the logged or commanded targets as they
  are (:meth:`DepthController.set_targets`). ALT_HOLD's surface and bottom clamps of ``pos_target`` are in
  :mod:`.surface_bottom`.

Saturation (ArduSub 4.1-4.5, the behaviour that keeps a saturated dive from winding the loop up):

* ``AP_Motors6DOF::output_armed_stabilizing``: ``limit.throttle_lower`` / ``throttle_upper`` are set when the
  bidirectional throttle reaches -1 / +1 (the motors' filtered throttle at 0 / 1); ``update_z_controller`` reads
  the flags of the previous output. :class:`~udrobot_ctrl.autopilot.ardusub.ArduSubAutopilot` feeds its own
  flags back (and any the caller gives).
* ``update_z_controller``: ``_pid_vel_z.update_all(..., limit.throttle_lower, limit.throttle_upper)`` (the
  velocity integrator does not grow towards the limit), ``_pid_accel_z.update_all(..., throttle_lower ||
  throttle_upper)`` (the acceleration integrator may only shrink), and at its end ``_limit_vector.z`` = +1
  (upper) / -1 (lower) / 0, up frame.
* ``input_vel_accel_z`` (``set_pos_target_z_from_climb_rate_cm``) -> ``update_pos_vel_accel(_pos_target.z,
  _vel_desired.z, _accel_desired.z, dt, _limit_vector.z, _p_pos_z.get_error(), _pid_vel_z.get_error())``
  (``libraries/AP_Math/control.cpp``): the target's position step is skipped when it points along the limit and
  the position error already does (``delta_pos * limit > 0 && pos_error * limit > 0``), and likewise the desired
  velocity's step with the velocity error. A target the vehicle cannot follow stops moving: once the pilot
  centres the stick the vehicle is held where the target stopped.
* ``AC_P_1D`` (``PSC_POSZ``) limits the position error to ``inv_sqrt_controller(PILOT_SPEED_DN/UP)`` and moves
  the target to within that distance of the vehicle.

Here the limit vector is on the down axis (+1 = ``throttle_lower``: full down-thrust, -1 = ``throttle_upper``).
"""
from __future__ import annotations

from dataclasses import replace

from udrobot_ctrl.ardusub.params import DepthParameters
from udrobot_ctrl.autopilot.pid import ACPID, ACPIDBasic, PIDTerms, inv_sqrt_controller, sqrt_controller


class DepthController:
    """``AC_PosControl`` z (ArduSub 4.1-4.5) on the down axis, with its PID state.

    Parameters
    ----------
    params : DepthParameters
        Gains, hover throttle and speed/acceleration limits (SI).

    Attributes
    ----------
    pos_target, vel_desired, accel_desired : float
        Depth target (m, down), its feed-forward velocity (m/s) and acceleration (m/s^2).
    vel_target, accel_target : float
        The last velocity and acceleration demands (m/s, m/s^2), as PSCD's TVD and TAD.
    active : bool
        False until :meth:`init` (``init_z_controller``) has run.
    """

    def __init__(self, params: DepthParameters):
        self.params = params
        self.pid_vel = ACPIDBasic(params.vel)
        self.pid_accel = ACPID(params.accel)
        self.pos_target = 0.0
        self.vel_desired = 0.0
        self.accel_desired = 0.0
        self.vel_target = 0.0
        self.accel_target = 0.0
        self.throttle = params.throttle_hover
        self.active = False
        #: ``_limit_vector.z`` on the down axis (+1 throttle_lower, -1 throttle_upper, 0 none), set by update
        self.limit_down = 0.0
        self._pos_error = 0.0

    def init(self, depth: float, vel_down: float, throttle_in: float) -> None:
        """``init_z_controller``: targets to the current depth and velocity, accel I term from the throttle.

        Parameters
        ----------
        depth : float
            Current depth (m, positive down).
        vel_down : float
            Current vertical velocity (m/s, positive down).
        throttle_in : float
            The throttle being applied (0..1), so the switch into depth hold is bumpless.
        """
        self.pos_target = depth
        self.vel_desired = vel_down
        self.accel_desired = 0.0
        self.pid_vel.reset_filter()
        self.pid_vel.set_integrator(0.0)
        self.pid_accel.reset_filter()
        self._sync_imax()
        # up frame: I = (throttle_in - hover) * 1000 (cm/s^2 units); down frame and SI: -(throttle_in - hover)
        self.pid_accel.set_integrator(-(throttle_in - self.params.throttle_hover))
        self.throttle = throttle_in
        self.active = True
        self.limit_down = 0.0
        self._pos_error = 0.0

    def relax(self, depth: float, throttle: float) -> None:
        """``relax_z_controller``: hold the current depth, integrator from ``throttle`` (used while disarmed)."""
        self.init(depth, 0.0, throttle)

    def _sync_imax(self) -> None:
        hover = self.params.throttle_hover
        if hover > self.pid_accel.gains.imax:
            self.pid_accel.gains = replace(self.pid_accel.gains, imax=hover)

    def set_pos_target_from_climb_rate(self, climb_rate: float, dt: float) -> None:
        """The pilot's climb rate (m/s, positive *up*, ArduSub's sign) moves the depth target (see module notes).

        ``vel_desired`` is integrated into ``pos_target`` and ramps to ``-climb_rate`` at ``accel_max``; neither step
        is taken towards a throttle limit the errors already point to (``update_pos_vel_accel`` with
        :attr:`limit_down`, module notes).
        """
        limit = self.limit_down
        delta_pos = self.vel_desired * dt
        if not (delta_pos * limit > 0.0 and self._pos_error * limit > 0.0):
            self.pos_target += delta_pos
        want = -climb_rate
        step = self.params.accel_max * dt
        delta_vel = min(max(want, self.vel_desired - step), self.vel_desired + step) - self.vel_desired
        if not (delta_vel * limit > 0.0 and self.pid_vel.error * limit > 0.0):
            self.vel_desired += delta_vel
        self.accel_desired = 0.0

    def set_targets(self, depth: float, vel_down: float = 0.0, accel_down: float = 0.0) -> None:
        """Set the position, velocity and acceleration targets directly (GUIDED, SURFTRAK; PSCD TPD/DVD/DAD).

        Parameters
        ----------
        depth : float
            Target depth (m, down).
        vel_down, accel_down : float
            Feed-forward velocity (m/s) and acceleration (m/s^2), down.
        """
        self.pos_target, self.vel_desired, self.accel_desired = depth, vel_down, accel_down

    def update(self, depth: float, vel_down: float, accel_down: float, dt: float, limit_lower: bool = False,
               limit_upper: bool = False) -> float:
        """``update_z_controller``: one tick; returns the throttle (0..1, 0.5 neutral with the default hover).

        Parameters
        ----------
        depth, vel_down, accel_down : float
            Measured depth (m), vertical velocity (m/s) and kinematic vertical acceleration (m/s^2), all down.
        dt : float
            Tick (s).
        limit_lower, limit_upper : bool
            The motors' ``limit.throttle_lower`` / ``throttle_upper`` (saturation flags).
        """
        p = self.params
        # AC_P_1D error limits from the speed limits (set_max_speed_accel_z -> set_limits)
        err = self.pos_target - depth
        err_max_down = inv_sqrt_controller(p.speed_down_effective, p.pos_p, p.accel_max)
        err_max_up = inv_sqrt_controller(abs(p.speed_up), p.pos_p, p.accel_max)
        if err > err_max_down > 0:
            err = err_max_down
            self.pos_target = depth + err
        elif err < -err_max_up < 0:
            err = -err_max_up
            self.pos_target = depth + err
        self._pos_error = err
        self.vel_target = sqrt_controller(err, p.pos_p, p.accel_max, dt) + self.vel_desired
        # up-frame (limit_neg = throttle_lower, limit_pos = throttle_upper) seen from the down axis
        self.accel_target = self.pid_vel.update_all(self.vel_target, vel_down, dt, limit_neg=limit_upper,
                                                    limit_pos=limit_lower) + self.accel_desired
        self._sync_imax()
        out = self.pid_accel.update_all(self.accel_target, accel_down, dt, limit_lower or limit_upper)
        self.throttle = p.throttle_hover - (out + self.pid_accel.ff)
        self.limit_down = 1.0 if limit_lower else -1.0 if limit_upper else 0.0
        return self.throttle

    @property
    def terms(self) -> PIDTerms:
        """The last PIDA terms (down frame, SI: Tar/Act/Err in m/s^2, P/I/D in throttle)."""
        return self.pid_accel.terms


__all__ = ["DepthController"]
