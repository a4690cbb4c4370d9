"""udrobot-ctrl: control design for small underwater robots from identified hydrodynamic coefficients."""
from udrobot_ctrl.vehicle import MODEL_NAMES, Vehicle, load_model

__all__ = ["MODEL_NAMES", "Vehicle", "load_model"]
__version__ = "0.1.0"
