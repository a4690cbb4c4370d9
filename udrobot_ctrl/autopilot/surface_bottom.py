"""ArduSub's surface and bottom detector and ALT_HOLD's depth-target clamps (ArduSub 4.1.1-4.5), SI, down axis.

Sources (ArduPilot):

* ``ArduSub/surface_bottom_detector.cpp`` ``Sub::update_surface_and_bottom_detector`` (run every main-loop tick
  after the flight mode, ``FAST_TASK`` / ``fast_loop``), ``Sub::set_surfaced``, ``Sub::set_bottomed``
  -> :class:`SurfaceBottomDetector`. With a healthy depth sensor (the only branch emulated here):

  - ``at_surface`` = barometer altitude > ``SURFACE_DEPTH / 100`` (m, up), at once (no counter); once surfaced
    the threshold is 5 cm lower (``SURFACE_DEPTH / 100 - 0.05``, "a 5cm buffer"). On the down axis:
    surfaced when ``depth < d_s``, unsurfaced when ``depth >= d_s + 0.05`` with ``d_s = -SURFACE_DEPTH / 100``.
  - ``at_bottom`` after ``motors.limit.throttle_lower`` and ``|vel_z| < 0.05 m/s`` (``ahrs.get_velocity_NED``)
    held for ``BOTTOM_DETECTOR_TRIGGER_SEC * MAIN_LOOP_RATE`` = 1.0 x 400 *ticks* (``ArduSub/defines.h``,
    ``config.h``): the count is in ticks of the compile-time 400 Hz, so at ``SCHED_LOOP_RATE`` 200 Hz it takes
    2 s. Any tick without the criteria calls ``set_bottomed(false)``, which resets the count only when the flag
    *changes*: while ``at_bottom`` is already false the count is kept across interruptions (emulated as is).
  - disarmed: both flags false.

  Not emulated: the no-depth-sensor branch (surface from ``limit.throttle_upper`` and a still vehicle).

* ``ArduSub/control_althold.cpp`` ``Sub::control_depth`` (Sub-4.1 branch, 4.1.1+) and ``ArduSub/mode_althold.cpp``
  ``ModeAlthold::control_depth`` (4.5), the same law -> :func:`althold_depth_target`: when the pilot's climb rate
  is zero (``fabsf(target_climb_rate_cm_s) < 0.05``, the throttle stick in its dead zone)::

      if at_surface:  pos_target_z = MIN(pos_target_z, SURFACE_DEPTH - 5)            // 5 cm below SURFACE_DEPTH
      elif at_bottom: pos_target_z = MAX(inertial_nav.get_position_z_up_cm() + 10, pos_target_z)   // 10 cm up

  then ``set_pos_target_z_from_climb_rate_cm`` and ``update_z_controller`` as without the clamps. The pilot's
  climb is *not* limited at the surface in 4.1.1-4.5 (only the centred-stick clamp above). Forks built on the
  4.1.0 betas' "depth hold at arbitrary attitudes" rework carry another ``control_depth`` (earth-frame stick
  inputs; climb capped at 0 while ``at_surface`` or the target is above ``SURFACE_DEPTH``, descent at 0 on the
  bottom, the clamps through ``set_alt_target_with_slew``), which 4.1.1's release note "Improve Depth hold
  behavior when surface/bottom is reached" would have replaced (``ArduSub/ReleaseNotes.txt``; ArduPilot's own
  4.1.0 tag was not read): that variant is not emulated. Neither is the surface throttle limit
  ``SURFACE_MAX_THR`` (``motors.set_max_throttle`` in ``control_depth``), which came with ArduPilot PR #29995
  (May 2025), after Sub-4.5.3. SURFTRAK's ``ModeSurftrak::control_range`` (4.5) applies the same two clamps, then
  resets its rangefinder target; SURFTRAK itself is not emulated (:mod:`.fly`).

The detector reads the depth and the velocity the controllers read (the emulation's :class:`VehicleState`); in
ArduSub the surface test reads the barometer and the clamp the EKF's altitude, which agree for a sub whose
barometer was zeroed at the surface.
"""
from __future__ import annotations

from dataclasses import dataclass

#: ``ArduSub/config.h`` ``MAIN_LOOP_RATE``: the detector's counts are in ticks of this rate (Hz), whatever the loop
MAIN_LOOP_RATE = 400
#: ``ArduSub/defines.h`` ``BOTTOM_DETECTOR_TRIGGER_SEC`` (s at MAIN_LOOP_RATE)
BOTTOM_DETECTOR_TRIGGER_SEC = 1.0
#: ``surface_bottom_detector.cpp``: ``vel_stationary`` is ``|vel_z| < 0.05`` m/s
VEL_STATIONARY = 0.05
#: ``surface_bottom_detector.cpp``: once surfaced, the surface threshold is 5 cm deeper (m)
SURFACE_HYSTERESIS = 0.05
#: ``control_depth``: the surface clamp holds the target 5 cm below ``SURFACE_DEPTH`` (m)
SURFACE_TARGET_MARGIN = 0.05
#: ``control_depth``: the bottom clamp raises the target to 10 cm above the current depth (m)
BOTTOM_CLEARANCE = 0.10
#: ``control_depth``: a climb rate below 0.05 cm/s counts as the stick centred (m/s)
CLIMB_RATE_ZERO = 0.05 * 0.01


class SurfaceBottomDetector:
    """``Sub::update_surface_and_bottom_detector`` with a depth sensor (module docstring), its flags and count.

    Parameters
    ----------
    surface_depth : float
        ``-SURFACE_DEPTH / 100`` (m, positive down): shallower than this the vehicle is at the surface.

    Attributes
    ----------
    at_surface, at_bottom : bool
        ``ap.at_surface``, ``ap.at_bottom``.
    bottom_count : int
        ``bottom_detector_count`` (ticks).
    """

    def __init__(self, surface_depth: float):
        self.surface_depth = surface_depth
        self.at_surface = False
        self.at_bottom = False
        self.bottom_count = 0

    def _set_bottomed(self, at_bottom: bool) -> None:
        """``Sub::set_bottomed``: the count restarts only when the flag changes."""
        if self.at_bottom != at_bottom:
            self.at_bottom = at_bottom
            self.bottom_count = 0

    def update(self, depth: float, vel_down: float, throttle_lower: bool, armed: bool = True) -> None:
        """One main-loop tick.

        Parameters
        ----------
        depth : float
            Depth (m, positive down), the depth sensor's.
        vel_down : float
            Vertical velocity (m/s, positive down).
        throttle_lower : bool
            ``motors.limit.throttle_lower`` of this tick's output (the mixer's throttle at -1).
        armed : bool
            False clears both flags.
        """
        if not armed:
            self.at_surface = False
            self._set_bottomed(False)
            return
        threshold = self.surface_depth + (SURFACE_HYSTERESIS if self.at_surface else 0.0)
        self.at_surface = depth < threshold  # set_surfaced: surface_detector_count is unused with a depth sensor
        if throttle_lower and abs(vel_down) < VEL_STATIONARY:
            if self.bottom_count < BOTTOM_DETECTOR_TRIGGER_SEC * MAIN_LOOP_RATE:
                self.bottom_count += 1
            else:
                self._set_bottomed(True)
        else:
            self._set_bottomed(False)


@dataclass(frozen=True)
class DepthTargetClamp:
    """What :func:`althold_depth_target` did to the depth target in one tick.

    Attributes
    ----------
    target : float
        The depth target after the clamp (m, positive down).
    reason : str
        ``"surface"``, ``"bottom"`` or ``""`` (unchanged).
    """

    target: float
    reason: str = ""


def althold_depth_target(pos_target: float, depth: float, climb_rate: float, at_surface: bool, at_bottom: bool,
                         surface_depth: float) -> DepthTargetClamp:
    """ALT_HOLD's surface and bottom clamps of the depth target (``control_depth``, module docstring), down axis.

    Parameters
    ----------
    pos_target : float
        The depth target (m, positive down).
    depth : float
        Current depth (m, positive down).
    climb_rate : float
        The pilot's climb-rate demand (m/s, positive up); the clamps act only when it is zero.
    at_surface, at_bottom : bool
        The detector's flags.
    surface_depth : float
        ``-SURFACE_DEPTH / 100`` (m, positive down).

    Returns
    -------
    DepthTargetClamp
        At the surface the target is at least ``surface_depth + 0.05`` m deep; on the bottom at most 0.10 m
        below the vehicle (``MAX(z_up + 10 cm, target_up)``).
    """
    if abs(climb_rate) >= CLIMB_RATE_ZERO:
        return DepthTargetClamp(pos_target)
    if at_surface:
        floor = surface_depth + SURFACE_TARGET_MARGIN
        return DepthTargetClamp(floor, "surface") if pos_target < floor else DepthTargetClamp(pos_target)
    if at_bottom:
        ceiling = depth - BOTTOM_CLEARANCE
        return DepthTargetClamp(ceiling, "bottom") if pos_target > ceiling else DepthTargetClamp(pos_target)
    return DepthTargetClamp(pos_target)


__all__ = ["BOTTOM_CLEARANCE", "DepthTargetClamp", "MAIN_LOOP_RATE", "SurfaceBottomDetector",
           "althold_depth_target"]
