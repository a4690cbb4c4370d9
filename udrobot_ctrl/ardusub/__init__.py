"""ArduSub as its firmware defines it: the parameters (names, defaults, documented ranges, the one check of values
read from a log) and the flight-mode numbers and pilot-input semantics. Imports no other unit of the package, so
the readers of logs (:mod:`udrobot_ctrl.io`) and the emulation (:mod:`udrobot_ctrl.autopilot`) share one
definition."""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used
_EXPORTS = {"ArduSubParameters": "params"}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
