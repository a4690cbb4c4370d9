"""udrobot-ctrl: control design for small underwater robots from identified hydrodynamic coefficients.

The public API is listed in each subpackage's ``__all__`` (:mod:`udrobot_ctrl.dynamics`, :mod:`udrobot_ctrl.control`,
:mod:`udrobot_ctrl.autopilot`, :mod:`udrobot_ctrl.io`, :mod:`udrobot_ctrl.gap`, :mod:`udrobot_ctrl.sensitivity`),
in :mod:`udrobot_ctrl.vehicle` and in ``identification``. This package exports the vehicle models, the
converters of field logs to runs (:func:`convert_log`, :func:`load_any`) and the four functions whose name is
also their module's (a package attribute cannot be both): :func:`compare`, :func:`linearize`, :func:`fly` and
:func:`check_flight`.
"""
from udrobot_ctrl.vehicle import MODEL_NAMES, Vehicle, load_model
from udrobot_files.exports import lazy_exports

# name -> the module defining it, imported when first used
_EXPORTS = {"convert_log": "convert", "load_any": "convert", "compare": "control.compare",
            "linearize": "control.linearize", "fly": "autopilot.fly", "check_flight": "autopilot.check_flight"}
__all__ = ["MODEL_NAMES", "Vehicle", "load_model", *_EXPORTS]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__version__ = "0.1.0"
