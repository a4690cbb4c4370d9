"""ArduSub's emulated autopilot against every ArduSub log in ../shared/data: motor outputs from the logged pilot inputs.

    PYTHONPATH=. python bench/autopilot.py [LOG ...] [--json] [--pid]

For each log (default: the three of ``../shared/data/ardusub_log_tools`` and the sea dive of
``../shared/data/guided_above_terrain``), converted with every row kept (``convert_log(cut=False)``), the emulated
ArduSub (:func:`udrobot_ctrl.autopilot.feedback.emulated_mixer_inputs`: the log's own parameters, ArduSub's
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
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, VehicleState
from udrobot_ctrl.autopilot.feedback import changed_rows, emulated_mixer_inputs
from udrobot_ctrl.autopilot.modes import Mode, PilotInput
from udrobot_ctrl.autopilot.motors import MotorParameters, frame, mix, to_pwm
from udrobot_ctrl.autopilot.params import ArduSubParameters, run_log_params
from udrobot_ctrl.autopilot.validate import check_log, nrmse, read_log
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.io import convert_log
from udrobot_ctrl.vehicle import load_model

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LOGS = (SHARED / "ardusub_log_tools" / "small.BIN", SHARED / "ardusub_log_tools" / "small.tlog",
        SHARED / "ardusub_log_tools" / "2023-04-18 11-03-34.tlog",
        SHARED / "guided_above_terrain" / "00000029_filtered.BIN")
#: fewer output-sample rows than this and the comparison uses every row (outputs constant, e.g. disarmed)
MIN_SAMPLE_ROWS = 20
PID_AXES = ("PIDR", "PIDP", "PIDY", "PIDA")


@dataclass(frozen=True)
class OutputCheck:
    """The emulated motor outputs of one log against its logged ones.

    Attributes
    ----------
    log, vehicle, frame : str
    rows : int
        Rows compared.
    nrmse, rmse_us, logged_std_us : tuple of float
        Per motor channel: RMSE / std of the logged channel, RMSE (us), std of the logged channel (us).
    modes : dict
        Mode name -> rows compared in it.
    armed_fraction : float
        Fraction of the compared rows armed.
    assumed : int
        ArduSub parameters the log lacked (defaults used).
    seconds : float
        Wall time of the emulation (s).
    """

    log: str
    vehicle: str
    frame: str
    rows: int
    nrmse: tuple
    rmse_us: tuple
    logged_std_us: tuple
    modes: dict
    armed_fraction: float
    assumed: int
    seconds: float

    def summary(self) -> str:
        modes = ", ".join(f"{k} {v}" for k, v in self.modes.items())
        return "\n".join([
            f"{self.log}: {self.vehicle} ({self.frame}), {self.rows} rows compared ({modes}; "
            f"{100 * self.armed_fraction:.0f}% armed), {self.assumed} parameters defaulted, {self.seconds:.1f} s",
            "  NRMSE per motor:  " + " ".join(f"{x:6.3f}" for x in self.nrmse),
            "  RMSE us:          " + " ".join(f"{x:6.1f}" for x in self.rmse_us),
            "  logged std us:    " + " ".join(f"{x:6.1f}" for x in self.logged_std_us)])


def output_check(path: Path) -> OutputCheck:
    """Convert ``path`` (every row) and compare the emulated motor PWM with the logged one (module docstring)."""
    run = convert_log(path, cut=False)
    vehicle = run.metadata.get("vehicle") or "bluerov2-heavy"
    p = plant_parameters(load_model(vehicle))
    fr = frame(p.ardusub_frame)
    log_params, _ = run_log_params(run.metadata)
    params = ArduSubParameters.from_log_params(log_params)
    k = fr.n_motors
    # the run's pwm_i are motor-command PWM (the converter mirrored the reversed motors): every direction +1
    motors = replace(MotorParameters.from_log_params(log_params, k), directions=(1,) * k)
    t0 = time.perf_counter()
    u = emulated_mixer_inputs(run, params, fr, motors, p)
    seconds = time.perf_counter() - t0
    if u is None:
        raise ValueError(f"{path}: no 'mode' column, nothing to emulate")
    emulated = to_pwm(mix(fr, u, motors), motors, integer=True)
    logged = np.asarray(run.inputs, float)
    rows = changed_rows(run)
    if rows.size < MIN_SAMPLE_ROWS:
        rows = np.arange(run.n)
    e, x = emulated[rows], logged[rows]
    rmse = [float(np.sqrt(np.nanmean((e[:, i] - x[:, i]) ** 2))) for i in range(k)]
    mode = run.extra.get("mode")
    names = {}
    for m in np.nan_to_num(mode[rows], nan=-1).astype(int):
        name = Mode(m).name if m in Mode._value2member_map_ else str(m)
        names[name] = names.get(name, 0) + 1
    armed = run.extra.get("armed")
    on = np.ones(rows.size, bool) if armed is None else np.nan_to_num(armed[rows], nan=1.0) != 0
    return OutputCheck(log=path.name, vehicle=vehicle, frame=fr.name, rows=int(rows.size),
                       nrmse=tuple(nrmse(e[:, i], x[:, i]) for i in range(k)), rmse_us=tuple(rmse),
                       logged_std_us=tuple(float(np.nanstd(x[:, i])) for i in range(k)), modes=names,
                       armed_fraction=float(on.mean()), assumed=len(params.assumed), seconds=seconds)


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
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--pid", action="store_true", help="also the PID term check on dataflash logs with PID records")
    args = ap.parse_args(argv)
    paths = args.logs or [p for p in LOGS if p.exists()]
    if not paths:
        print(f"no ArduSub log given and none found under {SHARED}", file=sys.stderr)
        return 1
    out = {}
    for path in paths:
        if not path.exists():
            print(f"{path}: not found", file=sys.stderr)
            return 1
        check = output_check(path)
        print(check.summary())
        out[path.name] = {"vehicle": check.vehicle, "frame": check.frame, "rows": check.rows,
                          "nrmse": [_finite(x) for x in check.nrmse], "rmse_us": [_finite(x) for x in check.rmse_us],
                          "modes": check.modes}
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
