"""The vehicle's own flight controller, as data plus one implementation (ArduSub 4.1-4.5).

``motors``: ArduSub's output side (AP_Motors6DOF frame factors, motor directions, PWM range, battery
compensation) from the mixer inputs to the thrusters' PWM, and back. The controllers (attitude angle P ->
rate PID, depth hold on AC_PosControl z, the flight modes and pilot input shaping) use it; ``simulate
--closed-loop`` and the diagnoser's closed-loop replays fly the plant under them.
"""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used.
# fly() and check_flight() share their module's name, so they are exported by udrobot_ctrl itself.
_EXPORTS = {
    "ArduSubAutopilot": "ardusub",
    "ClosedLoopFlight": "fly",
    "Specification": "design", "ArduSubDesign": "design", "design_ardusub": "design", "check_gains": "design",
    "read_params": "qgc_params", "parse_params": "qgc_params", "format_params": "qgc_params",
    "Frame": "motors", "frame": "motors",
    "check_log": "validate", "replay_autopilot": "validate",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
