"""A check flight for designed ArduSub gains: what to fly, per axis, to verify them and to identify the vehicle.

Each designed loop gets a *doublet* (a step one way, a step back through the start to the other side, back to
the start) flown by the pilot in the mode that closes that loop: STABILIZE for roll, pitch and yaw, ALT_HOLD for
depth. The stick deflection that commands the step follows ArduSub's pilot input mapping (:mod:`.params`):

* roll and pitch (STABILIZE, ``Sub::get_pilot_desired_lean_angles``): the lean-angle target is the stick
  fraction times ``ANGLE_MAX``, so a step of ``A`` is ``A / ANGLE_MAX`` of full stick;
* yaw (STABILIZE, ``Sub::get_pilot_desired_yaw_rate``): the stick commands a yaw *rate*, ``ACRO_YAW_P`` times the
  stick in centidegrees (full stick ``4500 ACRO_YAW_P`` cdeg/s); a heading step of ``A`` is the stick held at a
  fraction ``f`` for ``A / (f x full rate)`` seconds;
* depth (ALT_HOLD, ``Sub::get_pilot_desired_climb_rate``): outside the throttle dead zone ``THR_DZ`` the stick
  commands a climb rate up to ``PILOT_SPEED_UP`` (down ``PILOT_SPEED_DN``, 0 = the same); a depth step of ``A`` is
  the stick held for ``A / rate`` seconds.

The amplitudes are the design's steps (:data:`.design.STEP_SIZE`: 10 deg roll and pitch, 45 deg heading, 1 m
depth), limited to half of ``ANGLE_MAX`` for roll and pitch (the lean-angle limit the stick cannot pass); each
level is held for twice the settling time the design predicts with the new gains on the nominal model, or twice
the specification's when the prediction does not settle: long enough to see the settling the design claims.
Depth manoeuvres start at least twice the amplitude below the surface and above the seabed. The log of this
flight (dataflash, with its parameters) converted by ``udrobot-ctrl convert`` is what ``diagnose`` needs to tell
apart the look-alike effects the gains' predictions depend on: steps of both signs on every axis, from rest.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from udrobot_ctrl.ardusub.params import ArduSubParameters

#: the mode (ArduSub custom mode name) each loop is flown in
LOOP_MODE = {"roll": "STABILIZE", "pitch": "STABILIZE", "yaw": "STABILIZE", "depth": "ALT_HOLD"}
#: ArduSub's full stick in centidegrees (RC control_in of roll, pitch, yaw)
FULL_STICK_CDEG = 4500.0
#: the yaw stick fraction used for a heading step: a quarter of full stick, *chosen* to give a rate a pilot can
#: hold for a second or more at ArduSub's default ACRO_YAW_P (about 38 deg/s)
YAW_STICK_FRACTION = 0.25
#: the throttle stick fraction of the depth step (half stick: half of PILOT_SPEED_UP outside the dead zone)
THROTTLE_STICK_FRACTION = 0.5


@dataclass(frozen=True)
class Manoeuvre:
    """One doublet of the check flight.

    Attributes
    ----------
    loop : str
    mode : str
        ArduSub mode to fly it in.
    amplitude : float
        Step size (deg or m).
    unit : str
    stick_pct : float
        Stick deflection (% of full, from centre) that commands it.
    stick_s : float or None
        How long to hold the stick (s) for the rate-commanded axes (yaw, depth); None for roll and pitch, where
        the stick is held for the whole level.
    hold_s : float
        How long to hold each level (s).
    instruction : str
        The checklist line.
    """

    loop: str
    mode: str
    amplitude: float
    unit: str
    stick_pct: float
    stick_s: float | None
    hold_s: float
    instruction: str


def _hold(design, loop: str) -> float:
    d = design.loops[loop]
    settle = d.nominal_new.settling_s
    base = settle if settle is not None and math.isfinite(settle) else design.spec.settling_s(loop)
    return float(math.ceil(2.0 * base))


def check_flight(design, step_size: dict) -> list:
    """The doublets (:class:`Manoeuvre`) of the designed loops of ``design``, with the stick mapping of its
    parameters (see the module notes).

    Parameters
    ----------
    design : ArduSubDesign
        The design (:func:`~udrobot_ctrl.autopilot.design.design_ardusub`); only its designed loops are flown.
    step_size : dict
        Loop -> step size: rad for ``roll``, ``pitch`` and ``yaw``, m for ``depth``
        (:data:`udrobot_ctrl.autopilot.design.STEP_SIZE`).

    Returns
    -------
    list of Manoeuvre
        One doublet per designed loop: mode, amplitude (deg or m), stick deflection (%) and hold times (s).
    """
    params: ArduSubParameters = design.parameters()
    pilot, depth = params.pilot, params.depth
    out = []
    for loop, d in design.loops.items():
        if not d.designed:
            continue
        hold = _hold(design, loop)
        mode = LOOP_MODE[loop]
        if loop in ("roll", "pitch"):
            amp = min(math.degrees(step_size[loop]), 0.5 * math.degrees(pilot.angle_max))
            pct = 100.0 * amp / math.degrees(pilot.angle_max)
            text = (f"{mode}, level and still: {loop} stick {pct:.0f} % one way for {hold:g} s (a {amp:.0f} deg "
                    f"{loop} target), {pct:.0f} % the other way for {hold:g} s, centre and hold {hold:g} s")
            out.append(Manoeuvre(loop, mode, amp, "deg", pct, None, hold, text))
        elif loop == "yaw":
            amp = math.degrees(step_size["yaw"])
            rate = YAW_STICK_FRACTION * FULL_STICK_CDEG * pilot.acro_yaw_p / 100.0  # deg/s
            stick_s = amp / rate
            text = (f"{mode}, still: yaw stick {100 * YAW_STICK_FRACTION:.0f} % right for {stick_s:.1f} s (about "
                    f"{amp:.0f} deg at {rate:.0f} deg/s), release and hold {hold:g} s; the same left twice "
                    f"({2 * stick_s:.1f} s), release and hold {hold:g} s; right {stick_s:.1f} s back to the start")
            out.append(Manoeuvre(loop, mode, amp, "deg", 100 * YAW_STICK_FRACTION, stick_s, hold, text))
        else:
            amp = step_size["depth"]
            dz = pilot.throttle_deadzone / 500.0  # THR_DZ of the 500 stick units either side of centre
            frac = max((THROTTLE_STICK_FRACTION - dz) / (1.0 - dz), 0.0)
            down = depth.speed_down_effective * frac
            up = abs(depth.speed_up) * frac
            text = (f"{mode} at least {2 * amp:g} m deep and {2 * amp:g} m above the seabed: throttle stick "
                    f"{100 * THROTTLE_STICK_FRACTION:.0f} % down for {amp / down:.1f} s (about {amp:g} m at "
                    f"{down:.2f} m/s), centre and hold {hold:g} s; {100 * THROTTLE_STICK_FRACTION:.0f} % up for "
                    f"{2 * amp / up:.1f} s, centre and hold {hold:g} s; down {amp / down:.1f} s back, hold {hold:g} s")
            out.append(Manoeuvre(loop, mode, amp, "m", 100 * THROTTLE_STICK_FRACTION, amp / down, hold, text))
    return out


def checklist_markdown(design, manoeuvres) -> str:
    """The check flight as a Markdown checklist (the file ``design ardusub --report`` writes)."""
    lines = [f"# Check flight for the gains designed on {design.model}", ""]
    if not design.safe:
        lines += ["The new gains fail the specification and were not written without `--force` "
                  f"({'; '.join(design.refusal)}). Fly these doublets with the current gains to log the "
                  "vehicle's own response for `diagnose` (the identification), or with a `--force` file only if "
                  "you accept those failures.", ""]
    lines += [
             "Load the new parameters, arm at the surface, dive to a clear area, log (dataflash, with parameters) "
             "and fly each doublet from rest, sticks centred between them:", ""]
    for m in manoeuvres:
        lines.append(f"- [ ] **{m.loop}** ({m.mode}): {m.instruction}")
    lines += ["", "Then `udrobot-ctrl convert` the log and `udrobot-ctrl diagnose` it against the model the gains "
              "were designed on: a step that overshoots or settles differently from the prediction names the "
              "part of the model to correct before redesigning.", ""]
    return "\n".join(lines)


__all__ = ["LOOP_MODE", "Manoeuvre", "check_flight", "checklist_markdown"]
