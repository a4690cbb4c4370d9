"""ArduSub's emulated autopilot against every ArduSub log in ../shared/data: motor outputs from the logged pilot inputs.

    PYTHONPATH=. python bench/autopilot.py [LOG ...] [--log LOG] [--json] [--pid]

For each log (default: the three of ``../shared/data/ardusub_log_tools`` and the sea dive of
``../shared/data/guided_above_terrain``), converted with every row kept (``convert_log(cut=False)``), the emulated
ArduSub (:func:`udrobot_ctrl.autopilot.feedback.motor_output_check`: the log's own parameters, ArduSub's
defaults for the missing ones, the logged modes, armed state, pilot inputs ``rcin_i`` and GUIDED targets, one tick
per grid row on the logged states) is mixed by the log's frame into PWM (``motors.mix``, ``to_pwm``) and compared
with the logged motor outputs (RCOU for dataflash, SERVO_OUTPUT_RAW for tlogs): per channel the NRMSE (RMSE / std
of the logged channel) and the RMSE (us), at the rows where a logged output sample lands (every row when the
outputs never change). Logs with PID records (PIDR/PIDP/PIDY/PIDA) also get, with ``--pid``, the term-by-term
check of :mod:`udrobot_ctrl.autopilot.validate` (emulated P/I/D terms and RCOU on the logged mixer inputs); a log
without them is compared on its motor outputs alone. The cost of one ``ArduSubAutopilot.step`` ends the output.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from udrobot_ctrl.ardusub.modes import Mode, PilotInput
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, VehicleState
from udrobot_ctrl.autopilot.feedback import motor_output_check
from udrobot_ctrl.autopilot.validate import check_log, read_log
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.vehicle import load_model

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LOGS = (SHARED / "ardusub_log_tools" / "small.BIN", SHARED / "ardusub_log_tools" / "small.tlog",
        SHARED / "ardusub_log_tools" / "2023-04-18 11-03-34.tlog",
        SHARED / "guided_above_terrain" / "00000029_filtered.BIN")
PID_AXES = ("PIDR", "PIDP", "PIDY", "PIDA")


def output_check(path: Path) -> tuple:
    """(vehicle, :class:`~udrobot_ctrl.autopilot.feedback.MotorOutputCheck`, seconds) of ``path`` converted with
    every row kept."""
    run = convert_log(path, cut=False)
    vehicle = run.metadata.get("vehicle") or "bluerov2-heavy"
    t0 = time.perf_counter()
    check = motor_output_check(run, plant_parameters(load_model(vehicle)))
    return vehicle, check, time.perf_counter() - t0


def summary(name: str, vehicle: str, check, seconds: float) -> str:
    """The printed block of one log."""
    modes = ", ".join(f"{k} {v}" for k, v in check.mode_rows.items())
    return "\n".join([
        f"{name}: {vehicle} ({check.frame}), {check.rows.size} rows compared ({modes}; "
        f"{100 * check.armed_fraction:.0f}% armed), {len(check.assumed)} parameters defaulted, {seconds:.1f} s",
        "  NRMSE per motor:  " + " ".join(f"{x:6.3f}" for x in check.nrmse),
        "  RMSE us:          " + " ".join(f"{x:6.1f}" for x in check.rmse_us),
        "  logged std us:    " + " ".join(f"{x:6.1f}" for x in check.logged_std_us)])


def step_cost(n: int = 4000) -> float:
    """Microseconds per ``ArduSubAutopilot.step`` in ALT_HOLD (attitude + depth loops)."""
    ap = ArduSubAutopilot()
    state = VehicleState(depth=3.0, rates=(0.01, -0.02, 0.03))
    pilot = PilotInput.centred()
    t0 = time.perf_counter()
    for _ in range(n):
        ap.step(0.0025, state, pilot, Mode.ALT_HOLD)
    return (time.perf_counter() - t0) / n * 1e6


def pid_check(path: Path) -> dict | None:
    """The term-by-term check of :func:`~udrobot_ctrl.autopilot.validate.check_log` (None without PID records)."""
    if path.suffix.lower() != ".bin":
        return None
    log = read_log(path)
    if not all(ax in log.messages for ax in PID_AXES):
        print(f"{path.name}: no PID records ({', '.join(a for a in PID_AXES if a not in log.messages)} missing): "
              f"term-by-term check skipped")
        return None
    check = check_log(log, "default")
    print(check.summary())
    return {"rcou_mixer": [round(x, 4) for x in check.rcou_mixer],
            "rcou_emulated": [round(x, 4) for x in check.rcou_emulated]}


def _finite(x: float):
    return round(x, 4) if math.isfinite(x) else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path, help="ArduSub .bin/.tlog logs (default: the shared ones)")
    ap.add_argument("--log", type=Path, action="append", default=[], help="a log (as the positional LOG; repeatable)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--pid", action="store_true", help="also the PID term check on dataflash logs with PID records")
    args = ap.parse_args(argv)
    paths = (args.logs + args.log) or [p for p in LOGS if p.exists()]
    if not paths:
        print(f"no ArduSub log given and none found under {SHARED}", file=sys.stderr)
        return 1
    out = {}
    for path in paths:
        if not path.exists():
            print(f"{path}: not found", file=sys.stderr)
            return 1
        vehicle, check, seconds = output_check(path)
        print(summary(path.name, vehicle, check, seconds))
        out[path.name] = {"vehicle": vehicle, "frame": check.frame, "rows": int(check.rows.size),
                          "nrmse": [_finite(x) for x in check.nrmse], "rmse_us": [_finite(x) for x in check.rmse_us],
                          "modes": check.mode_rows}
        if args.pid:
            pid = pid_check(path)
            if pid is not None:
                out[path.name]["pid"] = pid
    cost = step_cost()
    print(f"ArduSubAutopilot.step: {cost:.0f} us (ALT_HOLD); 1 s at 400 Hz = {cost * 400 / 1e6:.3f} s")
    out["step_us"] = round(cost, 1)
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
