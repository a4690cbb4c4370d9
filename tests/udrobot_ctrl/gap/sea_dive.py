"""A synthetic sea dive with a known current and tether (issue 37): what the shared sea dive cannot give, a truth.

The shared dive (``../shared/data/guided_above_terrain``) flies transects out and back with a DVL, and its verdict
must be physically plausible: a current of one size and direction on both parts, a tether pulling toward its top
end at the surface. Whether the diagnoser can *find* such a current and tether on a dive of that shape is checked
here, on a BlueROV2 Heavy with the published model flown by a pilot under the emulated ArduSub in ALT_HOLD:

* three transects of 37-46 s at +200 us forward stick, the second heading 90 deg from the first and the third (the
  last third of the dive, which ``diagnose`` holds out) the reverse of the first; climbs and descents of +-300 us
  between them and a sideways push on the second transect;
* a QGroundControl tlog as :func:`tests.udrobot_ctrl.gap.field_dive.write_tlog` writes it, with the motor outputs at
  10 Hz (a dataflash log's RCOU rate), the DVL's velocity over ground (``VISION_SPEED_ESTIMATE`` at 5 Hz, as BlueOS's
  DVL driver sends it) and the EKF's position (``LOCAL_POSITION_NED`` at 5 Hz);
* truths (:data:`CASES`): a steady current of 0.15 m/s toward east, a tether to a boat at the surface 5 m west of
  the start (its cross-flow drag 15 N s^2/m^2 and 2 N s/m), and both.
"""
from __future__ import annotations

import math

from tests.udrobot_ctrl.gap.field_dive import Leg, Variant

#: the pilot's legs (times in s from the start); the yaw legs turn the vehicle 90 deg each (ALT_HOLD's pilot yaw
#: rate at +200 us, measured on the emulated autopilot: 68 deg/s)
TRANSECTS = (Leg(3, 40, "forward", 200.0), Leg(42, 47, "throttle", -300.0), Leg(49, 54, "throttle", 300.0),
             Leg(57, 58.32, "yaw", 200.0), Leg(61, 100, "forward", 200.0), Leg(102, 106, "lateral", 200.0),
             Leg(110, 111.32, "yaw", 200.0), Leg(114, 160, "forward", 200.0), Leg(163, 168, "throttle", -300.0),
             Leg(170, 175, "throttle", 300.0))
CURRENT = ("water_current", {"current_north_mps": 0.0, "current_east_mps": 0.15, "current_down_mps": 0.0})
TETHER = ("tether_drag", {"k_quadratic_N_s2_per_m2": 15.0, "k_linear_N_s_per_m": 2.0, "anchor_north_m": 0.0,
                          "anchor_east_m": -5.0, "anchor_down_m": 0.0})
CASES = {"current": (CURRENT,), "tether": (TETHER,), "current_and_tether": (CURRENT, TETHER)}
TRANSECT_SPEED = 0.5  # m/s, the forward legs' speed (ALT_HOLD at +200 us)


def sea_variant(case: str, seed: int = 0) -> Variant:
    """The dive of ``case`` (a key of :data:`CASES`) as a :class:`~tests.udrobot_ctrl.gap.field_dive.Variant`: the
    published Heavy (no heave drag change), ALT_HOLD throughout, the transects, the DVL and the EKF's position."""
    return Variant(scale=0.0, alt_hold_from=0.0, servo_hz=10.0, duration=180.0, pattern=TRANSECTS,
                   effects=CASES[case], dvl_hz=5.0, position_hz=5.0, seed=seed)


def current_error(params) -> float:
    """Horizontal distance (m/s) of a fitted current's ``params`` from the truth's :data:`CURRENT`."""
    true = CURRENT[1]
    return math.hypot(params["current_north_mps"] - true["current_north_mps"],
                      params["current_east_mps"] - true["current_east_mps"])


def anchor_error(params) -> float:
    """Horizontal distance (m) of a fitted tether's anchor in ``params`` from the truth's :data:`TETHER` anchor."""
    true = TETHER[1]
    return math.hypot(params["anchor_north_m"] - true["anchor_north_m"],
                      params["anchor_east_m"] - true["anchor_east_m"])


def tether_drag(params, speed: float = TRANSECT_SPEED) -> float:
    """The tether's cross-flow drag (N) with amplitudes ``params`` at ``speed`` (m/s) across the cable."""
    return params["k_quadratic_N_s2_per_m2"] * speed ** 2 + params["k_linear_N_s_per_m"] * speed
