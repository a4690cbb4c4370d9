"""Identification of hydrodynamic coefficients from free-decay, pendulum and CFD data.

Modules
-------
free_decay  : spring free-decay test (Cely 2019 eqs. 6-9)
pendulum    : pendulum free-decay test, Chin and Morison forms (eqs. 10-16)
cfd         : force-speed regressions (Table 5)
similitude  : scale-model -> full-scale laws
statistics  : launch groups, pairwise tests, outliers
fossen      : coefficient set -> Fossen-form M_A and D(nu)
"""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used
_EXPORTS = {
    "RigOptions": "identify", "identify_files": "identify", "format_table": "identify",
    "coefficient_set_values": "identify",
    "SpringRig": "free_decay", "read_spring_launch": "free_decay",
    "PendulumRig": "pendulum", "read_pendulum_launch": "pendulum",
    "ForceTable": "cfd", "read_force_table": "cfd", "chin_regression": "cfd", "morison_regression": "cfd",
    "identify_table": "cfd",
    "CoefficientSet": "fossen", "added_mass_matrix": "fossen", "damping_matrices": "fossen",
    "load_coefficient_set": "sets", "write_coefficient_set": "sets",
    "FullSizeVehicle": "similitude", "full_scale": "similitude",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
