"""The equations of motion, thrusters and integrators (one definition of the dynamics)."""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used
_EXPORTS = {
    "PlantParameters": "plant", "plant_parameters": "plant", "state_derivative": "plant", "thrust_to_wrench": "plant",
    "thruster_matrix": "plant", "SingularMassMatrixError": "plant",
    "simulate": "sim", "SimResult": "sim",
    "ThrusterCurve": "thrusters", "load_curve": "thrusters", "pwm_to_thrust": "thrusters",
    "thrust_to_pwm": "thrusters", "ThrustAllocator": "thrusters",
    "PlantEffect": "effects", "plant_effect": "effects", "parse_effects": "effects",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
