"""The names every layer shares, defined once at the bottom of the package (docs/architecture.md).

SNAME (1950) notation, as in Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control* (2011), table 2.1:
the generalised forces along and about the body axes, the body velocities and the NED pose. This module imports
nothing of the project, so any module may import it.
"""
from __future__ import annotations

#: Generalised forces (body frame): surge X, sway Y, heave Z (N); roll K, pitch M, yaw N (N m).
DOF_NAMES = ("X", "Y", "Z", "K", "M", "N")
#: Body velocities in the order of :data:`DOF_NAMES`: u, v, w (m/s); p, q, r (rad/s).
VELOCITY_NAMES = ("u", "v", "w", "p", "q", "r")
#: NED position x, y, z (m, z down) and ZYX Euler angles phi, theta, psi (rad).
POSE_NAMES = ("x", "y", "z", "phi", "theta", "psi")
#: The plant's 12-state order: pose then body velocities.
STATE_NAMES = POSE_NAMES + VELOCITY_NAMES
#: State name -> index in :data:`STATE_NAMES`.
STATE_INDEX = {n: i for i, n in enumerate(STATE_NAMES)}
