"""ALT_HOLD's surface and bottom handling (autopilot/surface_bottom.py): ArduSub's detector and the depth-target
clamps, checked alone and in closed loop on a heave plant with a free surface and a seabed."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode, PilotInput
from udrobot_ctrl.ardusub.params import ArduSubParameters
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, MixerInputs, VehicleState
from udrobot_ctrl.autopilot.fly import fly
from udrobot_ctrl.autopilot.surface_bottom import (
    BOTTOM_CLEARANCE,
    BOTTOM_DETECTOR_TRIGGER_SEC,
    MAIN_LOOP_RATE,
    SurfaceBottomDetector,
    althold_depth_target,
)
from udrobot_ctrl.io.runlog import Run

DT = 0.005  # s: the dive's 200 Hz loop (SCHED_LOOP_RATE 200)
TRIGGER_TICKS = int(BOTTOM_DETECTOR_TRIGGER_SEC * MAIN_LOOP_RATE)


def test_surface_flag_has_arduSubs_5_cm_hysteresis():
    det = SurfaceBottomDetector(surface_depth=0.10)  # SURFACE_DEPTH -10 cm
    for depth, expected in ((0.30, False), (0.11, False), (0.09, True), (0.14, True), (0.151, False), (0.12, False)):
        det.update(depth, 0.0, throttle_lower=False)
        assert det.at_surface is expected, depth
    det.update(0.0, 0.0, throttle_lower=False, armed=False)
    assert not det.at_surface  # disarmed: cleared


def test_bottom_flag_after_400_ticks_of_lower_limit_and_no_vertical_speed():
    det = SurfaceBottomDetector(surface_depth=0.10)
    for _ in range(TRIGGER_TICKS):
        det.update(5.0, 0.01, throttle_lower=True)
    assert not det.at_bottom
    det.update(5.0, 0.01, throttle_lower=True)
    assert det.at_bottom
    det.update(5.0, 0.2, throttle_lower=True)  # moving again: cleared at once
    assert not det.at_bottom
    # set_bottomed(false) resets the count only when the flag changes: ArduSub keeps counting across interruptions
    for _ in range(TRIGGER_TICKS // 2):
        det.update(5.0, 0.0, throttle_lower=True)
    det.update(5.0, 0.0, throttle_lower=False)
    for _ in range(TRIGGER_TICKS // 2 + 1):
        det.update(5.0, 0.0, throttle_lower=True)
    assert det.at_bottom


def test_depth_target_clamps_only_with_the_stick_centred():
    at_surface = althold_depth_target(-0.5, 0.02, 0.0, True, False, surface_depth=0.10)
    assert at_surface.target == pytest.approx(0.15) and at_surface.reason == "surface"
    assert althold_depth_target(0.4, 0.3, 0.0, True, False, 0.10).target == 0.4  # already deeper: kept
    assert althold_depth_target(-0.5, 0.02, 0.3, True, False, 0.10).target == -0.5  # pilot climbing: kept
    bottom = althold_depth_target(3.5, 3.0, 0.0, False, True, 0.10)
    assert bottom.target == pytest.approx(3.0 - BOTTOM_CLEARANCE) and bottom.reason == "bottom"
    assert althold_depth_target(2.5, 3.0, 0.0, False, True, 0.10).target == 2.5  # already above: kept


@dataclass
class Heave:
    """A vehicle in heave (SI, down positive): weight, a hull of ``hull`` m whose buoyancy falls as it leaves the
    water (the depth sensor at its middle), a stiff seabed, linear and quadratic drag, thrust = gain x (2 thr - 1).
    Buoyancy 2 N above weight when submerged (a trimmed BlueROV2 is slightly positive)."""

    depth: float
    w: float = 0.0
    a: float = 0.0
    weight: float = 110.0
    buoyancy: float = 112.0
    hull: float = 0.25
    mass: float = 16.0          # kg incl. added mass
    thrust_gain: float = 60.0   # N at full throttle
    drag: tuple = (20.0, 30.0)  # N/(m/s), N/(m/s)^2
    seabed: float = np.inf      # m
    stiffness: float = 5000.0   # N/m, seabed contact
    contact_damping: float = 500.0

    def state(self) -> VehicleState:
        return VehicleState(depth=self.depth, vel_down=self.w, accel_down=self.a)

    def step(self, u: MixerInputs, dt: float) -> None:
        submerged = np.clip((self.depth + self.hull / 2) / self.hull, 0.0, 1.0)
        force = self.weight - self.buoyancy * submerged - self.thrust_gain * (2.0 * u.throttle - 1.0)
        force -= self.drag[0] * self.w + self.drag[1] * self.w * abs(self.w)
        if self.depth > self.seabed:
            force -= self.stiffness * (self.depth - self.seabed) + self.contact_damping * self.w
        self.a = force / self.mass
        self.w += self.a * dt
        self.depth += self.w * dt


def fly_althold(ap: ArduSubAutopilot, body: Heave, sticks, seconds: float) -> np.ndarray:
    """ALT_HOLD for ``seconds`` with ``sticks(t)`` -> throttle stick (-1..1); returns (t, depth, target, surface,
    bottom, throttle) rows."""
    rows = []
    for k in range(int(round(seconds / DT))):
        t = k * DT
        u = ap.step(DT, body.state(), PilotInput.from_sticks(throttle=sticks(t)), Mode.ALT_HOLD)
        body.step(u, DT)
        det = ap.surface_bottom
        rows.append((t, body.depth, ap.depth.pos_target, det.at_surface, det.at_bottom, u.throttle))
    return np.array(rows, float)


@pytest.mark.parametrize("surface_depth_cm", [None, -30.0])
def test_buoyant_vehicle_brought_to_the_surface_holds_5_cm_below_surface_depth(surface_depth_cm):
    """The pilot climbs into the surface and lets go: the target the stick left is above the water; ArduSub
    moves it to SURFACE_DEPTH - 5 cm and the vehicle dives back to it and holds (the log's SURFACE_DEPTH if given,
    else -10 cm)."""
    log = {} if surface_depth_cm is None else {"SURFACE_DEPTH": surface_depth_cm}
    params = ArduSubParameters.from_log_params({**log, "SCHED_LOOP_RATE": 200})
    assert ("SURFACE_DEPTH" in params.assumed) is (surface_depth_cm is None)
    hold = params.depth.surface_depth + 0.05  # m, down
    ap = ArduSubAutopilot(params)
    body = Heave(depth=1.5)
    climb = 5.0
    rows = fly_althold(ap, body, lambda t: 1.0 if t < climb else 0.0, 40.0)
    t, depth, target, surfaced = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    let_go = np.searchsorted(t, climb)
    assert depth[let_go - 1] < params.depth.surface_depth and surfaced[let_go - 1]  # at the surface, pushing up
    assert target[let_go - 1] < -0.1            # the stick's target is above the water
    # clamped on the first centred tick, then moved by that tick's integration of the decaying climb (< 1 m/s x dt)
    assert target[let_go] == pytest.approx(hold, abs=1.0 * DT)
    assert ap.surface_clamps >= 1
    settled = t > 30.0
    # the depth loop holds its target to well under a centimetre once settled (no noise, constant buoyancy)
    assert np.max(np.abs(depth[settled] - hold)) < 0.005
    assert np.all(np.abs(target[settled] - hold) < 1e-9)


def test_vehicle_driven_onto_the_seabed_is_detected_and_lifted_10_cm():
    """The pilot descends onto the seabed: with the throttle at its lower limit and the vehicle still, ArduSub sets
    at_bottom after 400 ticks (2 s at 200 Hz); when the pilot lets go the target moves to 10 cm above the vehicle,
    which lifts off and holds there."""
    params = ArduSubParameters.from_log_params({"SCHED_LOOP_RATE": 200})
    ap = ArduSubAutopilot(params)
    seabed = 3.0
    body = Heave(depth=2.5, seabed=seabed)
    descend = 4.0
    rows = fly_althold(ap, body, lambda t: -1.0 if t < descend else 0.0, 40.0)
    t, depth, target, bottomed, throttle = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 4], rows[:, 5]
    assert depth[t < descend].max() > seabed            # it reached the seabed
    criteria = (throttle <= 0.0) & (np.abs(np.gradient(depth, DT)) < 0.05)
    first, k = int(np.argmax(criteria)), int(np.argmax(bottomed > 0))
    assert criteria[first] and bottomed[k]
    assert t[k] - t[first] >= TRIGGER_TICKS * DT - DT    # counted in 400 ticks of the compile-time 400 Hz: 2 s here
    let_go = int(np.searchsorted(t, descend))
    assert bottomed[let_go - 1] and target[let_go - 1] > seabed  # still pushing down into the seabed
    # the clamp on the first centred tick, plus that tick's integration of the decaying descent (< 1 m/s x dt)
    assert target[let_go] == pytest.approx(depth[let_go] - BOTTOM_CLEARANCE, abs=1.0 * DT)
    assert ap.bottom_clamps >= 1
    # the emulated target then drifts down with the decaying descent demand (AC_PosControl's limit vector, which
    # stops that drift while the throttle is saturated, is not emulated) and the detector clamps it again: the
    # vehicle ends 10 cm above where it sat
    final = target[-1]
    assert final == pytest.approx(seabed - BOTTOM_CLEARANCE, abs=0.02)  # the contact sinks ~1 cm into the seabed
    settled = t > t[-1] - 5.0
    assert np.max(np.abs(depth[settled] - final)) < 0.005    # off the seabed and held
    assert np.all(throttle[settled] > 0.0) and not bottomed[-1]  # no longer pushing down at the limit


def test_closed_loop_flight_notes_surface_depth_and_surftrak():
    """fly() says which SURFACE_DEPTH ALT_HOLD used and that SURFTRAK is flown on its logged targets only."""
    t = np.arange(0.0, 2.0, 0.02)
    mode = np.where(t < 1.0, float(Mode.ALT_HOLD), float(Mode.SURFTRAK))
    names = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
    channels = {n: np.full(t.size, 5.0 if n == "z" else 0.0) for n in names}
    extra = {"mode": mode, "z_target": np.full(t.size, 5.0), **{f"rcin_{i}": np.full(t.size, 1500.0)
                                                                 for i in range(1, 9)},
             **{f"{a}_target": np.zeros(t.size) for a in ("roll", "pitch", "yaw")}}  # SURFTRAK flies logged targets
    notes = {}
    for label, params in (("default", {}), ("logged", {"SURFACE_DEPTH": -30.0})):
        run = Run(path="plan.csv", t=t, channels=channels, input_kind="pwm", inputs=np.full((t.size, 8), 1500.0),
                  extra=extra, metadata={"vehicle": "bluerov2-heavy", "autopilot_params": params})
        notes[label] = " | ".join(fly("bluerov2-heavy", run, loop_rate_hz=200.0).notes)
    assert "SURFACE_DEPTH -10 cm (ArduSub's default, not in the log)" in notes["default"]
    assert "SURFACE_DEPTH -30 cm (from the log)" in notes["logged"]
    assert "clamped 0 tick(s) at the surface and 0 on the bottom" in notes["default"]  # at 5 m: never
    assert "SURFTRAK is not emulated" in notes["default"]
