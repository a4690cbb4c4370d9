"""Whether a fitted tether runs to where a tether's top end is: the surface.

A tether (``tether_drag``) is paid out from the surface: a tender's hands, a boat, a pier, a pool deck. Its fit
places the top end where the runs' residual force points (the anchor's NED position, a shape parameter searched
from the surface and refined no deeper than :data:`~udrobot_ctrl.gap.effects.TOP_END_DEPTH_MAX_M`); a fit pinned at
that limit, deeper (a model file's), or a far anchor whose cable runs down, is a free-form force the search found,
not that cable. :func:`top_end` reads the fitted top end against
the surface and the vehicle's depth (docs/formats/diagnosis.md, the ``tether_drag`` verdict's ``top_end``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from udrobot_ctrl.dynamics.effects import TETHER_ANCHOR
from udrobot_ctrl.gap.effects import FAR_ANCHOR_M, TOP_END_DEPTH_MAX_M

#: the catalogue effect whose top end is read
TETHER = "tether_drag"
#: a top end at most this far below the surface (m) is at the surface: the deepest the tether search lets it lie
#: (assumed; see :data:`udrobot_ctrl.gap.effects.TOP_END_DEPTH_MAX_M`)
SURFACE_TOLERANCE_M = TOP_END_DEPTH_MAX_M
#: a top end within this of :data:`SURFACE_TOLERANCE_M` (m) is pinned at the search's limit (the refinement clips
#: there): the fit wants it deeper, which is read as below the surface
AT_LIMIT_M = 1e-3
#: the kinds of :class:`TopEnd` reading
READINGS = ("at the surface", "below the surface", "rising", "not rising")


@dataclass(frozen=True)
class TopEnd:
    """Where a fitted tether's top end lies (the ``tether_drag`` verdict's ``top_end``).

    Attributes
    ----------
    north_m, east_m, down_m : float
        The fitted top end (the anchor, NED, m; a walking top end's reference point).
    vehicle_depth_m : float
        The vehicle's median depth over the fit runs, m.
    far : bool
        The anchor is a far point (at least half of ``FAR_ANCHOR_M`` from the runs): a fixed cable direction.
    elevation_deg : float
        The cable's elevation from the vehicle's median position towards the top end, deg (+: up).
    reading : str
        One of :data:`READINGS`: ``at the surface`` (a near top end less than ``SURFACE_TOLERANCE_M`` below it),
        ``below the surface`` (deeper, or pinned at that limit of the search where it would go on deeper, clearly
        better: the fit wants it under water),
        ``rising`` (a far top end above the vehicle) or ``not rising``.
    text : str
        The reading in words; for a top end below the surface or a cable that does not rise, what is missing.
    """

    north_m: float
    east_m: float
    down_m: float
    vehicle_depth_m: float
    far: bool
    elevation_deg: float
    reading: str
    text: str

    def to_json(self) -> dict:
        return asdict(self)


def top_end(params, position, limit_binds: bool = True) -> TopEnd | None:
    """Read a tether fit's top end against the surface and the vehicle's depth.

    Parameters
    ----------
    params : mapping
        The ``tether_drag`` fit's parameters (``anchor_north_m anchor_east_m anchor_down_m``, m).
    position : ndarray, shape (n, 3)
        The vehicle's NED positions over the fit runs (x, y as logged or dead-reckoned, z the depth), m.
    limit_binds : bool
        For a top end pinned at the search's limit (``SURFACE_TOLERANCE_M`` down): whether the fit would go on
        deeper, clearly better (:meth:`~udrobot_ctrl.gap.attribute.Attributor.bound_binds`), i.e. it wants the top
        end under water; when it would not, the runs cannot place the top end within that metre, and it is read at
        the surface.

    Returns
    -------
    TopEnd or None
        None when the fit has no anchor or the runs no finite position.
    """
    if any(k not in params for k in TETHER_ANCHOR):
        return None
    a = np.array([float(params[k]) for k in TETHER_ANCHOR])
    pos = np.asarray(position, float)
    pos = pos[np.all(np.isfinite(pos), axis=1)]
    if not np.all(np.isfinite(a)) or pos.size == 0:
        return None
    centre = np.median(pos, axis=0)
    d = a - centre
    elevation = math.degrees(math.atan2(-d[2], math.hypot(d[0], d[1])))
    far = bool(np.linalg.norm(d) >= 0.5 * FAR_ANCHOR_M)
    depth = float(centre[2])
    pinned = abs(a[2] - SURFACE_TOLERANCE_M) <= AT_LIMIT_M  # at the search's limit
    if far:
        toward = math.degrees(math.atan2(d[1], d[0])) % 360
        if elevation > 0:
            reading, text = READINGS[2], (f"a far top end: the cable rises at {elevation:.0f} deg towards "
                                          f"{toward:03.0f} deg (a float or a boat trailing the vehicle)")
        else:
            reading, text = READINGS[3], (f"a far top end below the vehicle: the cable runs down at {-elevation:.0f} "
                                          f"deg towards {toward:03.0f} deg, where no tether goes; the fit is a "
                                          "free-form force, not that cable")
    elif a[2] < SURFACE_TOLERANCE_M - AT_LIMIT_M or (pinned and not limit_binds):
        how = (f"its fit ends at the search's {SURFACE_TOLERANCE_M:.1f} m limit, but would not go clearly better "
               f"deeper: the runs do not place it within that metre" if pinned else f"{a[2]:.1f} m down")
        reading, text = READINGS[0], (f"at the surface ({how}), {math.hypot(d[0], d[1]):.1f} m across "
                                      f"from the runs' centre; the vehicle at {depth:.1f} m")
    else:
        where = (f"pinned at {a[2]:.1f} m down, the deepest the search lets a top end lie: the fit wants it under water"
                 if pinned else f"{a[2]:.1f} m below the surface")
        below = " and below the vehicle" if a[2] > depth else ""
        reading, text = READINGS[1], (
            f"{where}{below} (the vehicle at {depth:.1f} m): a tether runs up to the surface (a tender, a boat, a "
            f"pier), so this fit is a free-form force, not that cable; missing: where the tether was paid out from "
            f"(its top end's position) and its paid-out length")
    return TopEnd(float(a[0]), float(a[1]), float(a[2]), depth, far, elevation, reading, text)
