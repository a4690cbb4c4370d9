"""ArduPilot's ``AC_PID`` / ``AC_PID_Basic`` and the sqrt controller, step for step (ArduSub 4.1-4.5).

Sources (ArduPilot): ``libraries/AC_PID/AC_PID.cpp`` (``update_all``, ``update_i``, ``get_ff``,
``set_integrator``, ``relax_integrator``), ``libraries/AC_PID/AC_PID_Basic.cpp`` (``update_all`` with the
directional integrator limits, used for ``PSC_VELZ``), ``libraries/AP_Math/control.cpp`` (``sqrt_controller``,
``inv_sqrt_controller``) and ``libraries/Filter/LowPassFilter.cpp`` / ``AP_Math.cpp`` (``calc_lowpass_alpha_dt``).

``AC_PID.update_all(target, measurement, limit)`` per loop tick ``dt``::

    first call (or after reset_filter):  T = target; E = T - measurement; Dv = 0
    otherwise:  T += aT (target - T);  E_last = E;  E += aE ((T - measurement) - E)
                Dv += aD ((E - E_last) / dt - Dv)
    I: if ki != 0 and (not limit or I shrinks):  I = clamp(I + ki E dt, -IMAX, IMAX)   (ki == 0 -> I = 0)
    P = kp E,  D = kd Dv,  [4.5: |P + D| <= PDMX,  D_FF = kdff dT/dt]
    return P + I + D (+ D_FF);   FF = kff T is read separately (get_ff) and added by the motors (roll_in_ff)

with ``a = dt / (dt + 1 / (2 pi f))`` (``a = 1`` for f = 0). The state may hold one value per row of a batch:
``target`` and ``measurement`` given as arrays (N,) step N independent loops at once (the closed-loop replay
windows of :mod:`udrobot_ctrl.autopilot.feedback`); scalars give floats as before.

The D term acts on the (filtered) *error*, so a
target step kicks it. ``SMAX`` (slew limiter, ``Dmod``) is Sub's default 0 and not emulated: ``Dmod`` stays 1
(the Seattle dive logs Dmod = 1 throughout). Version notes: ``D_FF`` appeared in 4.3, ``PDMX`` in 4.5, the
notch filters (``NTF``/``NEF``, 4.5) are off by default and not emulated.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.ardusub.params import PIDGains


def _clip(value, bound: float):
    """``value`` clamped to [-bound, bound]: a float for a scalar, an array for an array (one loop per row)."""
    if isinstance(value, float):  # the scalar loop's fast path (numpy's call overhead is most of a tick)
        return -bound if value < -bound else (bound if value > bound else value)
    out = np.clip(value, -bound, bound)
    return float(out) if np.ndim(out) == 0 else out


def _finite(*values) -> bool:
    """Every value finite (arrays: every element)."""
    return all(math.isfinite(v) if isinstance(v, float) else bool(np.all(np.isfinite(v))) for v in values)


def lowpass_alpha(dt: float, cutoff_hz: float) -> float:
    """``calc_lowpass_alpha_dt``: the first-order filter's blend factor for a step ``dt`` (s) at ``cutoff_hz``.

    Returns 1 (no filtering) when ``dt <= 0`` or ``cutoff_hz <= 0``.
    """
    if dt <= 0.0 or cutoff_hz <= 0.0:
        return 1.0
    rc = 1.0 / (2.0 * math.pi * cutoff_hz)
    return dt / (dt + rc)


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """``sqrt_controller`` (``AP_Math/control.cpp``): P near zero, square root beyond ``second_ord_lim / p^2``.

    Parameters
    ----------
    error : float
        Error (e.g. rad or m).
    p : float
        Proportional gain (1/s).
    second_ord_lim : float
        Second-order limit (e.g. rad/s^2 or m/s^2); <= 0 gives a pure P controller.
    dt : float
        Time step (s); the correction is limited to ``|error| / dt`` so one step cannot overshoot.

    Returns
    -------
    float
        The correction rate (error units per s).
    """
    if second_ord_lim <= 0.0:
        correction = error * p
    elif p == 0.0:
        correction = math.copysign(math.sqrt(2.0 * second_ord_lim * abs(error)), error) if error else 0.0
    else:
        linear_dist = second_ord_lim / (p * p)
        if error > linear_dist:
            correction = math.sqrt(max(2.0 * second_ord_lim * (error - linear_dist / 2.0), 0.0))
        elif error < -linear_dist:
            correction = -math.sqrt(max(2.0 * second_ord_lim * (-error - linear_dist / 2.0), 0.0))
        else:
            correction = error * p
    if dt > 0.0:
        bound = abs(error) / dt
        return min(max(correction, -bound), bound)
    return correction


def inv_sqrt_controller(output: float, p: float, d_max: float) -> float:
    """``inv_sqrt_controller`` (``AP_Math/control.cpp``): the error that makes :func:`sqrt_controller` give ``output``.

    Used by ``AC_AttitudeControl::thrust_heading_rotation_angles`` to cap the yaw error.
    """
    if d_max > 0.0 and p == 0.0:
        return output * output / (2.0 * d_max)
    if d_max <= 0.0 and p != 0.0:
        return output / p
    if d_max <= 0.0 and p == 0.0:
        return 0.0
    linear_velocity = d_max / p
    if abs(output) < linear_velocity:
        return output / p
    linear_dist = d_max / (p * p)
    stopping = linear_dist * 0.5 + output * output / (2.0 * d_max)
    return stopping if output > 0 else -stopping


@dataclass(frozen=True)
class PIDTerms:
    """One update's terms, as ``AP_PIDInfo`` and the PIDR/PIDP/PIDY/PIDA log messages record them.

    Attributes
    ----------
    target, actual, error : float
        Filtered target (Tar), measurement (Act) and filtered error (Err), loop units.
    p, i, d, ff, d_ff : float
        The terms (output units): P, I (the integrator), D, FF (``kff * target``) and DFF.
    dmod : float
        Slew-limiter gain modifier (1: not limiting).
    limit : bool
        The output-saturation flag passed in (integrator may only shrink).
    """

    target: float
    actual: float
    error: float
    p: float
    i: float
    d: float
    ff: float
    d_ff: float = 0.0
    dmod: float = 1.0
    limit: bool = False

    @property
    def output(self) -> float:
        """P + I + D + D_FF + FF: what reaches the mixer (``_roll_in + _roll_in_ff``)."""
        return self.p + self.i + self.d + self.d_ff + self.ff


class ACPID:
    """``AC_PID`` with its filter and integrator state.

    Parameters
    ----------
    gains : PIDGains
        Gains and filter cut-offs in the loop's (SI) units.
    """

    def __init__(self, gains: PIDGains):
        self.gains = gains
        self.reset()

    def reset(self) -> None:
        """Zero the integrator and restart the filters from the next input (``reset_I`` + ``reset_filter``)."""
        self.integrator = 0.0
        self._target = 0.0
        self._error = 0.0
        self._derivative = 0.0
        self._target_derivative = 0.0
        self._reset_filter = True
        self.terms = PIDTerms(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def reset_filter(self) -> None:
        """``AC_PID::reset_filter``: the next update restarts the target, error and derivative filters."""
        self._reset_filter = True

    def reset_i(self) -> None:
        """``AC_PID::reset_I``: zero the integrator."""
        self.integrator = 0.0

    def set_integrator(self, value: float) -> None:
        """``AC_PID::set_integrator(integrator)``: set the I term (clamped to IMAX), output units."""
        self.integrator = _clip(value, self.gains.imax)

    def relax_integrator(self, value: float, dt: float, time_constant: float) -> None:
        """``AC_PID::relax_integrator``: move the I term towards ``value`` with a first-order ``time_constant`` (s)."""
        value = _clip(value, self.gains.imax)
        self.integrator += (value - self.integrator) * (dt / (dt + time_constant))

    def _update_i(self, dt: float, limit: bool) -> None:
        g = self.gains
        if g.i != 0.0 and dt > 0.0:
            if not limit:
                self.integrator = _clip(self.integrator + self._error * g.i * dt, g.imax)
            else:  # saturated: the integrator may only shrink
                shrinking = np.sign(self.integrator) * np.sign(self._error) < 0
                grown = _clip(self.integrator + self._error * g.i * dt, g.imax)
                out = np.where(shrinking, grown, self.integrator)
                self.integrator = float(out) if np.ndim(out) == 0 else out
        else:
            self.integrator = 0.0 * self._error

    def update_all(self, target: float, measurement: float, dt: float, limit: bool = False) -> float:
        """One tick of ``AC_PID::update_all``; returns P + I + D (+ D_FF), FF excluded (see :attr:`terms`).

        Parameters
        ----------
        target, measurement : float
            Loop input (e.g. rad/s, m/s^2).
        dt : float
            Tick (s).
        limit : bool
            The actuator is saturated in this axis (``_motors.limit.roll`` etc.): the integrator may only shrink.

        Returns
        -------
        float
            P + I + D + D_FF (output units). :attr:`terms` holds the per-term values and FF.
        """
        g = self.gains
        if not _finite(target, measurement):
            return 0.0
        if self._reset_filter:
            self._reset_filter = False
            self._target = target
            self._error = target - measurement
            self._derivative = 0.0 * self._error
            self._target_derivative = 0.0 * self._error
        else:
            error_last, target_last = self._error, self._target
            self._target += lowpass_alpha(dt, g.filt_t_hz) * (target - self._target)
            self._error += lowpass_alpha(dt, g.filt_e_hz) * ((self._target - measurement) - self._error)
            if dt > 0.0:
                derivative = (self._error - error_last) / dt
                self._derivative += lowpass_alpha(dt, g.filt_d_hz) * (derivative - self._derivative)
                self._target_derivative = (self._target - target_last) / dt
        self._update_i(dt, limit)
        p_out = self._error * g.p
        d_out = self._derivative * g.d
        if g.pd_max > 0.0:  # AC_PID 4.5: limit P + D, scaling both
            scale = g.pd_max / np.maximum(np.abs(p_out + d_out), g.pd_max)
            p_out, d_out = (p_out * scale, d_out * scale) if np.ndim(scale) else (p_out * float(scale),
                                                                                  d_out * float(scale))
        d_ff = self._target_derivative * g.d_ff
        self.terms = PIDTerms(target=self._target, actual=measurement, error=self._error, p=p_out,
                              i=self.integrator, d=d_out, ff=self._target * g.ff, d_ff=d_ff, limit=limit)
        return p_out + self.integrator + d_out + d_ff

    @property
    def ff(self) -> float:
        """``AC_PID::get_ff``: ``kff * filtered target``."""
        return self._target * self.gains.ff


class ACPIDBasic(ACPID):
    """``AC_PID_Basic`` (``PSC_VELZ``): no target filter, FF inside the output, one-sided integrator limits.

    ``update_all(target, measurement, dt, limit_neg, limit_pos)``: the integrator does not grow positive while
    ``limit_pos`` (or negative while ``limit_neg``) is set (``AC_PID_Basic::update_i``).
    """

    @property
    def error(self) -> float:
        """The filtered error of the last update (``get_error``, input units)."""
        return float(self._error)

    def update_all(self, target: float, measurement: float, dt: float, limit: bool = False,
                   limit_neg: bool = False, limit_pos: bool = False) -> float:
        """One tick of ``AC_PID_Basic::update_all``; returns P + I + D + FF (output units)."""
        g = self.gains
        if not (math.isfinite(target) and math.isfinite(measurement)):
            return 0.0
        if self._reset_filter:
            self._reset_filter = False
            self._target = target
            self._error = target - measurement
            self._derivative = 0.0
        else:
            error_last = self._error
            self._target = target
            self._error += lowpass_alpha(dt, g.filt_e_hz) * ((target - measurement) - self._error)
            if dt > 0.0:
                derivative = (self._error - error_last) / dt
                self._derivative += lowpass_alpha(dt, g.filt_d_hz) * (derivative - self._derivative)
        if g.i != 0.0:
            if not ((self.integrator > 0 and limit_pos) or (self.integrator < 0 and limit_neg)):
                self.integrator += self._error * g.i * dt
                self.integrator = min(max(self.integrator, -g.imax), g.imax)
        else:
            self.integrator = 0.0
        p_out, d_out, ff = self._error * g.p, self._derivative * g.d, target * g.ff
        self.terms = PIDTerms(target=target, actual=measurement, error=self._error, p=p_out, i=self.integrator,
                              d=d_out, ff=ff)
        return p_out + self.integrator + d_out + ff


def integrator_after(gains: PIDGains, integrator: float, errors, dt: float, limit=False) -> float:
    """The I term after integrating ``errors`` (one per tick ``dt``) from ``integrator`` (``AC_PID::update_i``).

    A helper for checking logged I terms between log samples; ``limit`` as in :meth:`ACPID.update_all`.
    """
    for e in errors:
        if gains.i == 0.0:
            return 0.0
        if not limit or (integrator > 0 and e < 0) or (integrator < 0 and e > 0):
            integrator = min(max(integrator + e * gains.i * dt, -gains.imax), gains.imax)
    return integrator


__all__ = ["ACPID", "ACPIDBasic", "PIDGains", "PIDTerms", "integrator_after", "inv_sqrt_controller",
           "lowpass_alpha", "sqrt_controller"]
