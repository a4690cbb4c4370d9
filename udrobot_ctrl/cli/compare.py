"""``udrobot-ctrl compare``: design on model A, fly on plant B (see :mod:`udrobot_ctrl.control.compare`)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from udrobot_ctrl.control.compare import (
    TABLE_LEGEND,
    compare,
    output_names,
    write_outputs,
)
from udrobot_ctrl.control.missions import CONTROLLER_KINDS
from udrobot_ctrl.vehicle import MODEL_NAMES
from udrobot_files.output import (
    atomic_write,
    check_command,
    spec_files,
)


def register(subparsers):
    p = subparsers.add_parser(
        "compare", help="design on model A, fly on plant B: every pair of the models, "
                        "LQR/PID/MPC metrics and EKF consistency",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Every controller (LQR, PID, linear and nonlinear MPC) is designed on model A and flown on\n"
                    "plant B through the standard mission (depth step 0.5 -> 1.5 m, heading 0 -> 90 deg, surge\n"
                    "transit at 0.5 m/s and stop), for every pair (A, B) of the models; an EKF built on A filters\n"
                    "B's simulated sensors. Shows how much a controller suffers when the coefficients it was\n"
                    "designed with are wrong.\n\n" + TABLE_LEGEND,
        epilog="example: udrobot-ctrl compare --quick --controllers lqr,pid --out compare_out")
    p.add_argument("--out", help="folder for CSV, text tables (with a legend), full JSON and plots (created if "
                                 "missing)")
    p.add_argument("--json", help="write the JSON report (models, results, ekf; NaN as null) here (its folder must "
                                  "exist)")
    p.add_argument("--controllers", default=",".join(CONTROLLER_KINDS),
                   help="comma-separated subset of lqr,pid,lmpc,nmpc (default all)")
    p.add_argument("--models", default=",".join(MODEL_NAMES),
                   help="comma-separated model names or files, used both as design models and plants "
                        "(default: the five shipped models)")
    p.add_argument("--quick", action="store_true", help="short mission (23 s instead of 46 s)")
    p.add_argument("--workers", type=int, default=None, help="processes (default: one per core; 1 = no pool)")
    p.add_argument("--no-ekf", action="store_true", help="skip the EKF matrix")
    p.add_argument("--force", action="store_true", help="replace existing output files (never an input)")
    p.set_defaults(func=run)


def run(args) -> int:
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    for c in controllers:
        if c not in CONTROLLER_KINDS:
            raise ValueError(f"--controllers: unknown controller {c!r} (expected {', '.join(CONTROLLER_KINDS)})")
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    inputs = spec_files(*models)
    in_out = bool(args.json and args.out) and Path(args.json).parent.resolve() == Path(args.out).resolve()
    check_command({"--json": args.json}, inputs, force=args.force,  # --out creates the folder --json may be in
                  folders={"--out": (args.out, output_names(controllers)) if args.out else None},
                  create_folders=("--json",) if in_out else ())
    result = compare(models, controllers, quick=args.quick, workers=args.workers, keep_trajectories=bool(args.out),
                     ekf=not args.no_ekf)
    print(result.summary())
    print(f"{len(result.results)} controller runs, {len(result.ekf)} EKF runs in {result.wall_s:.1f} s")
    if args.out:
        files = write_outputs(result, Path(args.out), protect=inputs)
        print(f"wrote {len(files)} files to {args.out}")
    if args.json:
        path = Path(args.json)
        atomic_write(path, json.dumps(result.to_json(), indent=1), protect=inputs)
        print(f"wrote {path}")
    return 0
