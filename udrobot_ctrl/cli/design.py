"""``udrobot-ctrl design ardusub``: ArduSub's own gains designed on a model, written as a QGroundControl file."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from udrobot_ctrl.ardusub.params import run_log_params
from udrobot_ctrl.autopilot.check_flight import check_flight, checklist_markdown
from udrobot_ctrl.autopilot.design import (
    LOOP_PARAMETERS,
    LOOPS,
    STEP_SIZE,
    Specification,
    design_ardusub,
    plot_loop,
    prediction_sensitivity,
)
from udrobot_ctrl.autopilot.firmware import (
    ASSUMED_FIRMWARE,
    UnverifiedConversion,
    firmware_name,
    firmware_of_run,
    from_firmware,
    parse_firmware,
    range_violations,
    to_firmware,
)
from udrobot_ctrl.autopilot.qgc_params import format_params, read_params
from udrobot_ctrl.io.mavlink import ARDUSUB_FRAMES
from udrobot_ctrl.io.runlog import read_metadata
from udrobot_ctrl.vehicle import ALL_MODEL_NAMES, load_model
from udrobot_files.output import atomic_write, check_command, sidecar, spec_files

#: the files ``--report DIR`` holds
REPORT_FILES = ("design.json", "check_flight.md", *(f"step_{lp}.png" for lp in LOOPS))


def register(subparsers):
    """Add ``design`` with the sub-command ``ardusub``."""
    parser = subparsers.add_parser(
        "design", help="design the vehicle's own autopilot gains on a model (ArduSub -> .params file)",
        description="Design a vehicle autopilot's own gains on a model and write them in the autopilot's format.")
    sub = parser.add_subparsers(dest="design_command", required=True, metavar="{ardusub}")
    p = sub.add_parser(
        "ardusub", help="ArduSub's attitude and depth gains -> QGroundControl .params",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Tune ArduSub's cascaded gains (attitude angle P and rate PID for roll, pitch, yaw; depth\n"
                    "position P, velocity P, acceleration PID) on model M with the emulated ArduSub in closed loop\n"
                    "(udrobot_ctrl/autopilot/design.py), starting from the log's gains (--from) or ArduSub's\n"
                    "defaults, for the specifications below and no thruster at its limit in a 1 m depth step or\n"
                    "a 45 deg yaw step. The new gains are checked on the model's spread of coefficient sets\n"
                    "(UDrobot: the five sets; BlueROV2: the Wu2018 alternative and a low-damping corner; a\n"
                    "corrected model: with and without its effects), and every loop must keep 45 deg of phase\n"
                    "and 6 dB of gain margin on each of them (its frequency response with the IMU and PID\n"
                    "filters, the motor lag and the loop delays). Every gain stays inside the range ArduSub\n"
                    "documents for the firmware (--firmware, else the run's sidecar, else <= 4.6 assumed).\n"
                    "Writes only the parameters that change, in the names and units that firmware loads\n"
                    "(PSC_POSZ_P/VELZ/ACCZ up to 4.6, PSC_D_POS/D_VEL/D_ACC from 4.7), as a QGroundControl\n"
                    "parameter file (Parameters > Tools > Load from file). Gains that fail the specification\n"
                    "are reported with the failing figure and not written without --force; a gain outside\n"
                    "ArduSub's documented range is never written.",
        epilog="example: udrobot-ctrl design ardusub --model bluerov2-heavy --out gains.params --report design_out")
    p.add_argument("--model", required=True, help=f"model name ({', '.join(ALL_MODEL_NAMES)}) or model file "
                                                  f"(e.g. diagnose --out-model's corrected model)")
    p.add_argument("--from", dest="from_", metavar="RUN.csv|GAINS.params",
                   help="start from this vehicle's parameters: a converted run (its sidecar's autopilot_params, "
                        "else autopilot_params_estimated) or a .params file; ArduSub's defaults otherwise")
    p.add_argument("--out", required=True, help="the QGroundControl .params file to write")
    p.add_argument("--report", metavar="DIR", help="folder for design.json, check_flight.md (the doublets to fly "
                                                   "to check the gains), one step plot per loop and the "
                                                   "sensitivity of the predictions")
    p.add_argument("--loops", default=",".join(LOOPS), help=f"comma-separated loops to design (default "
                                                            f"{','.join(LOOPS)})")
    p.add_argument("--spread", action="append", default=[], metavar="MODEL",
                   help="a further model the gains must stay safe on (repeatable)")
    p.add_argument("--depth-settling", type=float, default=Specification.depth_settling_s, metavar="S",
                   help="settling time (2 %%) of the 1 m depth step, s (default %(default)s)")
    p.add_argument("--depth-overshoot", type=float, default=Specification.depth_overshoot_pct, metavar="PCT",
                   help="overshoot of the depth step, %% (default %(default)s)")
    p.add_argument("--yaw-settling", type=float, default=Specification.yaw_settling_s, metavar="S",
                   help="settling time (5 %%) of the 45 deg yaw step, s (default %(default)s)")
    p.add_argument("--yaw-overshoot", type=float, default=Specification.yaw_overshoot_pct, metavar="PCT",
                   help="overshoot of the yaw step, %% (default %(default)s)")
    p.add_argument("--loop-rate", type=float, default=100.0, metavar="HZ",
                   help="the emulated autopilot's rate in the design flights (default %(default)s Hz)")
    p.add_argument("--firmware", metavar="VERSION",
                   help="the ArduSub version the file is for (e.g. 4.5, 4.7.0): its parameter names, units and "
                        "ranges; default: the run's sidecar (--from RUN.csv), else <= 4.6 names (assumed, said so)")
    p.add_argument("--evaluations", type=int, default=12, metavar="N",
                   help="flights per loop in the search (default %(default)s)")
    p.add_argument("--no-sensitivity", action="store_true", help="with --report: skip the sensitivity study")
    p.add_argument("--force", action="store_true",
                   help="write the gains even when they fail the specification (never outside ArduSub's ranges), "
                        "and replace existing output files")
    p.set_defaults(func=run)


def _start_params(path, firmware=None) -> tuple:
    """(parameters in the canonical names and ArduSub units, description, firmware the run names or None) from a
    run CSV's sidecar or a .params file; a 4.7+ file's PSC_D_* names are read back to the canonical ones."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"--from {path}: no such file")
    if path.suffix.lower() in (".params", ".param", ".parm"):
        return from_firmware(read_params(path), firmware), f"the parameters of {path}", None
    meta_path = path if path.suffix.lower() == ".json" else sidecar(path)
    if not meta_path.exists():
        raise FileNotFoundError(f"--from {path}: its sidecar {meta_path} (udrobot-run/1 metadata) does not exist")
    metadata = read_metadata(meta_path)
    params, note = run_log_params(metadata)
    if not params:
        raise ValueError(f"--from {path}: the sidecar {meta_path} holds no autopilot_params or "
                         f"autopilot_params_estimated; run without --from to start from ArduSub's defaults")
    logged = firmware_of_run(metadata)
    return (from_firmware(params, firmware or logged),
            f"the log's parameters ({meta_path})" + (f"; {note}" if note else ""), logged)


def check_thruster_counts(model, spread, log_params: dict, source) -> None:
    """Refuse, before any flight, a design whose inputs disagree on the vehicle's thrusters: a ``--spread`` model
    with another thruster count than ``--model`` (one mixer cannot fly both), or a ``--from`` log whose
    ``FRAME_CONFIG`` names a frame of another motor count (``ArduSub/Parameters.cpp`` FRAME_CONFIG @Values;
    :data:`~udrobot_ctrl.io.mavlink.ARDUSUB_FRAMES`): a Heavy's gains are tuned for eight thrusters.

    Raises
    ------
    ValueError
        Naming the option, both counts and both models or the log.
    """
    nominal = load_model(model)
    n = nominal.n_thrusters
    for other in spread:
        k = load_model(other).n_thrusters
        if k != n:
            raise ValueError(f"--spread {other}: {k} thrusters, but --model {model} has {n}; the spread holds models "
                             f"of the same vehicle (the designed gains drive one mixer)")
    frame_config = log_params.get("FRAME_CONFIG")
    if frame_config is not None and int(frame_config) in ARDUSUB_FRAMES:
        label, motors, _ = ARDUSUB_FRAMES[int(frame_config)]
        if motors is not None and motors != n:
            raise ValueError(f"--from {source}: FRAME_CONFIG {int(frame_config)} ({label}) is a {motors}-thruster "
                             f"vehicle, but --model {model} has {n} thrusters; design on the model of that vehicle "
                             f"(e.g. {'bluerov2-heavy' if motors == 8 else 'bluerov2'}) or start without --from")


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{v:.2f}" if isinstance(v, float) and math.isfinite(v) else str(v)


def run(args) -> int:
    loops = tuple(lp.strip() for lp in args.loops.split(",") if lp.strip())
    for lp in loops:
        if lp not in LOOPS:
            raise ValueError(f"--loops: unknown loop {lp!r} (expected some of {', '.join(LOOPS)})")
    if args.evaluations < 1:
        raise ValueError(f"--evaluations must be >= 1, got {args.evaluations}")
    for name in ("depth_settling", "depth_overshoot", "yaw_settling", "yaw_overshoot"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):  # inf would be a specification every flight meets
            raise ValueError(f"--{name.replace('_', '-')} must be a finite number > 0, got {value}")
    if not (math.isfinite(args.loop_rate) and 10.0 <= args.loop_rate <= 2000.0):
        raise ValueError(f"--loop-rate must be between 10 and 2000 Hz (ArduSub runs 50-400 Hz, AP_Scheduler "
                         f"LOOP_RATE), got {args.loop_rate}")
    inputs = [*spec_files(args.model, *args.spread), *([args.from_] if args.from_ else [])]
    check_command({"--out": args.out}, inputs, force=args.force,
                  folders={"--report": (args.report, REPORT_FILES) if args.report else None})
    given = parse_firmware(args.firmware, f"--firmware {args.firmware}") if args.firmware else None
    if args.from_:
        log_params, origin, logged = _start_params(args.from_, given)
    else:
        log_params, origin, logged = {}, "ArduSub's defaults (no --from: the vehicle's current gains taken as " \
                                         "ArduSub's defaults)", None
    check_thruster_counts(args.model, args.spread, log_params, args.from_)
    firmware = given or logged or ASSUMED_FIRMWARE
    if given and logged and (given.major, given.minor) != (logged.major, logged.minor):
        print(f"note: --firmware {args.firmware} overrides the run's {logged.label} ({logged.source})")
    spec = Specification(depth_settling_s=args.depth_settling, depth_overshoot_pct=args.depth_overshoot,
                         yaw_settling_s=args.yaw_settling, yaw_overshoot_pct=args.yaw_overshoot)
    design = design_ardusub(args.model, log_params, spec, loop_rate_hz=args.loop_rate, loops=loops,
                            spread_extra=args.spread, max_evaluations=args.evaluations, firmware=firmware)
    print(f"ArduSub gains for {design.model} (frame {design.frame_name}), from {origin}")
    print(f"firmware: {firmware.label} ({firmware.source}): names, units and ranges of that version")
    for v in range_violations(gain_values_of(design, "old"), firmware):
        print(f"note: the current {v.sentence()}")
    print(f"{'parameter':16s} {'current':>9s} {'new':>9s}  {'(as ' + firmware.label + ' names it)'}")
    for loop in LOOPS:
        for name in LOOP_PARAMETERS[loop]:
            d = design.loops[loop]
            mark = "" if d.new[name] != d.old[name] else "   (unchanged)"
            try:
                fname, scale = firmware_name(name, firmware)
                shown = "" if fname == name else f"   {fname} {d.old[name] * scale:.4g} -> {d.new[name] * scale:.4g}"
            except UnverifiedConversion:
                shown = "   (no verified name in this version)"
            print(f"{name:16s} {d.old[name]:9.4g} {d.new[name]:9.4g}{mark}{shown}")
    _print_margins(design)
    print(f"\n{'loop':6s} {'gains':4s} {'settling s':>15s} {'overshoot %':>15s} {'IAE s':>13s} {'max cmd':>11s} "
          f"{'spread (new)':>14s}")
    print("(old->new on the nominal model; settling: '-' = not settled in the flight)")
    for loop, d in design.loops.items():
        o, n = d.nominal_old.summary(), d.nominal_new.summary()
        stable = sum(r.stable for r in d.spread_new)
        if not d.designed:
            print(f"{loop:6s} kept  not designed: {d.note}")
            continue
        kind = "new" if d.designed else "kept"
        met = not [f for f in design.failures if f.loop.split("_")[0] == loop]
        print(f"{loop:6s} {kind:4s} {_fmt(o['settling_s']):>7s}->{_fmt(n['settling_s']):>7s} "
              f"{_fmt(o['overshoot_pct']):>7s}->{_fmt(n['overshoot_pct']):>7s} {_fmt(o['iae_s']):>6s}->"
              f"{_fmt(n['iae_s']):>6s} {_fmt(o['max_command']):>5s}->{_fmt(n['max_command']):>5s} "
              f"{stable}/{len(d.spread_new)} stable  spec {'met' if met else 'NOT met'}"
              + ("" if not d.note else f"  [{d.note}]"))
    for note in design.notes:
        print(f"note: {note}")
    changed = design.changed_params()
    if args.report:
        report = Path(args.report)
        report.mkdir(parents=True, exist_ok=True)
        doc = design.to_dict()
        doc["started_from"] = origin
        if not args.no_sensitivity:
            try:
                sens = prediction_sensitivity(design, args.model)
                doc["sensitivity"] = {"parameters": sens.names, "elasticity": {m: [_num(v) for v in e] for m, e in
                                                                               sens.elasticity.items()},
                                      "low": {m: [_num(v) for v in e] for m, e in sens.low.items()},
                                      "high": {m: [_num(v) for v in e] for m, e in sens.high.items()},
                                      "base": {m: _num(v) for m, v in sens.base.items()}}
                _print_sensitivity(sens)
            except ValueError as exc:
                doc["sensitivity"] = {"skipped": str(exc)}
                print(f"sensitivity: skipped ({exc})")
        manoeuvres = check_flight(design, STEP_SIZE)
        doc["check_flight"] = [m.__dict__ for m in manoeuvres]
        atomic_write(report / "design.json", json.dumps(doc, indent=1) + "\n", force=True)
        atomic_write(report / "check_flight.md", checklist_markdown(design, manoeuvres), force=True)
        for loop in LOOPS:
            plot_loop(design, loop, report / f"step_{loop}.png")
        print(f"report: {report}/design.json, check_flight.md (what to fly to check the gains), step_<loop>.png "
              f"for {', '.join(LOOPS)}")
    code, sentence = design.verdict()
    print(f"verdict: {sentence}")
    for f in design.current_failures():
        print(f"current gains: {f.sentence()}")
    hard = [f for f in design.failures if f.code in ("out_of_range", "unwritable")]
    try:
        values = to_firmware(changed, firmware)
    except UnverifiedConversion as exc:
        hard.append(exc)
        values = {}
    if hard:
        for f in hard:
            print(f"REFUSED: {f.sentence() if hasattr(f, 'sentence') else f}")
        print(f"not written: {args.out} (a gain {firmware.label} cannot load as designed; --force does not override "
              f"ArduSub's documented ranges)")
        return 1
    if not design.safe:
        for f in design.failures:
            print(f"NOT MET: {f.sentence()}")
        if not args.force:
            print(f"not written: {args.out} (the specification is not met; --force writes the gains anyway)")
            return 1
    if not changed:
        print(f"no gain changes: the current gains already are the design; {args.out} not written")
        return 0
    comments = [f"ArduSub gains designed by udrobot-ctrl design ardusub on model {design.model} "
                f"(frame {design.frame_name}), from {origin}",
                f"for {firmware.label} ({firmware.source}): only the parameters that change, in that version's "
                f"names and units"]
    if not design.safe:
        comments.append("SPECIFICATION NOT MET (written with --force): " + "; ".join(design.refusal))
    atomic_write(args.out, format_params(values, comments=comments), force=True)
    print(f"wrote {args.out}: {len(values)} parameters ({firmware.label} names)")
    return 0


def gain_values_of(design, which: str) -> dict:
    """The designed loops' current (``old``) or ``new`` gains, canonical names."""
    return {n: v for d in design.loops.values() for n, v in getattr(d, which).items()}


def _print_margins(design) -> None:
    """Phase / gain margins of every loop on every model, current gains -> new."""
    print("\nmargins (phase deg / gain dB; current -> new; required "
          f"{design.spec.phase_margin_deg:g} deg / {design.spec.gain_margin_db:g} dB on every model)")
    for d in design.loops.values():
        new = d.margins_new or d.margins_old
        for o, n in zip(d.margins_old, new):
            flag = "" if n.meets(design.spec.phase_margin_deg, design.spec.gain_margin_db) else "  below spec"
            print(f"  {o.loop:10s} {o.model:34s} {_fmt(o.phase_margin_deg):>7s}/{_fmt(o.gain_margin_db):>6s} -> "
                  f"{_fmt(n.phase_margin_deg):>7s}/{_fmt(n.gain_margin_db):>6s}{flag}")


def _num(v):
    return None if v is None or not math.isfinite(float(v)) else round(float(v), 4)


def _print_sensitivity(sens) -> None:
    print("\nsensitivity of the predictions with the new gains (metric at the low / high end of each coefficient):")
    for metric in ("depth_settling_s", "depth_iae_s", "yaw_settling_s", "yaw_iae_s"):
        if metric not in sens.base:
            continue
        parts = [f"{n} {_fmt(lo)}/{_fmt(hi)}" for n, lo, hi in zip(sens.names, sens.low[metric], sens.high[metric])
                 if n.split(".")[0] == ("heave" if metric.startswith("depth") else "yaw")]
        print(f"  {metric} (nominal {_fmt(sens.base[metric])}): " + ", ".join(parts))
