"""Control design on the plant: linearisation, LQR, PID, MPC, EKF, missions, metrics, compare."""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used.
# compare() and linearize() share their module's name, so they are exported by udrobot_ctrl itself.
_EXPORTS = {
    "OperatingPoint": "linearize", "trim_at": "linearize", "hover_trim": "linearize", "LinearModel": "linearize",
    "BrysonWeights": "lqr", "LQRDesign": "lqr", "design_lqr": "lqr", "ScheduledLQR": "lqr",
    "PIDTuning": "pid", "design_loops": "pid", "PIDController": "pid",
    "LinearMPC": "mpc", "NonlinearMPC": "mpc",
    "UDrobotEKF": "ekf", "EKFResult": "ekf", "ekf_on_trajectory": "ekf",
    "Mission": "missions", "standard_mission": "missions", "make_controller": "missions", "run_mission": "missions",
    "mission_metrics": "metrics",
    "Comparison": "compare",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
