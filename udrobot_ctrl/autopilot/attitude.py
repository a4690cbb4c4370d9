"""ArduSub's attitude controller (``AC_AttitudeControl`` + ``AC_AttitudeControl_Sub``, ArduSub 4.1-4.5).

Two layers, as in the source:

* angle layer (``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp``): the input functions
  ``input_euler_angle_roll_pitch_euler_rate_yaw`` and ``input_euler_angle_roll_pitch_yaw`` shape the pilot's or
  the mode's demand (``input_shaping_angle``: the sqrt controller with ``1 / ATC_INPUT_TC`` and the acceleration
  limits ``ATC_ACCEL_*_MAX``, mapped to Euler axes by ``euler_accel_limit``) into a moving *target* attitude
  (quaternion) and a feed-forward angular velocity (``ATC_RATE_FF_ENAB``); ``attitude_controller_run_quat``
  turns the target-minus-body error (``thrust_heading_rotation_angles``: thrust vector first, then heading, the
  yaw error capped by ``inv_sqrt_controller``) into a body rate demand with ``update_ang_vel_target_from_att_error``
  (``sqrt_controller`` with ``ATC_ANG_*_P`` and half the acceleration limit clamped to 40..720 deg/s^2 for
  roll/pitch, 10..120 deg/s^2 for yaw) plus the rotated feed-forward, blended out when the thrust-vector error
  exceeds 30 deg.
* rate layer (``AC_AttitudeControl_Sub::rate_controller_run``): one ``AC_PID`` per axis on the body rates
  (``ATC_RAT_RLL/PIT/YAW``), output ``update_all(...) + get_ff()`` to the mixer's roll, pitch, yaw.

Quaternions are ``[w, x, y, z]``, body to NED (ArduPilot's ``get_quat_body_to_ned``), Euler angles 3-2-1 in rad.
ArduPilot's public interface takes centidegrees (``*_cd``); this one takes rad and rad/s.

Version notes: 4.1-4.5 share this structure. 4.1-4.4 ``input_shaping_ang_vel`` has no time-constant argument
(Sub never sets ``_rate_y_tc``, so it is 0 and the 4.5 form reduces to the same acceleration clamp); later master
renamed the members to ``*_rad``/``*_rads`` without changing the algorithm.
"""
from __future__ import annotations

import math

import numpy as np

from udrobot_ctrl.ardusub.params import AttitudeParameters
from udrobot_ctrl.autopilot.pid import ACPID, PIDTerms, inv_sqrt_controller, sqrt_controller

ACCEL_RP_CONTROLLER_MIN = math.radians(40.0)    # AC_ATTITUDE_ACCEL_RP_CONTROLLER_MIN_RADSS
ACCEL_RP_CONTROLLER_MAX = math.radians(720.0)   # AC_ATTITUDE_ACCEL_RP_CONTROLLER_MAX_RADSS
ACCEL_Y_CONTROLLER_MIN = math.radians(10.0)     # AC_ATTITUDE_ACCEL_Y_CONTROLLER_MIN_RADSS
ACCEL_Y_CONTROLLER_MAX = math.radians(120.0)    # AC_ATTITUDE_ACCEL_Y_CONTROLLER_MAX_RADSS
THRUST_ERROR_ANGLE = math.radians(30.0)         # AC_ATTITUDE_THRUST_ERROR_ANGLE
YAW_MAX_ERROR_ANGLE = math.radians(45.0)        # AC_ATTITUDE_YAW_MAX_ERROR_ANGLE


# ----------------------------------------------------------------------------------------------- quaternions


def wrap_pi(a: float) -> float:
    """Angle wrapped to (-pi, pi] (rad)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion ``[w, x, y, z]`` (body to NED) of 3-2-1 Euler angles (rad) (``Quaternion::from_euler``)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])


def quat_to_euler(q) -> tuple:
    """3-2-1 Euler angles (roll, pitch, yaw) in rad of a unit quaternion (``Quaternion::to_euler``)."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def quat_mul(a, b) -> np.ndarray:
    """Hamilton product ``a * b``."""
    aw, ax, ay, az = (float(c) for c in a)
    bw, bx, by, bz = (float(c) for c in b)
    return np.array((aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw))


def quat_inv(q) -> np.ndarray:
    """Inverse of a unit quaternion (its conjugate)."""
    return np.array((q[0], -q[1], -q[2], -q[3]), dtype=float)


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def quat_rotate(q, v) -> np.ndarray:
    """``q * v``: vector ``v`` rotated by unit quaternion ``q`` (body vector -> NED for a body-to-NED ``q``).

    ``v + 2 w (r x v) + 2 r x (r x v)`` with ``q = (w, r)``, the same rotation as ``q (0, v) q*``.
    """
    w, r = float(q[0]), (float(q[1]), float(q[2]), float(q[3]))
    v = (float(v[0]), float(v[1]), float(v[2]))
    t = _cross(r, v)
    u = _cross(r, t)
    return np.array((v[0] + 2.0 * (w * t[0] + u[0]), v[1] + 2.0 * (w * t[1] + u[1]), v[2] + 2.0 * (w * t[2] + u[2])))


def quat_from_axis_angle(v) -> np.ndarray:
    """Quaternion of the rotation vector ``v`` (axis times angle, rad) (``Quaternion::from_axis_angle(Vector3f)``)."""
    angle = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    s = math.sin(angle / 2) / angle
    return np.array([math.cos(angle / 2), v[0] * s, v[1] * s, v[2] * s])


def quat_to_axis_angle(q) -> np.ndarray:
    """Rotation vector (rad) of a quaternion, angle wrapped to +-pi (``Quaternion::to_axis_angle``)."""
    length = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    v = np.array([q[1], q[2], q[3]], dtype=float)
    if length != 0.0:
        v *= wrap_pi(2.0 * math.atan2(length, q[0])) / length
    return v


def _normalise(q) -> np.ndarray:
    return np.asarray(q, dtype=float) / math.sqrt(float(np.dot(q, q)))


# ---------------------------------------------------------------------------------------- shaping functions


def input_shaping_angle(error_angle: float, input_tc: float, accel_max: float, target_ang_vel: float, dt: float,
                        desired_ang_vel: float = 0.0, max_ang_vel: float = 0.0) -> float:
    """``AC_AttitudeControl::input_shaping_angle``: the shaped angular velocity (rad/s) towards ``error_angle``.

    ``desired + sqrt_controller(error, 1 / max(tc, 0.01), accel_max, dt)``, limited to ``max_ang_vel`` (if > 0),
    then slewed from ``target_ang_vel`` by at most ``accel_max dt``.
    """
    desired_ang_vel += sqrt_controller(error_angle, 1.0 / max(input_tc, 0.01), accel_max, dt)
    if max_ang_vel > 0.0:
        desired_ang_vel = min(max(desired_ang_vel, -max_ang_vel), max_ang_vel)
    return input_shaping_ang_vel(target_ang_vel, desired_ang_vel, accel_max, dt)


def input_shaping_ang_vel(target_ang_vel: float, desired_ang_vel: float, accel_max: float, dt: float) -> float:
    """``AC_AttitudeControl::input_shaping_ang_vel`` (tc = 0): slew ``target`` towards ``desired`` at ``accel_max``."""
    if accel_max > 0.0:
        delta = accel_max * dt
        return min(max(desired_ang_vel, target_ang_vel - delta), target_ang_vel + delta)
    return desired_ang_vel


def euler_accel_limit(euler_rp: tuple, accel: tuple) -> tuple:
    """``AC_AttitudeControl::euler_accel_limit``: body acceleration limits mapped to the Euler axes (rad/s^2)."""
    if not all(a > 0 for a in accel):
        return tuple(accel)
    phi, theta = euler_rp
    sin_phi = min(max(abs(math.sin(phi)), 0.1), 1.0)
    cos_phi = min(max(abs(math.cos(phi)), 0.1), 1.0)
    sin_theta = min(max(abs(math.sin(theta)), 0.1), 1.0)
    cos_theta = min(max(abs(math.cos(theta)), 0.1), 1.0)
    return (accel[0], min(accel[1] / cos_phi, accel[2] / sin_phi),
            min(accel[0] / sin_theta, accel[1] / (sin_phi * cos_theta), accel[2] / (cos_phi * cos_theta)))


def euler_rate_to_ang_vel(euler_rp: tuple, euler_rate) -> np.ndarray:
    """``AC_AttitudeControl::euler_rate_to_ang_vel``: 3-2-1 Euler rates -> body angular velocity (rad/s)."""
    phi, theta = euler_rp
    st, ct, sp, cp = math.sin(theta), math.cos(theta), math.sin(phi), math.cos(phi)
    return np.array([euler_rate[0] - st * euler_rate[2], cp * euler_rate[1] + sp * ct * euler_rate[2],
                     -sp * euler_rate[1] + ct * cp * euler_rate[2]])


def ang_vel_to_euler_rate(euler_rp: tuple, ang_vel) -> np.ndarray:
    """``AC_AttitudeControl::ang_vel_to_euler_rate``: body angular velocity -> 3-2-1 Euler rates (rad/s)."""
    phi, theta = euler_rp
    st, ct, sp, cp = math.sin(theta), math.cos(theta), math.sin(phi), math.cos(phi)
    if ct == 0.0:
        return np.zeros(3)
    return np.array([ang_vel[0] + sp * (st / ct) * ang_vel[1] + cp * (st / ct) * ang_vel[2],
                     cp * ang_vel[1] - sp * ang_vel[2], (sp / ct) * ang_vel[1] + (cp / ct) * ang_vel[2]])


def ang_vel_limit(w, rate_max: tuple) -> np.ndarray:
    """``AC_AttitudeControl::ang_vel_limit``: elliptical roll/pitch limit and yaw clamp (0 = no limit)."""
    w = np.array(w, dtype=float)
    rmax, pmax, ymax = rate_max
    if rmax == 0.0 or pmax == 0.0:
        if rmax:
            w[0] = min(max(w[0], -rmax), rmax)
        if pmax:
            w[1] = min(max(w[1], -pmax), pmax)
    else:
        length = math.hypot(w[0] / rmax, w[1] / pmax)
        if length > 1.0:
            w[0] /= length
            w[1] /= length
    if ymax:
        w[2] = min(max(w[2], -ymax), ymax)
    return w


def thrust_heading_rotation_angles(attitude_target, attitude_body, yaw_error_max: float) -> tuple:
    """``thrust_vector_rotation_angles`` + ``thrust_heading_rotation_angles``: the error rotation vector (rad).

    Returns
    -------
    error : ndarray (3,)
        x, y: the rotation that aligns the body thrust axis with the target's; z: the remaining heading error,
        capped at ``yaw_error_max``.
    attitude_target : ndarray (4,)
        The target, moved towards the body when the heading error was capped (ArduPilot changes it in place).
    thrust_error_angle : float
        Angle between the body and target thrust vectors (rad).
    """
    up = (0.0, 0.0, -1.0)
    target_thrust = quat_rotate(attitude_target, up)
    body_thrust = quat_rotate(attitude_body, up)
    cross = np.array(_cross(body_thrust, target_thrust))
    dot = float(body_thrust[0] * target_thrust[0] + body_thrust[1] * target_thrust[1]
                + body_thrust[2] * target_thrust[2])
    thrust_error_angle = math.acos(min(max(dot, -1.0), 1.0))
    length = math.sqrt(float(cross[0] ** 2 + cross[1] ** 2 + cross[2] ** 2))
    if length == 0.0 or thrust_error_angle == 0.0:
        cross = np.array(up)
    else:
        cross = cross / length
    cross = quat_rotate(quat_inv(attitude_body), cross)
    thrust_correction = quat_from_axis_angle(cross * thrust_error_angle)
    rot = quat_to_axis_angle(thrust_correction)
    heading_correction = quat_mul(quat_mul(quat_inv(thrust_correction), quat_inv(attitude_body)), attitude_target)
    error = np.array([rot[0], rot[1], quat_to_axis_angle(heading_correction)[2]])
    if abs(error[2]) > yaw_error_max:
        error[2] = min(max(wrap_pi(error[2]), -yaw_error_max), yaw_error_max)
        attitude_target = quat_mul(quat_mul(attitude_body, thrust_correction),
                                   quat_from_axis_angle((0.0, 0.0, error[2])))
    return error, attitude_target, thrust_error_angle


# --------------------------------------------------------------------------------------------- controller


class AttitudeController:
    """``AC_AttitudeControl_Sub``: the angle layer and the three rate PIDs, with their state.

    Parameters
    ----------
    params : AttitudeParameters
        Gains and limits (SI).

    Notes
    -----
    Call an ``input_*`` method once per tick (the flight mode's part) and :meth:`rate_controller_run` once per
    tick (the fast loop's part); ArduSub runs the rate controller *first* in ``Sub::fast_loop``, on the rate
    demand the previous tick's input call produced. :class:`~udrobot_ctrl.autopilot.ArduSubAutopilot` does so.
    """

    def __init__(self, params: AttitudeParameters):
        self.params = params
        self.rate_pids = tuple(ACPID(g) for g in params.rate_pids())
        self.attitude_target = np.array([1.0, 0.0, 0.0, 0.0])
        self.euler_rate_target = np.zeros(3)
        self.ang_vel_target = np.zeros(3)       # feed-forward (target frame), rad/s
        self.rate_target = np.zeros(3)          # _ang_vel_body: the rate PIDs' demand, rad/s
        self.thrust_error_angle = 0.0
        self.feedforward_scalar = 1.0

    # -- helpers
    def _accel_max(self) -> tuple:
        return tuple(self.params.accel_max)

    def relax(self, attitude, gyro) -> None:
        """``relax_attitude_controllers``: targets to the current attitude and rates, PIDs reset (I to 0).

        Parameters
        ----------
        attitude : array (4,)
            Body-to-NED quaternion.
        gyro : array (3,)
            Body rates p, q, r (rad/s).
        """
        self.attitude_target = _normalise(attitude)
        self.ang_vel_target = np.array(gyro, dtype=float)
        self.euler_rate_target = ang_vel_to_euler_rate(quat_to_euler(self.attitude_target)[:2], self.ang_vel_target)
        self.thrust_error_angle = 0.0
        for pid in self.rate_pids:
            pid.reset_filter()
            pid.reset_i()
        self.rate_target = np.array(gyro, dtype=float)

    def reset_yaw_target(self, yaw: float) -> None:
        """``reset_yaw_target_and_rate``: rotate the target to heading ``yaw`` (rad), zero the yaw rate target."""
        euler = quat_to_euler(self.attitude_target)
        shift = quat_from_axis_angle((0.0, 0.0, yaw - euler[2]))
        self.attitude_target = _normalise(quat_mul(shift, self.attitude_target))
        self.euler_rate_target[2] = 0.0
        self.ang_vel_target = euler_rate_to_ang_vel(quat_to_euler(self.attitude_target)[:2], self.euler_rate_target)

    def _update_attitude_target(self, dt: float) -> tuple:
        self.attitude_target = _normalise(quat_mul(self.attitude_target,
                                                   quat_from_axis_angle(self.ang_vel_target * dt)))
        return quat_to_euler(self.attitude_target)

    def _finish_ff(self, euler) -> None:
        rp = euler[:2]
        self.ang_vel_target = euler_rate_to_ang_vel(rp, self.euler_rate_target)
        self.ang_vel_target = ang_vel_limit(self.ang_vel_target, self.params.rate_max)
        self.euler_rate_target = ang_vel_to_euler_rate(rp, self.ang_vel_target)

    # -- input functions
    def input_euler_angle_roll_pitch_euler_rate_yaw(self, roll: float, pitch: float, yaw_rate: float, attitude,
                                                    gyro, dt: float) -> None:
        """``input_euler_angle_roll_pitch_euler_rate_yaw``: roll and pitch angles (rad), Euler yaw rate (rad/s).

        ``attitude`` (quaternion) and ``gyro`` (rad/s) are the vehicle's current state; ``dt`` the tick (s).
        """
        euler = self._update_attitude_target(dt)
        p = self.params
        if p.rate_ff_enabled:
            accel = euler_accel_limit(euler[:2], self._accel_max())
            self.euler_rate_target[0] = input_shaping_angle(wrap_pi(roll - euler[0]), p.input_tc, accel[0],
                                                            self.euler_rate_target[0], dt)
            self.euler_rate_target[1] = input_shaping_angle(wrap_pi(pitch - euler[1]), p.input_tc, accel[1],
                                                            self.euler_rate_target[1], dt)
            self.euler_rate_target[2] = input_shaping_ang_vel(self.euler_rate_target[2], yaw_rate, accel[2], dt)
            self._finish_ff(euler)
        else:
            self.attitude_target = quat_from_euler(roll, pitch, euler[2] + yaw_rate * dt)
            self.euler_rate_target[:] = 0.0
            self.ang_vel_target[:] = 0.0
        self._run_quat(attitude, gyro, dt)

    def input_euler_angle_roll_pitch_yaw(self, roll: float, pitch: float, yaw: float, slew_yaw: bool, attitude,
                                         gyro, dt: float) -> None:
        """``input_euler_angle_roll_pitch_yaw``: roll, pitch and yaw angles (rad); yaw rate limited to
        ``ATC_SLEW_YAW`` when ``slew_yaw``."""
        euler = self._update_attitude_target(dt)
        p = self.params
        if p.rate_ff_enabled:
            accel = euler_accel_limit(euler[:2], self._accel_max())
            for k, want in enumerate((roll, pitch, yaw)):
                self.euler_rate_target[k] = input_shaping_angle(wrap_pi(want - euler[k]), p.input_tc, accel[k],
                                                                self.euler_rate_target[k], dt)
            if slew_yaw:
                self.euler_rate_target[2] = min(max(self.euler_rate_target[2], -p.slew_yaw), p.slew_yaw)
            self._finish_ff(euler)
        else:
            new_yaw = yaw
            if slew_yaw:
                step = min(max(wrap_pi(yaw - euler[2]), -p.slew_yaw * dt), p.slew_yaw * dt)
                new_yaw = wrap_pi(euler[2] + step)
            self.attitude_target = quat_from_euler(roll, pitch, new_yaw)
            self.euler_rate_target[:] = 0.0
            self.ang_vel_target[:] = 0.0
        self._run_quat(attitude, gyro, dt)

    def input_rate_bf_roll_pitch_yaw(self, rates, attitude, gyro, dt: float) -> None:
        """``input_rate_bf_roll_pitch_yaw``: body rates (rad/s), acceleration limited (ACRO)."""
        euler = self._update_attitude_target(dt)
        if self.params.rate_ff_enabled:
            acc = self._accel_max()
            for k in range(3):
                self.ang_vel_target[k] = input_shaping_ang_vel(self.ang_vel_target[k], rates[k], acc[k], dt)
            self.euler_rate_target = ang_vel_to_euler_rate(euler[:2], self.ang_vel_target)
        else:
            self.attitude_target = _normalise(quat_mul(self.attitude_target, quat_from_axis_angle(np.asarray(rates)
                                                                                                 * dt)))
            self.euler_rate_target[:] = 0.0
            self.ang_vel_target[:] = 0.0
        self._run_quat(attitude, gyro, dt)

    def input_target(self, attitude_target, ang_vel_target, attitude, gyro, dt: float) -> np.ndarray:
        """Set the already-shaped target attitude and its angular velocity, run the angle layer.

        For replays of a log's targets: ATT's DesRoll/DesPitch/DesYaw are ``_attitude_target`` (the *shaped*
        target, ``get_att_target_euler_cd``), and its rate is the feed-forward ``_ang_vel_target``.

        Parameters
        ----------
        attitude_target : array (4,)
            Target quaternion (body to NED).
        ang_vel_target : array (3,)
            Target angular velocity, target body frame (rad/s).
        attitude, gyro : array (4,), array (3,)
            The vehicle's quaternion and body rates (rad/s).
        dt : float
            Tick (s).

        Returns
        -------
        ndarray (3,)
            The body rate demand of the rate PIDs (rad/s; the RATE log's RDes/PDes/YDes in deg/s).
        """
        self.attitude_target = _normalise(attitude_target)
        self.ang_vel_target = np.array(ang_vel_target, dtype=float)
        self.euler_rate_target = ang_vel_to_euler_rate(quat_to_euler(self.attitude_target)[:2], self.ang_vel_target)
        self._run_quat(attitude, gyro, dt)
        return self.rate_target.copy()

    # -- the angle P layer
    def _angle_p(self, error) -> np.ndarray:
        """``update_ang_vel_target_from_att_error``: angle error (rad) -> body rate demand (rad/s)."""
        p, acc = self.params.angle_p, self._accel_max()
        out = np.zeros(3)
        limits = ((ACCEL_RP_CONTROLLER_MIN, ACCEL_RP_CONTROLLER_MAX),) * 2 + ((ACCEL_Y_CONTROLLER_MIN,
                                                                               ACCEL_Y_CONTROLLER_MAX),)
        for k in range(3):
            if acc[k] != 0.0:
                lo, hi = limits[k]
                out[k] = sqrt_controller(error[k], p[k], min(max(acc[k] / 2.0, lo), hi), self._dt)
            else:
                out[k] = p[k] * error[k]
        return out

    def _run_quat(self, attitude, gyro, dt: float) -> None:
        """``attitude_controller_run_quat``: the rate demand (``_ang_vel_body``) from the target and the body."""
        self._dt = dt
        body = _normalise(attitude)
        yaw_gains = self.rate_pids[2].gains
        heading_accel = min(max(self._accel_max()[2] / 2.0, ACCEL_Y_CONTROLLER_MIN), ACCEL_Y_CONTROLLER_MAX)
        yaw_error_max = math.inf
        if yaw_gains.p != 0.0 and self.params.angle_p[2] != 0.0:
            yaw_error_max = min(inv_sqrt_controller(1.0 / yaw_gains.p, self.params.angle_p[2], heading_accel),
                                YAW_MAX_ERROR_ANGLE)
        error, self.attitude_target, self.thrust_error_angle = thrust_heading_rotation_angles(
            self.attitude_target, body, yaw_error_max)
        rate = ang_vel_limit(self._angle_p(error), self.params.rate_max)
        ff = quat_rotate(quat_mul(quat_inv(body), self.attitude_target), self.ang_vel_target)
        self.feedforward_scalar = 1.0
        if self.thrust_error_angle > 2.0 * THRUST_ERROR_ANGLE:
            rate[2] = gyro[2]
        elif self.thrust_error_angle > THRUST_ERROR_ANGLE:
            s = 1.0 - (self.thrust_error_angle - THRUST_ERROR_ANGLE) / THRUST_ERROR_ANGLE
            self.feedforward_scalar = s
            rate[0] += ff[0] * s
            rate[1] += ff[1] * s
            rate[2] += ff[2]
            rate[2] = gyro[2] * (1.0 - s) + rate[2] * s
        else:
            rate += ff
        self.rate_target = rate

    _dt = 0.0025

    # -- the rate layer
    def rate_controller_run(self, gyro, dt: float, limits=(False, False, False)) -> np.ndarray:
        """``AC_AttitudeControl_Sub::rate_controller_run``: roll, pitch, yaw mixer inputs (normalised).

        Parameters
        ----------
        gyro : array (3,)
            Body rates (rad/s).
        dt : float
            Tick (s).
        limits : 3 bools
            ``_motors.limit.roll/pitch/yaw`` (saturation: integrators only shrink).

        Returns
        -------
        ndarray (3,)
            ``update_all(...) + get_ff()`` per axis (``set_roll`` + ``set_roll_ff``).
        """
        out = np.empty(3)
        for k, pid in enumerate(self.rate_pids):
            pid.update_all(float(self.rate_target[k]), float(gyro[k]), dt, bool(limits[k]))
            out[k] = pid.terms.output
        return out

    @property
    def terms(self) -> tuple[PIDTerms, PIDTerms, PIDTerms]:
        """The last PIDR, PIDP, PIDY terms."""
        return tuple(pid.terms for pid in self.rate_pids)


__all__ = ["AttitudeController", "ang_vel_to_euler_rate", "euler_rate_to_ang_vel", "input_shaping_angle",
           "input_shaping_ang_vel", "quat_from_euler", "quat_to_euler", "thrust_heading_rotation_angles", "wrap_pi"]
