"""Stability margins of ArduSub's loops from their frequency response, with the filters and delays the vehicle has.

One single-input loop per axis, linear about hover, in SI:

* **rate loops** (roll, pitch, yaw), broken at the mixer input the rate PID drives::

      L_rate = PID(s) * H_gyro(s) * G_rate(s) * M(s) * exp(-s T_out)

  ``PID`` is ``AC_PID``'s feedback path: the error filter ``FLTE`` (first order) times ``P + I/s + D s F_D(s)``
  with the derivative filter ``FLTD`` (``libraries/AC_PID/AC_PID.cpp`` ``update_all``; the target filter ``FLTT``
  acts on the target only, outside the loop). ``H_gyro`` is the IMU's gyro low-pass ``INS_GYRO_FILTER``
  (``AP_InertialSensor``: a second-order ``LowPassFilter2p``, Butterworth; 20 Hz by default, ``DEFAULT_GYRO_FILTER``
  in ``libraries/AP_InertialSensor/AP_InertialSensor.cpp``). ``G_rate`` is the body rate per unit mixer input:
  the model's rigid-body axis (inertia with added mass, the damping's slope at hover, the hydrostatic stiffness of
  roll and pitch) from a numerical Jacobian of :func:`udrobot_ctrl.dynamics.plant.state_derivative` at hover,
  times the torque per unit input of ArduSub's mixer (:func:`.motors.mix`, :func:`.motors.to_pwm`) and the T200
  curve's small-signal slope (:func:`udrobot_ctrl.dynamics.thrusters.pwm_to_thrust`, secant over +-100 us about the
  thruster's trim: past the dead band, *estimated*). ``M`` is the motor/ESC first-order lag (:class:`LoopTiming`).
  ``T_out`` is the loop's output delay: one tick of computation plus half a tick of zero-order hold.
* **angle loops**, broken at the rate target: ``L_ang = ATC_ANG_P / s * T_rate(s) * exp(-s T_att)`` with the rate
  loop closed (``T_rate = F_T PID G M e^{-sT} / (1 + L_rate)``, ``F_T`` the ``FLTT`` target filter) and one tick
  of attitude latency ``T_att`` (the EKF's output predictor propagates the attitude at the IMU rate). The
  sqrt controller is linear near zero error: its P is ``ATC_ANG_*_P``. ``ATC_INPUT_TC`` shapes the command
  before the loop (:func:`command_bandwidth`), not the feedback: it does not change the margins.
* **depth**, broken at the throttle (``AC_PosControl``'s z cascade, :mod:`.depth`)::

      L_depth = C_acc(s) [H_acc s^2 + C_vel(s) (s + P_pos) e^{-s T_z}] G_z(s) F_thr(s) M(s) e^{-s T_out}

  with ``C_acc`` = ``PSC_ACCZ`` (its ``FLTE`` 20 Hz, SI gains of :mod:`.params`), ``C_vel`` = ``PSC_VELZ`` (``FLTE``
  5 Hz), ``P_pos`` = ``PSC_POSZ_P``, ``H_acc`` the accelerometer's ``INS_ACCEL_FILTER`` (20 Hz, second order),
  ``F_thr`` the motors' throttle low-pass the position controller sets (``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ`` 2 Hz),
  ``G_z`` the heave axis (mass with added mass, damping slope at hover) and ``T_z`` the depth/velocity estimate's
  latency (:class:`LoopTiming`).

Margins (:func:`loop_margins`): the phase margin is the smallest ``180 deg - |arg L|`` (arg wrapped to +-180 deg)
over the gain crossovers (``|L| = 1``); the gain margin the smallest ``|20 log10 |L||`` over the phase crossovers
(``arg L = -180 deg``), so a loop that is conditionally stable (the depth cascade's phase passes -180 deg at low
frequency where ``|L| > 1``) is held to 6 dB of gain *reduction* too. The frequency response uses the delays
exactly; whether the closed loop is stable at all is decided on the rational model (second-order Pade delays) by its
poles. Cross-coupling between axes is neglected (each loop alone, the others open): the BlueROV2 frames are near
symmetric and the step flights (:mod:`.design`) fly the coupled plant.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from udrobot_ctrl.ardusub.params import ArduSubParameters, PIDGains
from udrobot_ctrl.autopilot.motors import MIXER_INPUTS, Frame, MotorParameters, mix, to_pwm
from udrobot_ctrl.dynamics.plant import generalized_forces, plant_parameters, state_derivative
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.vehicle import Vehicle

#: INS_GYRO_FILTER / INS_ACCEL_FILTER defaults (AP_InertialSensor.cpp DEFAULT_GYRO_FILTER / DEFAULT_ACCEL_FILTER, Hz)
GYRO_FILTER_DEFAULT_HZ, ACCEL_FILTER_DEFAULT_HZ = 20.0, 20.0
#: motor/ESC time constant when the model has no thruster_lag effect (s), *assumed*: no published T200 step
#: response exists; the one measured figure found, 110 +- 10 ms from the command to visible motion for a T200 on a
#: BasicESC stepped 1500 -> 1700 us from rest (Blue Robotics forum, "Response time and minimum rotation speed for
#: T200 with Basic ESC", thread 11112), includes the sensorless start from standstill; a spinning motor answers
#: faster, so half of it is taken as the first-order lag of the running motor
MOTOR_TAU_ASSUMED_S = 0.055
#: the depth and climb-rate estimate's latency (s), *assumed*: the Bar30 is read at 50 Hz by ArduSub's barometer
#: driver (one 20 ms sample) and the EKF fuses it with a delay of the same order (EK3_HGT_DELAY default 60 ms is
#: compensated by the output predictor); one sample period is taken
DEPTH_LATENCY_ASSUMED_S = 0.02
#: the T200 small-signal slope is the secant over this PWM excursion about the trim (us), *estimated*: past the
#: +-25 us dead band and within the range a loop's small signal moves a thruster
THRUST_SLOPE_EXCURSION_US = 100.0
#: the required margins (the issue's criterion; classical textbook robustness bounds, e.g. Skogestad and
#: Postlethwaite, Multivariable Feedback Control, 2nd ed., sec. 2.4.3: GM > 2 (6 dB) and PM > 30-60 deg)
PHASE_MARGIN_MIN_DEG, GAIN_MARGIN_MIN_DB = 45.0, 6.0

AXIS_INDEX = {"roll": (3, 9), "pitch": (4, 10), "yaw": (5, 11), "depth": (2, 8)}  # (position state, rate state)
WRENCH_INDEX = {"roll": 3, "pitch": 4, "yaw": 5, "depth": 2}


@dataclass(frozen=True)
class LoopTiming:
    """The loop's filters and delays besides the PID gains (SI).

    Attributes
    ----------
    loop_rate_hz : float
        ``SCHED_LOOP_RATE`` (ArduSub's 400 Hz by default).
    gyro_filter_hz, accel_filter_hz : float
        ``INS_GYRO_FILTER``, ``INS_ACCEL_FILTER`` (Hz; 0 = off).
    motor_tau_s : float
        The motor/ESC first-order lag (s).
    motor_tau_source : str
        Where it comes from (the model's ``thruster_lag`` effect, or assumed).
    depth_latency_s : float
        Latency of the depth and climb-rate estimates (s).
    """

    loop_rate_hz: float = 400.0
    gyro_filter_hz: float = GYRO_FILTER_DEFAULT_HZ
    accel_filter_hz: float = ACCEL_FILTER_DEFAULT_HZ
    motor_tau_s: float = MOTOR_TAU_ASSUMED_S
    motor_tau_source: str = "assumed (MOTOR_TAU_ASSUMED_S)"
    depth_latency_s: float = DEPTH_LATENCY_ASSUMED_S

    @property
    def output_delay_s(self) -> float:
        """One tick of computation and half a tick of zero-order hold (s)."""
        return 1.5 / self.loop_rate_hz

    @property
    def attitude_latency_s(self) -> float:
        """One tick (s)."""
        return 1.0 / self.loop_rate_hz

    @classmethod
    def of(cls, vehicle: Vehicle, log_params: Mapping | None = None, loop_rate_hz: float | None = None) -> LoopTiming:
        """The timing of ``vehicle`` with its log's ``INS_GYRO_FILTER``, ``INS_ACCEL_FILTER``, ``SCHED_LOOP_RATE``
        (ArduSub's defaults when absent) and its model's ``thruster_lag`` (the assumed lag when it has none)."""
        log_params = log_params or {}

        def get(name, default):
            v = log_params.get(name)
            return float(v) if v is not None and math.isfinite(float(v)) else default

        tau, source = MOTOR_TAU_ASSUMED_S, "assumed (MOTOR_TAU_ASSUMED_S: half the measured 110 ms start-up)"
        for e in vehicle.effects or ():
            if e.name == "thruster_lag" and "T_lag_s" in e.params:
                tau = float(e.params["T_lag_s"])
                source = f"the model's thruster_lag effect (T_lag_s {tau:g})"
        rate = loop_rate_hz if loop_rate_hz is not None else get("SCHED_LOOP_RATE", 400.0)
        return cls(loop_rate_hz=float(rate), gyro_filter_hz=get("INS_GYRO_FILTER", GYRO_FILTER_DEFAULT_HZ),
                   accel_filter_hz=get("INS_ACCEL_FILTER", ACCEL_FILTER_DEFAULT_HZ), motor_tau_s=tau,
                   motor_tau_source=source)

    def ideal(self) -> LoopTiming:
        """The same loop without filters, motor lag or delays (what the design's old loop model had)."""
        return replace(self, gyro_filter_hz=0.0, accel_filter_hz=0.0, motor_tau_s=0.0, depth_latency_s=0.0,
                       loop_rate_hz=1e9, motor_tau_source="none (ideal loop)")


@dataclass(frozen=True)
class AxisPlant:
    """One axis of the model about hover: ``(J s^2 + d s + k) y = b u`` for the mixer input ``u``.

    Attributes
    ----------
    loop : str
    inertia : float
        kg or kg m^2 (with added mass and the coupling the mass matrix puts on this axis' diagonal).
    damping : float
        Slope of the damping at hover (N s/m or N m s/rad); 0 for a Morison model (quadratic only).
    stiffness : float
        Hydrostatic stiffness (N m/rad for roll and pitch, 0 for yaw and depth).
    gain : float
        Force or torque per unit mixer input (N or N m); for depth per unit ArduSub throttle (0..1), up positive
        and returned positive (the loop's sign is its own).
    """

    loop: str
    inertia: float
    damping: float
    stiffness: float
    gain: float


def axis_plant(vehicle: Vehicle, fr: Frame, loop: str, motors: MotorParameters | None = None,
               depth: float = 2.0) -> AxisPlant:
    """The axis of ``loop`` about hover at ``depth`` (m), from the plant's own equations (see the module notes)."""
    p = plant_parameters(vehicle)
    x0 = np.zeros(12)
    x0[2] = depth
    tau0 = np.asarray(generalized_forces(x0, p), float)
    i_pos, i_rate = AXIS_INDEX[loop]
    w = WRENCH_INDEX[loop]
    h = 1e-4
    f0 = np.asarray(state_derivative(x0, tau0, p), float)

    def d(k_state=None, k_wrench=None, step=h):
        x, tau = x0.copy(), tau0.copy()
        if k_state is not None:
            x[k_state] += step
        if k_wrench is not None:
            tau[k_wrench] += step
        return (np.asarray(state_derivative(x, tau, p), float) - f0)[i_rate] / step

    b = d(k_wrench=w, step=1.0)  # acceleration per N (or N m): 1 / inertia
    # the damping's slope: +-0.01 m/s or rad/s central difference (zero for a Morison model at rest)
    x_p, x_m = x0.copy(), x0.copy()
    x_p[i_rate] += 0.01
    x_m[i_rate] -= 0.01
    slope = (np.asarray(state_derivative(x_p, tau0, p))[i_rate]
             - np.asarray(state_derivative(x_m, tau0, p))[i_rate]) / 0.02
    stiff = d(k_state=i_pos) if loop in ("roll", "pitch") else 0.0
    inertia = 1.0 / b
    motors = motors or MotorParameters.default(fr.n_motors)
    motors = replace(motors, directions=(1,) * fr.n_motors)
    j = MIXER_INPUTS.index("throttle" if loop == "depth" else loop)
    # trim command of each thruster (the vertical ones hold the net buoyancy) and the wrench per unit input
    trim = np.linalg.lstsq(p.T, tau0, rcond=None)[0]
    pwm_trim = _pwm_of_thrust(trim, p.supply_voltage)
    lo = pwm_to_thrust(pwm_trim - THRUST_SLOPE_EXCURSION_US, p.supply_voltage)
    hi = pwm_to_thrust(pwm_trim + THRUST_SLOPE_EXCURSION_US, p.supply_voltage)
    slope_n_per_us = (np.asarray(hi) - np.asarray(lo)) / (2.0 * THRUST_SLOPE_EXCURSION_US)
    e = np.zeros(6)
    e[j] = 0.1
    dpwm = (to_pwm(mix(fr, e, motors), motors, integer=False)
            - to_pwm(mix(fr, -e, motors), motors, integer=False)) / 0.2
    wrench = p.T @ (slope_n_per_us * dpwm)
    gain = float(wrench[w])
    if loop == "depth":
        gain = -2.0 * gain  # ArduSub throttle (0..1) -> bidirectional (x 2); up (-z) positive
    return AxisPlant(loop=loop, inertia=float(inertia), damping=float(-slope * inertia),
                     stiffness=float(-stiff * inertia), gain=abs(gain) if loop == "depth" else gain)


def _pwm_of_thrust(thrust, voltage) -> np.ndarray:
    """PWM (us) giving each thrust on the T200 curve (bisection on the monotone curve)."""
    thrust = np.asarray(thrust, float)
    lo, hi = np.full(thrust.shape, 1100.0), np.full(thrust.shape, 1900.0)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        above = np.asarray(pwm_to_thrust(mid, voltage)) > thrust
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    return 0.5 * (lo + hi)


# ------------------------------------------------------------------------------------------------ blocks
def _lowpass1(s, hz):
    return np.ones_like(s) if hz <= 0 else 1.0 / (1.0 + s / (2 * math.pi * hz))


def _lowpass2(s, hz):
    if hz <= 0:
        return np.ones_like(s)
    w = 2 * math.pi * hz
    return w * w / (s * s + math.sqrt(2.0) * w * s + w * w)


def _pid(s, g: PIDGains):
    """AC_PID's feedback path: FLTE x (P + I/s + D s FLTD)."""
    return _lowpass1(s, g.filt_e_hz) * (g.p + g.i / s + g.d * s * _lowpass1(s, g.filt_d_hz))


def _motor(s, timing: LoopTiming):
    lag = 1.0 / (1.0 + timing.motor_tau_s * s)
    return lag * np.exp(-s * timing.output_delay_s)


def _plant(s, ap: AxisPlant):
    """Output rate (rad/s or m/s) per unit mixer input."""
    return ap.gain * s / (ap.inertia * s * s + ap.damping * s + ap.stiffness)


def rate_gains(params: ArduSubParameters, loop: str) -> PIDGains:
    return params.attitude.rate_pids()[("roll", "pitch", "yaw").index(loop)]


def open_loop(s, loop: str, params: ArduSubParameters, ap: AxisPlant, timing: LoopTiming, which: str = "outer"):
    """The loop transfer L(s) at the complex frequencies ``s`` (1/s): ``which`` is ``rate`` (the rate loop of an
    attitude axis), ``outer`` (its angle loop with the rate loop closed; depth: the whole cascade)."""
    s = np.asarray(s, complex)
    if loop == "depth":
        dp = params.depth
        c_acc = _pid(s, dp.accel)
        c_vel = _pid(s, dp.vel)
        meas = (_lowpass2(s, timing.accel_filter_hz) * s * s
                + c_vel * (s + dp.pos_p) * np.exp(-s * timing.depth_latency_s))
        g_pos = _plant(s, ap) / s
        return c_acc * meas * g_pos * _lowpass1(s, dp.throttle_cutoff_hz) * _motor(s, timing)
    g = rate_gains(params, loop)
    forward = _pid(s, g) * _plant(s, ap) * _motor(s, timing)
    l_rate = forward * _lowpass2(s, timing.gyro_filter_hz)
    if which == "rate":
        return l_rate
    t_rate = _lowpass1(s, g.filt_t_hz) * (g.p + g.i / s + g.d * s * _lowpass1(s, g.filt_d_hz)) * _plant(s, ap) \
        * _motor(s, timing) / (1.0 + l_rate)
    k = ("roll", "pitch", "yaw").index(loop)
    return params.attitude.angle_p[k] / s * t_rate * np.exp(-s * timing.attitude_latency_s)


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop.

    Attributes
    ----------
    loop : str
        ``roll``, ``pitch``, ``yaw``, ``depth`` and for the attitude axes also ``roll_rate`` ...
    model : str
    phase_margin_deg : float
        Smallest over the gain crossovers of ``180 - |arg L|`` (arg wrapped to +-180 deg: the smallest phase lag
        or lead that puts L on -1); inf when ``|L|`` never crosses 1.
    gain_margin_db : float
        Smallest ``|20 log10 |L||`` over the phase crossovers (inf: none).
    crossover_rad_s : float
        The highest gain-crossover frequency (rad/s; nan: none): the loop's bandwidth.
    stable : bool
        The closed loop's poles (rational model) are all in the left half plane.
    """

    loop: str
    model: str
    phase_margin_deg: float
    gain_margin_db: float
    crossover_rad_s: float
    stable: bool

    def meets(self, pm_min: float = PHASE_MARGIN_MIN_DEG, gm_min: float = GAIN_MARGIN_MIN_DB) -> bool:
        return bool(self.stable and self.phase_margin_deg >= pm_min and self.gain_margin_db >= gm_min)

    def summary(self) -> dict:
        def num(v):
            return None if not math.isfinite(v) else round(float(v), 2)
        return {"phase_margin_deg": num(self.phase_margin_deg), "gain_margin_db": num(self.gain_margin_db),
                "crossover_rad_s": num(self.crossover_rad_s), "stable": self.stable}


def _grid(timing: LoopTiming) -> np.ndarray:
    top = min(math.pi * timing.loop_rate_hz, 1e4)
    return np.logspace(-3, math.log10(top), 4000)


def margins_from_response(w: np.ndarray, L: np.ndarray) -> tuple:
    """(phase margin deg, gain margin dB, highest crossover rad/s) of a frequency response ``L`` on grid ``w``."""
    mag = np.abs(L)
    phase = np.unwrap(np.angle(L))
    pm, gm, wc = math.inf, math.inf, math.nan
    db = 20 * np.log10(np.maximum(mag, 1e-300))
    for i in np.nonzero(np.diff(np.sign(db)) != 0)[0]:
        f = db[i] / (db[i] - db[i + 1])
        ph = phase[i] + f * (phase[i + 1] - phase[i])
        wrapped = ((math.degrees(ph) + 180.0) % 360.0) - 180.0  # arg L in [-180, 180)
        margin = 180.0 - abs(wrapped)  # the smallest phase change (lag or lead) that puts L on -1
        pm = min(pm, margin)
        wc = float(w[i] + f * (w[i + 1] - w[i])) if math.isnan(wc) or w[i] > wc else wc
    shifted = (phase + math.pi) / (2 * math.pi)  # integer crossings = phase at -180 deg + k 360 deg
    k = np.floor(shifted)
    for i in np.nonzero(np.diff(k) != 0)[0]:
        level = max(k[i], k[i + 1])
        f = (level - shifted[i]) / (shifted[i + 1] - shifted[i])
        g = db[i] + f * (db[i + 1] - db[i])
        gm = min(gm, abs(g))
    return pm, gm, wc


def _pade(T: float):
    """Second-order Pade approximant of exp(-sT): (num, den) polynomials, highest power first."""
    if T <= 0:
        return np.array([1.0]), np.array([1.0])
    return np.array([T * T / 12, -T / 2, 1.0]), np.array([T * T / 12, T / 2, 1.0])


def _lp1(hz):
    if hz <= 0:
        return np.array([1.0]), np.array([1.0])
    return np.array([1.0]), np.array([1.0 / (2 * math.pi * hz), 1.0])


def _lp2(hz):
    if hz <= 0:
        return np.array([1.0]), np.array([1.0])
    w = 2 * math.pi * hz
    return np.array([w * w]), np.array([1.0, math.sqrt(2.0) * w, w * w])


def _mul(*blocks):
    num, den = np.array([1.0]), np.array([1.0])
    for n, d in blocks:
        num, den = np.polymul(num, n), np.polymul(den, d)
    return num, den


def _add(a, b):
    return np.polyadd(np.polymul(a[0], b[1]), np.polymul(b[0], a[1])), np.polymul(a[1], b[1])


def _pid_poly(g: PIDGains, target: bool = False):
    d_filter = _lp1(g.filt_d_hz)
    pi = (np.array([g.p, g.i]), np.array([1.0, 0.0]))
    dd = _mul((np.array([g.d, 0.0]), np.array([1.0])), d_filter)
    return _mul(_add(pi, dd), _lp1(g.filt_t_hz if target else g.filt_e_hz))


def _closed_loop_stable(num, den, neutral_tol: float = 1e-6) -> bool:
    """1 + N/D = 0 has all roots with negative real part (common factors of s removed first; roots within
    ``neutral_tol`` of the origin count as neutral: an integrator the next loop out holds)."""
    num, den = np.trim_zeros(np.atleast_1d(num), "f"), np.trim_zeros(np.atleast_1d(den), "f")
    while num.size > 1 and den.size > 1 and abs(num[-1]) < 1e-14 * np.abs(num).max() \
            and abs(den[-1]) < 1e-14 * np.abs(den).max():
        num, den = num[:-1], den[:-1]
    char = np.polyadd(den, num)
    char = char / np.abs(char).max()
    roots = np.roots(np.trim_zeros(char, "f"))
    scale = max(1.0, float(np.max(np.abs(roots)))) if roots.size else 1.0
    real = roots.real[np.abs(roots) > neutral_tol * scale]
    return bool(np.all(real < -1e-9 * scale))


def _rational(loop: str, params: ArduSubParameters, ap: AxisPlant, timing: LoopTiming, which: str):
    """(num, den) of the loop with Pade delays (for the closed loop's poles)."""
    motor = _mul((np.array([1.0]), np.array([timing.motor_tau_s, 1.0])), _pade(timing.output_delay_s))
    plant_rate = (np.array([ap.gain, 0.0]), np.array([ap.inertia, ap.damping, ap.stiffness]))
    if loop == "depth":
        dp = params.depth
        c_acc, c_vel = _pid_poly(dp.accel), _pid_poly(dp.vel)
        acc_meas = _mul(_lp2(timing.accel_filter_hz), (np.array([1.0, 0.0, 0.0]), np.array([1.0])))
        vel_meas = _mul(c_vel, (np.array([1.0, dp.pos_p]), np.array([1.0])), _pade(timing.depth_latency_s))
        g_pos = _mul(plant_rate, (np.array([1.0]), np.array([1.0, 0.0])))
        return _mul(c_acc, _add(acc_meas, vel_meas), g_pos, _lp1(dp.throttle_cutoff_hz), motor)
    g = rate_gains(params, loop)
    forward = _mul(_pid_poly(g), plant_rate, motor)
    l_rate = _mul(forward, _lp2(timing.gyro_filter_hz))
    if which == "rate":
        return l_rate
    k = ("roll", "pitch", "yaw").index(loop)
    t_num, t_den = _mul(_pid_poly(g, target=True), plant_rate, motor)
    # T_rate = F_T PID G M / (1 + L_rate): with L_rate = Nl/Dl and the forward path F/DF
    nl, dl = l_rate
    inner_num = np.polymul(t_num, dl)
    inner_den = np.polymul(t_den, np.polyadd(dl, nl))
    return _mul((inner_num, inner_den), (np.array([params.attitude.angle_p[k]]), np.array([1.0, 0.0])),
                _pade(timing.attitude_latency_s))


def loop_margins(vehicle: Vehicle, fr: Frame, params: ArduSubParameters, loop: str, timing: LoopTiming,
                 which: str = "outer", plant: AxisPlant | None = None) -> Margins:
    """The margins of one loop of ``params`` on ``vehicle`` (see the module notes)."""
    ap = plant or axis_plant(vehicle, fr, loop)
    w = _grid(timing)
    L = open_loop(1j * w, loop, params, ap, timing, which)
    pm, gm, wc = margins_from_response(w, L)
    num, den = _rational(loop, params, ap, timing, which)
    stable = _closed_loop_stable(num, den) if which == "outer" or loop == "depth" else \
        _closed_loop_stable(num, den, neutral_tol=1e-6)
    name = loop if which == "outer" or loop == "depth" else f"{loop}_rate"
    return Margins(name, vehicle.name, float(pm), float(gm), float(wc), stable)


def command_bandwidth(params: ArduSubParameters, loop: str) -> float:
    """The -3 dB bandwidth of ``ATC_INPUT_TC``'s command shaping (rad/s; inf for depth or a zero time
    constant): the shaped target follows a command as a first-order lag of ``INPUT_TC`` near zero error."""
    if loop == "depth" or params.attitude.input_tc <= 0:
        return math.inf
    return 1.0 / params.attitude.input_tc


__all__ = ["AxisPlant", "GAIN_MARGIN_MIN_DB", "LoopTiming", "MOTOR_TAU_ASSUMED_S", "Margins", "PHASE_MARGIN_MIN_DEG",
           "axis_plant", "command_bandwidth", "loop_margins", "margins_from_response", "open_loop"]
