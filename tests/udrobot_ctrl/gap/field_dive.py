"""A synthetic field dive as the users' real BlueROV2 dives were logged (issue 37): a QGroundControl tlog of a
vehicle flown by a pilot under ArduSub in STABILIZE and ALT_HOLD, without a DVL, whose heave drag differs from the
published model.

Truth: the ``bluerov2-heavy`` model with its heave quadratic drag Z_w|w| scaled by ``1 + HEAVE_DRAG_SCALE`` (half the
published value: the size the users' fits suggested), flown by the emulated ArduSub
(:func:`udrobot_ctrl.autopilot.fly.fly`) from a pilot's RC inputs: climbs and descents at +-300 us throttle,
forward runs at +200 us, some yaw, first in STABILIZE then in ALT_HOLD.

The tlog holds the streams at the rates measured in a real BlueROV2 QGroundControl tlog (``../shared/data/
ardusub_log_tools/2023-04-18 11-03-34.tlog``, MIT): HEARTBEAT 1 Hz (custom_mode, armed), ATTITUDE 20 Hz, VFR_HUD
10 Hz, GLOBAL_POSITION_INT 3 Hz, SCALED_PRESSURE2 2 Hz, SERVO_OUTPUT_RAW 2 Hz (instantaneous samples of the 200 Hz
loop's outputs), RC_CHANNELS 2 Hz (ArduSub's RC overrides), SYS_STATUS 1 Hz, and the MANUAL_CONTROL that QGC sent
(system 255, component 190) at 23.6 Hz: the pilot's joystick, converted to RC overrides by ArduSub's
``transform_manual_control_to_rc_override`` (:func:`udrobot_ctrl.autopilot.joystick.rc_override`) at pilot gain
``PILOT_GAIN``. No DVL, no position, no accelerometer. Sensor noise (assumed, typical of the class): depth 1 cm
(pressure and the EKF's depths), attitude 0.2 deg, gyro 0.3 deg/s.

:class:`Variant` changes what a real dive may do differently (the robustness study of the verdict,
``bench/field_dive_variants.py``): the 6-thruster ``bluerov2``, the time ALT_HOLD starts, a log without
``MANUAL_CONTROL`` (older QGC: the pilot only in the 2 Hz ``RC_CHANNELS``), other ATTITUDE / VFR_HUD rates, the noise
seed and the withheld scale. Its defaults are the dive above.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.udrobot_ctrl.io.test_field_logs import RHO_G, write_events
from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.autopilot.fly import ClosedLoopFlight, fly
from udrobot_ctrl.autopilot.joystick import rc_override
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import kinematics, plant_parameters
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import Vehicle, load_model

MODEL = "bluerov2-heavy"
HEAVE_DRAG_SCALE = -0.5  # the withheld effect: Z_w|w| x (1 + s), s = -0.5 (half the published heave drag)
DEPTH_NOISE = 0.01  # m, assumed (Bar30 and the EKF's depth)
ATTITUDE_NOISE = np.radians(0.2)  # rad, assumed
GYRO_NOISE = np.radians(0.3)  # rad/s, assumed
START_DEPTH = 10.0  # m
PILOT_GAIN = 1.0  # assumed: ArduSub's JS_GAIN_MAX, where the +-300 us climbs are a full throttle stick
JOYSTICK_HZ = 23.6  # MANUAL_CONTROL rate measured in the real tlog above
STATE = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
DVL_NOISE = 0.01  # m/s per axis, assumed (a Water Linked A50's velocity noise at a few metres' altitude)
POSITION_NOISE = 0.05  # m, assumed (a DVL-aided EKF's position over a few minutes)


@dataclass(frozen=True)
class Leg:
    """One pilot action: from ``start`` to ``end`` (s) the named stick sits at ``1500 + offset`` us."""

    start: float
    end: float
    stick: str
    offset: float


@dataclass(frozen=True)
class Variant:
    """A variant of the dive; the defaults are the module's dive.

    Attributes
    ----------
    model : str
        The vehicle flown and logged (``bluerov2-heavy`` or the 6-thruster ``bluerov2``).
    scale : float
        The withheld heave drag scale: Z_w|w| x (1 + scale).
    alt_hold_from : float or None
        Time (s) from which the pilot flies ALT_HOLD (STABILIZE before); None: half the duration.
    manual_control : bool
        Whether the tlog holds QGC's ``MANUAL_CONTROL`` at ``JOYSTICK_HZ`` (else only ``RC_CHANNELS`` at 2 Hz).
    attitude_hz, vfr_hz : float
        ``ATTITUDE`` and ``VFR_HUD`` rates (Hz).
    forward : float
        Forward stick of the forward legs (us about 1500). The 6-thruster model tumbles in pitch at the default
        200 us: its horizontal thrusters sit 7.25 cm below CO and push 41 N, 2.97 N m of pitch against at most
        1.13 N m of restoring moment (BG 1 cm; models/bluerov2.toml).
    servo_hz : float
        ``SERVO_OUTPUT_RAW`` rate (Hz; QGC's default 2).
    voltage : float or None
        Battery voltage SYS_STATUS logs (V); None: the voltage the truth is flown at, the model's supply voltage
        (:attr:`logged_voltage`). The diagnosis computes the T200 thrusts at the logged voltage.
    seed : int
        Sensor noise seed.
    jitter : float
        Receive-time delay of each message, uniform in [0, jitter] s (the telemetry link's latency; the messages'
        own stamps stay exact); 0: none.
    duration : float
        Dive length (s).
    pattern : tuple of Leg or None
        The pilot's legs (:class:`Leg`, times from the start); None: :func:`legs` from the start and again from half
        the duration.
    effects : tuple of (name, params)
        Effects of the truth beyond the heave drag scale (``udrobot_ctrl.dynamics.effects`` catalogue entries: a
        current, a tether), flown by the plant.
    dvl_hz : float
        ``VISION_SPEED_ESTIMATE`` rate (Hz): a DVL's velocity over ground, NED, as BlueOS's DVL driver sends it to
        ArduSub (noise ``DVL_NOISE``); 0: no DVL.
    position_hz : float
        ``LOCAL_POSITION_NED`` rate (Hz): the EKF's position and velocity (position noise ``POSITION_NOISE``); 0:
        not logged.
    """

    model: str = MODEL
    scale: float = HEAVE_DRAG_SCALE
    alt_hold_from: float | None = None
    manual_control: bool = True
    attitude_hz: float = 20.0
    vfr_hz: float = 10.0
    forward: float = 200.0
    servo_hz: float = 2.0
    voltage: float | None = None
    seed: int = 0
    jitter: float = 0.0
    duration: float = 180.0
    pattern: tuple | None = None
    effects: tuple = ()
    dvl_hz: float = 0.0
    position_hz: float = 0.0

    @property
    def logged_voltage(self) -> float:
        """The battery voltage SYS_STATUS logs (V): ``voltage``, or the one :func:`fly` runs the truth's thrusters at
        (the model's supply voltage)."""
        return self.voltage if self.voltage is not None else plant_parameters(load_model(self.model)).supply_voltage


RC_INDEX = {"throttle": 2, "yaw": 3, "forward": 4, "lateral": 5}  # ArduSub's channel order, 0-based


def legs(t0: float, forward: float = 200.0) -> tuple:
    """The pilot's 90 s pattern from ``t0`` (s): descend, climb, forward and back (``forward`` us), yaw, climb and
    descend again."""
    return (Leg(t0 + 4, t0 + 14, "throttle", -300.0), Leg(t0 + 20, t0 + 30, "throttle", 300.0),
            Leg(t0 + 36, t0 + 46, "forward", forward), Leg(t0 + 50, t0 + 56, "forward", -forward),
            Leg(t0 + 58, t0 + 61, "yaw", 150.0), Leg(t0 + 64, t0 + 72, "throttle", 300.0),
            Leg(t0 + 76, t0 + 86, "throttle", -300.0))


def joystick(t: np.ndarray, duration: float, forward: float = 200.0, pattern=None) -> np.ndarray:
    """The pilot's joystick (N, 4) at times ``t``: MANUAL_CONTROL x (forward), y (lateral), z (throttle, 500
    neutral), r (yaw), each leg's stick offset (us; forward legs ``forward``) divided by ArduSub's scale at
    ``PILOT_GAIN``; the legs of ``pattern``, or :func:`legs` from 0 and from ``duration / 2``."""
    axes = np.zeros((np.size(t), 4))
    axes[:, 2] = 500.0
    column = {"forward": 0, "lateral": 1, "throttle": 2, "yaw": 3}
    for leg in (pattern if pattern is not None else legs(0.0, forward) + legs(duration / 2, forward)):
        scale = (0.8 if leg.stick == "throttle" else 0.4) * PILOT_GAIN
        axes[(t >= leg.start) & (t < leg.end), column[leg.stick]] += leg.offset / scale
    return axes


def pilot_plan(duration: float = 180.0, dt: float = 0.02, model: str = MODEL,
               alt_hold_from: float | None = None, forward: float = 200.0, pattern=None) -> Run:
    """The pilot's inputs and modes as a run for :func:`fly`: STABILIZE until ``alt_hold_from`` (s; None: half the
    duration), ALT_HOLD after; the RC inputs are ArduSub's overrides of the joystick (channels 3-6; the legs of
    ``pattern``, see :func:`joystick`), 1500 us elsewhere."""
    t = np.arange(0.0, duration, dt)
    rc = np.full((t.size, 8), 1500.0)
    js = joystick(t, duration, forward, pattern)
    rc[:, 2:6] = rc_override(js[:, 0], js[:, 1], js[:, 2], js[:, 3], PILOT_GAIN)
    switch = duration / 2 if alt_hold_from is None else alt_hold_from
    mode = np.where(t < switch, float(Mode.STABILIZE), float(Mode.ALT_HOLD))
    x0 = np.zeros(12)
    x0[2] = START_DEPTH
    channels = {name: np.full(t.size, x0[i]) for i, name in enumerate(STATE)}
    extra = {"mode": mode, **{f"rcin_{i + 1}": rc[:, i] for i in range(8)}}
    return Run(path="pilot.csv", t=t, channels=channels, input_kind="pwm",
               inputs=np.full((t.size, len(load_model(model).thrusters)), 1500.0),
               extra=extra, metadata={"vehicle": model})


def truth_vehicle(scale: float = HEAVE_DRAG_SCALE, model: str = MODEL, effects=()) -> Vehicle:
    """The published model with its heave quadratic drag Z_w|w| scaled by ``1 + scale`` and the plant effects
    ``effects`` ((name, params) pairs)."""
    v = load_model(model)
    q = np.array(v.quadratic_damping, float)
    q[2, 2] *= 1.0 + scale
    return v.with_changes(quadratic_damping=q, effects=tuple(PlantEffect(n, dict(p)) for n, p in effects))


def flight(duration: float = 180.0, scale: float = HEAVE_DRAG_SCALE, model: str = MODEL,
           alt_hold_from: float | None = None, forward: float = 200.0, pattern=None, effects=()) -> tuple:
    """The truth (:func:`truth_vehicle`) flown under the emulated ArduSub at 200 Hz from the pilot's ``pattern``
    (:func:`pilot_plan`). Returns (ClosedLoopFlight, pilot plan Run)."""
    plan = pilot_plan(duration, model=model, alt_hold_from=alt_hold_from, forward=forward, pattern=pattern)
    return fly(truth_vehicle(scale, model, effects), plan, loop_rate_hz=200.0), plan


#: the EKF configuration of a vehicle whose DVL feeds the EKF (BlueOS's Water Linked DVL extension)
DVL_PARAMETERS = {"VISO_TYPE": 1.0, "EK3_SRC1_POSXY": 6.0, "EK3_SRC1_VELXY": 6.0, "EK3_SRC1_POSZ": 1.0,
                  "EK3_SRC1_VELZ": 0.0}


def _at(f: ClosedLoopFlight, t: float) -> int:
    return int(min(np.searchsorted(f.t, t), f.t.size - 1))


def write_tlog(path, f: ClosedLoopFlight, plan: Run, variant: Variant = Variant()):
    """Log ``f`` (flown from ``plan``) as QGroundControl would (the streams and rates in the module docstring), with
    sensor noise, the streams, rates, pilot inputs, battery and receive delays of ``variant`` (:class:`Variant`)."""
    v = variant
    rng = np.random.default_rng(v.seed)
    battery_mv = int(round(v.logged_voltage * 1000))
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    end = float(f.t[-1])
    ev = []
    mode = plan.extra["mode"]
    for t in np.arange(0.0, end, 1.0):
        m = int(mode[min(np.searchsorted(plan.t, t), plan.n - 1)])
        ev.append((t, mav.heartbeat_encode(12, 3, 81 | 128, m, 4)))  # armed, custom_mode = ArduSub mode
        ev.append((t + 0.3, mav.sys_status_encode(0, 0, 0, 500, battery_mv, 500, 90, 0, 0, 0, 0, 0, 0)))
    for t in np.arange(0.01, end, 1.0 / v.attitude_hz):
        x = f.x[_at(f, t)]
        att = x[3:6] + rng.normal(0.0, ATTITUDE_NOISE, 3)
        rates = x[9:12] + rng.normal(0.0, GYRO_NOISE, 3)
        yaw = (att[2] + np.pi) % (2 * np.pi) - np.pi
        ev.append((t, mav.attitude_encode(int(t * 1000), att[0], att[1], yaw, *rates)))
    for t in np.arange(0.02, end, 0.5):
        depth = f.x[_at(f, t), 2] + rng.normal(0.0, DEPTH_NOISE)
        ev.append((t, mav.scaled_pressure2_encode(int(t * 1000), (101325.0 + RHO_G * depth) / 100.0, 0.0, 1200)))
    for t in np.arange(0.03, end, 1.0 / v.vfr_hz):
        depth = f.x[_at(f, t), 2] + rng.normal(0.0, DEPTH_NOISE)
        ev.append((t, mav.vfr_hud_encode(0.0, 0.0, int(np.degrees(f.x[_at(f, t), 5])) % 360, 0, -depth, 0.0)))
    for t in np.arange(0.04, end, 1.0 / 3.0):
        k = _at(f, t)
        depth = f.x[k, 2] + rng.normal(0.0, DEPTH_NOISE)
        ev.append((t, mav.global_position_int_encode(int(t * 1000), 0, 0, int(-depth * 1000), int(-depth * 1000),
                                                     0, 0, int(100 * f.x[k, 8]), 65535)))
    for t in np.arange(0.05, end, 1.0 / v.servo_hz):
        servo = [int(round(us)) for us in f.pwm[_at(f, t)]]
        servo += [0] * (16 - len(servo))  # unused outputs
        ev.append((t, mav.servo_output_raw_encode(int(t * 1e6), 0, *servo)))
    for t in np.arange(0.06, end, 0.5):
        rc = [int(plan.extra[f"rcin_{i + 1}"][min(np.searchsorted(plan.t, t), plan.n - 1)]) for i in range(8)]
        ev.append((t, mav.rc_channels_encode(int(t * 1000), 8, *rc, *[0] * 10, 255)))
    if v.manual_control:
        gcs = mav2.MAVLink(None, srcSystem=255, srcComponent=190)
        t_js = np.arange(0.007, end, 1.0 / JOYSTICK_HZ)
        for t, (x, y, z, r) in zip(t_js, joystick(t_js, plan.t[-1] + plan.t[1], v.forward, v.pattern)):
            ev.append((t, gcs.manual_control_encode(1, int(x), int(y), int(z), int(r), 0).pack(gcs)))
    if v.dvl_hz > 0:  # the DVL driver (BlueOS, component 197): velocity over ground, NED
        # the parameters BlueOS's DVL set-up writes: the EKF's horizontal sources are the external navigation (6),
        # the vertical position the baro (1); a QGC tlog carries them as PARAM_VALUE (its parameter download)
        for k, (name, value) in enumerate(DVL_PARAMETERS.items()):
            ev.append((0.001 * (k + 1), mav.param_value_encode(name.encode(), value, 9, len(DVL_PARAMETERS), k)))
        dvl = mav2.MAVLink(None, srcSystem=1, srcComponent=197)
        for t in np.arange(0.08, end, 1.0 / v.dvl_hz):
            ned = _ned_velocity(f.x[_at(f, t)]) + rng.normal(0.0, DVL_NOISE, 3)
            ev.append((t, dvl.vision_speed_estimate_encode(int(t * 1e6), *ned).pack(dvl)))
    if v.position_hz > 0:  # the EKF's local position and velocity
        for t in np.arange(0.09, end, 1.0 / v.position_hz):
            x = f.x[_at(f, t)]
            pos = x[:3] + rng.normal(0.0, POSITION_NOISE, 3)
            ev.append((t, mav.local_position_ned_encode(int(t * 1000), *pos, *_ned_velocity(x))))
    if v.jitter > 0:
        late = np.random.default_rng(v.seed + 1).uniform(0.0, v.jitter, len(ev))
        ev = [(t + d, m) for (t, m), d in zip(ev, late)]
    return write_events(path, mav, ev)


def _ned_velocity(x) -> np.ndarray:
    """(3,) NED velocity of state ``x`` (12,)."""
    return kinematics(x[None, :6], x[None, 6:])[0, :3]


def write_variant(path, variant: Variant = Variant()):
    """Fly ``variant`` and write its tlog to ``path``. Returns the path."""
    f, plan = flight(variant.duration, variant.scale, variant.model, variant.alt_hold_from, variant.forward,
                     variant.pattern, variant.effects)
    return write_tlog(path, f, plan, variant)
