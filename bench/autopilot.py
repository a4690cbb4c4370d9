"""ArduSub's emulated controllers against the Seattle sea dive (../shared/data/guided_above_terrain).

    PYTHONPATH=. python bench/autopilot.py [--log PATH] [--json]

Prints, for ArduSub's default gains and for gains fitted from the logged PID terms (the log has no parameters):
the NRMSE (RMSE / std of the logged signal) of the emulated P, I and D terms per axis (PIDR, PIDP, PIDY, PIDA),
of the motor PWM per RCOU channel (the mixer alone on the logged mixer inputs, and the emulated controllers),
the fitted gains, the fitted motor directions, and the cost of one ``ArduSubAutopilot.step``. See
``udrobot_ctrl/autopilot/validate.py`` for what a 10 Hz log can and cannot check.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, VehicleState
from udrobot_ctrl.autopilot.modes import Mode, PilotInput
from udrobot_ctrl.autopilot.validate import check_log, fit_depth_gains, fitted_parameters, read_log, replay_autopilot

DIVE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "guided_above_terrain" / \
    "00000029_filtered.BIN"


def step_cost(n: int = 4000) -> float:
    """Microseconds per ``ArduSubAutopilot.step`` in ALT_HOLD (attitude + depth loops)."""
    ap = ArduSubAutopilot()
    state = VehicleState(depth=3.0, rates=(0.01, -0.02, 0.03))
    pilot = PilotInput.centred()
    t0 = time.perf_counter()
    for _ in range(n):
        ap.step(0.0025, state, pilot, Mode.ALT_HOLD)
    return (time.perf_counter() - t0) / n * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, default=DIVE)
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args(argv)
    if not args.log.exists():
        print(f"{args.log}: not found (the shared sea dive is needed)", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    log = read_log(args.log)
    t_read = time.perf_counter() - t0
    out = {"log": str(args.log), "loop_hz": round(1 / log.loop_dt, 1), "read_s": round(t_read, 2)}
    for label in ("default", "fitted"):
        t1 = time.perf_counter()
        check = check_log(log, label)
        print(check.summary())
        print(f"({time.perf_counter() - t1:.2f} s)\n")
        out[label] = {"terms": {ax: {k: round(v, 6) for k, v in vars(r).items() if k not in ("axis", "n")}
                                for ax, r in check.terms.items()},
                      "rcou_mixer": [round(x, 4) for x in check.rcou_mixer],
                      "rcou_emulated": [round(x, 4) for x in check.rcou_emulated],
                      "throttle": round(check.throttle, 4),
                      "forward_lateral": [round(x, 4) for x in check.forward_lateral],
                      "rate_targets": [round(x, 4) for x in check.rate_targets]}
    print("fitted gains (SI; PIDA in throttle per m/s^2, ArduSub's PSC_ACCZ_* = 10 x):")
    for ax, f in check.fitted.items():
        print(f"  {ax}: kP {f.p:.5g}  kI {f.i:.5g} (corr {f.i_corr:.4f})  kD {f.d:.5g} (corr {f.d_corr:.3f})")
    out["fitted_gains"] = {ax: {k: (None if not math.isfinite(v) else v) for k, v in
                                (("p", f.p), ("i", f.i), ("d", f.d), ("i_corr", f.i_corr), ("d_corr", f.d_corr))}
                           for ax, f in check.fitted.items()}
    fd = fit_depth_gains(log)
    print(f"  PSCD: PSC_POSZ_P {fd.pos_p:.4g} (corr {fd.pos_corr:.3f})  PSC_VELZ_P {fd.vel_p:.4g} "
          f"(corr {fd.vel_corr:.4f})  [library defaults 1.0, 5.0]")
    out["fitted_depth"] = {"pos_p": fd.pos_p, "vel_p": fd.vel_p}
    out["directions"] = list(check.directions)
    print("\nArduSubAutopilot stepped through the dive (logged states, modes, shaped targets, RCIN):")
    for label, params in (("default", None), ("fitted", fitted_parameters(log))):
        r = replay_autopilot(log, params, directions=check.directions)
        print(f"  {label:8s} NRMSE roll/pitch/yaw/throttle vs RATE ROut/POut/YOut/AOut: "
              + " ".join(f"{x:.3f}" for x in r.inputs))
        print(f"  {label:8s} RCOU NRMSE: " + " ".join(f"{x:.3f}" for x in r.rcou)
              + "   RMSE us: " + " ".join(f"{x:.1f}" for x in r.rcou_rmse))
        out[label]["replay"] = {"inputs": [round(x, 4) for x in r.inputs], "rcou": [round(x, 4) for x in r.rcou],
                                "rcou_rmse_us": [round(x, 2) for x in r.rcou_rmse],
                                "wall_per_sim_s": round(r.seconds_per_second, 4)}
        print(f"  ({r.end - r.start:.0f} s of log at {1 / log.loop_dt:.0f} Hz, "
              f"{r.seconds_per_second:.3f} s wall per s)")
    cost = step_cost()
    print(f"motor directions (fitted): {check.directions}")
    print(f"ArduSubAutopilot.step: {cost:.0f} us (ALT_HOLD); 1 s at 400 Hz = {cost * 400 / 1e6:.3f} s")
    out["step_us"] = round(cost, 1)
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
