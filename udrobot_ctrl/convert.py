"""Real logs in: ROS bags, MAVLink/dataflash logs, QGC CSV, rostopic CSV -> ``udrobot-run/1`` runs.

:func:`load_any` is what other commands call for ``--input``: it dispatches on the file type.
:func:`convert_log` applies a mapping (``udrobot_ctrl.io.mapping``) to a log and returns a :class:`Run`; for an
ArduSub log it also applies what the firmware emulation knows (the motor directions through ArduSub's mixer,
the pilot input through its joystick conversion, gains fitted from its controller messages), so this module sits
above both ``io`` and ``autopilot`` (docs/architecture.md).
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.ardusub.params import ESTIMATED_PARAMS, gain_log_params
from udrobot_ctrl.autopilot.joystick import pilot_input
from udrobot_ctrl.autopilot.motors import MotorParameters, fit_directions, frame, throttle_bidirectional
from udrobot_ctrl.autopilot.validate import fitted_parameters, read_log
from udrobot_ctrl.dynamics.thrusters import PWM_NEUTRAL
from udrobot_ctrl.io.logs import DEFAULT_MAPPINGS, log_kind, motor_evidence, read_streams
from udrobot_ctrl.io.mapping import UNAIDED_NOTE, MappingError, assemble_run, judge_channels, load_mapping, motor_rules
from udrobot_ctrl.io.mavlink import (
    DecodedLog,
    choose_vehicle,
    detect_vehicle,
    ekf_aiding,
    firmware_text,
    motor_command_pwm,
    water_density_from_params,
)
from udrobot_ctrl.io.runlog import (
    PWM_RANGE_US,
    VOLTAGE_RANGE_V,
    Run,
    pulses_outside_range,
    read_run,
    voltages_outside_range,
)
from udrobot_ctrl.io.streams import LogImportError
from udrobot_ctrl.io.stretches import cut_run

PILOT_STREAM = "PILOT_RC"  # the pilot-input stream built from MANUAL_CONTROL (udrobot_ctrl.autopilot.joystick)


def convert_log(path, mapping=None, require_inputs: bool = True, vehicle: str | None = None,
                cut: bool = True) -> Run:
    """Convert a log to a :class:`Run` with a mapping (path, shipped name or :class:`Mapping`).

    Without a mapping, bags use ``bluerov2-mavros``, ``.tlog``/``.bin`` use ``ardusub`` and QGC CSV exports
    ``qgc-csv``. For MAVLink/dataflash logs the damage skipped while reading goes to the notes (``damage:``
    lines), the vehicle goes to the sidecar's ``vehicle`` (``vehicle:`` lines say what was read, inferred and
    assumed), and all its motor outputs are mapped to pwm_1..pwm_n in motor order through the mapping's
    ``[motors]`` table. The vehicle is ``vehicle`` when given, else what the log names (FRAME_CONFIG,
    "Frame: ..." texts, SERVOn_FUNCTION), else inferred from the active motor outputs
    (:func:`~udrobot_ctrl.io.mavlink.choose_vehicle`: an ambiguous log is refused, asking for ``vehicle``).
    With a ``[cut]`` table in the mapping and ``cut`` true, the stretches the plant cannot represent (surface,
    disarmed, upside down) are cut out and every valid stretch a replay can start from is kept as a segment of the
    run (the ``segment`` column; t stays the converted log's t; :func:`~udrobot_ctrl.io.stretches.cut_run`; ``cut:``
    notes, the sidecar's ``cut`` record).

    Parameters
    ----------
    path : str or Path
        The log: ROS 1/2 bag, ``.tlog``, dataflash ``.bin``, ``rostopic echo -p`` CSV or QGC CSV export.
    mapping : str, Path or Mapping, optional
        A mapping file, a shipped mapping name or a Mapping; the default of the log's kind when None.
    require_inputs : bool
        Refuse a log whose mapped input columns (``pwm_i``, ``thrust_i`` or ``tau_*``) are missing; False writes
        them as nan (``convert --allow-missing-inputs``).
    vehicle : str, optional
        Vehicle name (``bluerov2``, ``bluerov2-heavy``, or the mapping's default vehicle): overrides the log.
    cut : bool
        Apply the mapping's ``[cut]`` (False keeps every row).

    Returns
    -------
    Run
        The ``udrobot-run/1`` run (t in s from 0, SI channels; the notes and the sidecar's metadata).
    """
    kind = log_kind(path)
    if mapping is None:
        source = {"tlog": "mavlink", "bin": "mavlink"}.get(kind, kind)
        if source not in DEFAULT_MAPPINGS:
            raise MappingError(f"{path}: a {kind} log needs an explicit mapping (--mapping)")
        mapping = DEFAULT_MAPPINGS[source]
    mapping = load_mapping(mapping)
    decoded = read_streams(path, mapping)
    if isinstance(decoded, DecodedLog):
        facts = decoded.facts
        default = (mapping.metadata.get("vehicle"), mapping.motors.default_servos if mapping.motors else ())
        evidence = motor_evidence(mapping, decoded.streams)
        vehicle = choose_vehicle(detect_vehicle(facts), evidence, vehicle, default, str(path))
        notes = facts.damage.notes(path) + facts.notes + vehicle.notes
        servos = vehicle.motor_servos
        if not servos and mapping.motors:
            servos = mapping.motors.default_servos
            notes.append(f"vehicle: the log does not say which vehicle it is (no FRAME_CONFIG, no 'Frame:' text); "
                         f"mapping default vehicle {mapping.metadata.get('vehicle', '(none)')!r} with motors on "
                         f"servo {', '.join(map(str, servos))} assumed")
        streams = decoded.streams
        if "MANUAL_CONTROL" in streams and any(r.stream == PILOT_STREAM for r in mapping.rules):
            pilot = pilot_input(streams["MANUAL_CONTROL"], streams.get("RC_CHANNELS"), facts.params,
                                facts.named.get("PilotGain"))
            streams = {**streams, PILOT_STREAM: pilot.stream}
            notes += pilot.notes
        aiding = ekf_aiding(facts)  # the sidecar's channels: measured, estimated or estimated-unaided (dead reckoning)
        run = assemble_run(mapping, streams, str(path), extra_notes=notes + list(aiding.notes),
                           require_inputs=require_inputs, log_params=facts.params,
                           extra_rules=motor_rules(mapping, servos), aiding=aiding.of)
        if vehicle.name is not None:
            run.metadata["vehicle"] = vehicle.name
        for note in (silent_outputs(run), unmeasured_voltage(run), apply_motor_directions(run, facts.params)):
            if note:
                run.metadata["notes"] += "\n" + note
        if autopilot_params(facts.params):
            run.metadata["autopilot_params"] = autopilot_params(facts.params)
        if firmware_text(facts):
            run.metadata["firmware"] = firmware_text(facts)
        if kind == "bin":
            note = estimate_autopilot_gains(path, run, facts.params)
            if note:
                run.metadata["notes"] += "\n" + note
        density = water_density_from_params(facts.params)
        if density is not None and "water_density" not in mapping.metadata:
            run.metadata["water_density"] = density[0]
            run.metadata["notes"] += "\n" + density[1]
    else:
        if vehicle is not None:
            raise LogImportError(f"{path}: --vehicle applies to MAVLink / dataflash logs (the outputs of this log "
                                 f"are named by its mapping {mapping.name})")
        run = assemble_run(mapping, decoded, str(path), require_inputs=require_inputs)
    if cut and mapping.cut is not None:
        result = cut_run(run, mapping.cut)
        run = result.run
        run.metadata["notes"] += "\n" + "\n".join(result.notes)
        run.metadata["cut"] = result.record()
        if isinstance(decoded, DecodedLog) and run.n:  # the EKF's aiding judged again on the rows kept
            run.metadata["channels"], kept = judge_channels(run.metadata.get("channels", {}), aiding.of,
                                                            run.extra["t_source"])
            lines = [n for n in run.metadata["notes"].split("\n") if not n.startswith(UNAIDED_NOTE)]
            run.metadata["notes"] = "\n".join(lines + [f"{n} [on the rows the cut kept]" for n in kept])
    run.path = str(path)
    return run


def silent_outputs(run: Run) -> str:
    """The logged motor pulses no ESC reads as a command, in place; returns the note (empty when there are none).

    0 us (MAVLink's and RCOU's "no pulse" of an output not driven) is written as the neutral 1500 us: an ESC
    without a signal stops its motor, so it gives no thrust. Any other pulse outside ArduPilot's servo range
    (:func:`~udrobot_ctrl.io.runlog.pulses_outside_range`, e.g. 65535, "unused") is a damaged record, written as
    not logged.
    """
    if run.input_kind != "pwm" or not run.n:
        return ""
    pwm = np.array(run.inputs, float)
    silent = pwm == 0
    bad = pulses_outside_range(pwm) & ~silent
    pwm[silent] = PWM_NEUTRAL
    pwm[bad] = np.nan
    run.inputs = pwm
    lo, hi = PWM_RANGE_US
    parts = [f"pwm_{k + 1}: {int(silent[:, k].sum())} at 0 us (no pulse: the ESC stops its motor) written as "
             f"{PWM_NEUTRAL:g} us" for k in range(pwm.shape[1]) if silent[:, k].any()]
    parts += [f"pwm_{k + 1}: {int(bad[:, k].sum())} outside {lo:g}..{hi:g} us (no ESC command) written as not "
              f"logged" for k in range(pwm.shape[1]) if bad[:, k].any()]
    return "motors: " + "; ".join(parts) if parts else ""


def unmeasured_voltage(run: Run) -> str:
    """Battery voltages no battery has, in place, written as not measured; returns the note (empty when none).

    A vehicle without a battery monitor logs 0 V (``BAT.Volt``), and MAVLink's ``SYS_STATUS.voltage_battery`` is
    ``UINT16_MAX`` (65.535 V) when the autopilot sends no voltage: both are outside
    :data:`~udrobot_ctrl.io.runlog.VOLTAGE_RANGE_V` (:func:`~udrobot_ctrl.io.runlog.voltages_outside_range`), so
    the replay uses the model's supply voltage there.
    """
    if "voltage" not in run.channels:
        return ""
    v = np.array(run.channels["voltage"], float)
    bad = voltages_outside_range(v)
    if not bad.any():
        return ""
    values = ", ".join(f"{x:g}" for x in np.unique(v[bad])[:3])
    v[bad] = np.nan
    run.channels["voltage"] = v
    lo, hi = VOLTAGE_RANGE_V
    return (f"voltage: {int(bad.sum())} of {v.size} samples outside {lo:g}..{hi:g} V ({values} V: no battery "
            f"monitor, or not sent) written as not measured")


def apply_motor_directions(run: Run, params: dict) -> str:
    """Mirror the logged PWM of motors with ``MOT_k_DIRECTION = -1`` about 1500 us, in place; returns the note.

    ArduSub writes 1500 - (command) to a reversed motor (a propeller of the other hand, or swapped wires), so that
    its thrust still follows the command; after mirroring, ``pwm_k`` > 1500 us means positive thrust along
    thruster k's direction in the vehicle model, as the T-200 curve and the model expect
    (:func:`udrobot_ctrl.io.mavlink.motor_command_pwm`). Nothing is changed when the log holds no
    direction parameters or the run's inputs are not PWM.
    """
    if run.input_kind != "pwm":
        return ""
    n = run.inputs.shape[1]
    dirs = [params.get(f"MOT_{k}_DIRECTION") for k in range(1, n + 1)]
    if all(d is None for d in dirs):
        return infer_motor_directions(run, params)
    known = [1.0 if d is None or not np.isfinite(d) else float(np.sign(d) or 1.0) for d in dirs]
    run.inputs = motor_command_pwm(run.inputs, known)
    reversed_ = [k + 1 for k, d in enumerate(known) if d < 0]
    listed = ", ".join(f"{k + 1}: {'?' if d is None else int(d)}" for k, d in enumerate(dirs))
    return (f"motors: MOT_k_DIRECTION ({listed}) from the log; pwm of reversed motor(s) "
            f"{', '.join(map(str, reversed_)) or 'none'} mirrored about 1500 us (pwm' = 3000 - pwm) so that pwm_k > "
            f"1500 us is thruster k's positive thrust in the vehicle model")


#: ArduSub parameter prefixes kept in the sidecar's ``autopilot_params`` (the controllers, the mixer, the pilot input)
AUTOPILOT_PARAM_PREFIXES = ("ATC_", "PSC_", "MOT_", "PILOT_", "RC1_", "RC2_", "RC3_", "RC4_", "RC5_", "RC6_",
                            "RC7_", "RC8_", "RCMAP_", "JS_", "SURFTRAK_", "WPNAV_", "FRAME_", "SERVO")
AUTOPILOT_PARAM_NAMES = ("ANGLE_MAX", "SCHED_LOOP_RATE", "BARO_SPEC_GRAV", "SURFACE_DEPTH", "THR_DZ", "ACRO_YAW_P")
#: a direction pattern is inferred only when it explains the logged PWM this well (RMS of the normalised
#: command, 1 = full scale) and clearly better than the runner-up: ArduSub truncates its PWM to whole us, 0.0025
#: of full scale, so a right pattern fits to about 0.001 while a wrong one leaves residuals of the command's size
DIRECTION_FIT_RMS = 0.01
DIRECTION_FIT_MARGIN = 3.0


def autopilot_params(params: dict) -> dict:
    """The log's controller, mixer and pilot-input parameters (name -> value, ArduSub units) for the sidecar."""
    return {k: float(v) for k, v in sorted(params.items())
            if (k.startswith(AUTOPILOT_PARAM_PREFIXES) or k in AUTOPILOT_PARAM_NAMES) and np.isfinite(v)}


def estimate_autopilot_gains(path, run: Run, params: dict) -> str:
    """Where a dataflash log lacks the controllers' gains but logs their terms (PIDR/PIDP/PIDY/PIDA, PSCD), fit the
    gains from them (:func:`udrobot_ctrl.autopilot.validate.fitted_parameters`) into the sidecar's
    ``autopilot_params_estimated`` (ArduSub's names and units); returns the note ('' when nothing was estimated).
    The emulated autopilot takes the logged parameters first, these next, ArduSub's defaults last."""
    if "ATC_RAT_RLL_P" in params and "PSC_ACCZ_P" in params:
        return ""
    try:
        fitted = gain_log_params(fitted_parameters(read_log(path)))
    except (KeyError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
        return f"autopilot: no gains in the log and none estimated from its controller messages ({exc})"
    fitted = {k: v for k, v in fitted.items() if k not in params and np.isfinite(v)}
    if not fitted:
        return ""
    run.metadata[ESTIMATED_PARAMS] = fitted
    listed = ", ".join(f"{k} {v:.4g}" for k, v in fitted.items())
    return (f"autopilot: gains not in the log, estimated from its PIDR/PIDP/PIDY/PIDA and PSCD messages (least "
            f"squares of the logged terms on their errors; autopilot_params_estimated): {listed}")


def infer_motor_directions(run: Run, params: dict) -> str:
    """``MOT_k_DIRECTION`` inferred from the logged mixer inputs when the log lacks the parameters; mirrors the PWM of
    reversed motors in place (as :func:`apply_motor_directions`) and returns the note.

    ArduSub's PWM is a known function of its mixer inputs (:mod:`udrobot_ctrl.autopilot.motors`); with the
    attitude and throttle outputs logged (``out_roll``, ``out_pitch``, ``out_yaw``, ``out_throttle``: dataflash
    RATE) and forward / lateral fitted per sample, every sign pattern is tried
    (:func:`~udrobot_ctrl.autopilot.motors.fit_directions`). The pattern is used only when it explains the PWM to
    :data:`DIRECTION_FIT_RMS` and beats the runner-up by :data:`DIRECTION_FIT_MARGIN`; otherwise the PWM is left as
    logged and the note says the directions are unknown (assumed +1).
    """
    names = ("out_roll", "out_pitch", "out_yaw", "out_throttle")
    vehicle = run.metadata.get("vehicle")
    unknown = ("motors: no MOT_k_DIRECTION in the log and {why}: every motor assumed MOT_k_DIRECTION = +1 "
               "(pwm_k > 1500 us = positive thrust); a reversed motor would push the wrong way in the replay")
    if not all(c in run.extra for c in names):
        return unknown.format(why="no logged mixer inputs (dataflash RATE) to infer them from")
    try:
        fr = frame(vehicle)
    except (ValueError, TypeError):
        return unknown.format(why=f"vehicle {vehicle!r} has no known ArduSub frame")
    if fr.n_motors != run.inputs.shape[1]:
        return unknown.format(why=f"frame {fr.name} has {fr.n_motors} motors, the run {run.inputs.shape[1]} pwm "
                                  f"columns")
    known = np.column_stack([run.extra["out_roll"], run.extra["out_pitch"], run.extra["out_yaw"],
                             throttle_bidirectional(run.extra["out_throttle"])])
    moving = np.any(np.abs(run.inputs - 1500.0) > 0.5, axis=1)
    pwm = np.where(moving[:, None], run.inputs, np.nan)
    pmin, pmax = (params.get(k) for k in ("MOT_PWM_MIN", "MOT_PWM_MAX"))
    motors = MotorParameters(pwm_min=float(pmin or 1100.0), pwm_max=float(pmax or 1900.0))
    try:
        fit = fit_directions(fr, known, pwm, motors)
    except ValueError as exc:
        return unknown.format(why=f"too little armed output to infer them ({exc})")
    if not (fit.rms <= DIRECTION_FIT_RMS and fit.runner_up >= DIRECTION_FIT_MARGIN * fit.rms):
        return unknown.format(why=f"the logged mixer inputs do not single them out (best pattern RMS {fit.rms:.4f}, "
                                  f"runner-up {fit.runner_up:.4f} of full scale)")
    run.inputs = motor_command_pwm(run.inputs, fit.directions)
    reversed_ = [k + 1 for k, d in enumerate(fit.directions) if d < 0]
    return (f"motors: MOT_k_DIRECTION not in the log; inferred from the logged mixer inputs (RATE ROut/POut/YOut/AOut, "
            f"forward/lateral fitted per sample, frame {fr.name}) over {fit.samples} samples: "
            f"({', '.join(f'{k + 1}: {d:+d}' for k, d in enumerate(fit.directions))}), residual RMS {fit.rms:.4f} "
            f"of full scale against {fit.runner_up:.4f} for the next pattern (estimated); pwm of reversed motor(s) "
            f"{', '.join(map(str, reversed_)) or 'none'} mirrored about 1500 us (pwm' = 3000 - pwm)")


def load_any(path, mapping=None, require_inputs: bool = True, vehicle: str | None = None) -> Run:
    """A :class:`Run` from any supported file: a ``udrobot-run/1`` CSV is read as is, logs are converted.

    Parameters
    ----------
    path : str or Path
        ``.csv`` (udrobot-run/1 or rostopic echo -p), ``.bag``, ``.mcap``, ``.db3``, ROS 2 bag directory,
        ``.tlog`` or ``.bin``.
    mapping : str, Path or Mapping, optional
        For logs; defaults per type as in :func:`convert_log`.
    require_inputs : bool
        Refuse a log without the mapped input columns, as in :func:`convert_log`.
    vehicle : str, optional
        Vehicle of a MAVLink / dataflash log, as in :func:`convert_log`.

    Returns
    -------
    Run
        The run read or converted.
    """
    if log_kind(path) == "run":
        return read_run(path)
    return convert_log(path, mapping, require_inputs=require_inputs, vehicle=vehicle)
