"""``udrobot-ctrl diagnose``: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks.

    udrobot-ctrl diagnose --model MODEL --json REPORT.json [--holdout RUN.csv ...] [--plot DIR] RUN.csv [...]

Positional runs fit the effects' parameters; ``--holdout`` runs only score. Without ``--holdout`` the last run
is held out (a single run: its last third). Exit 0 whenever the diagnosis ran; 2 with a message on bad input.
"""
from __future__ import annotations

import sys
from pathlib import Path


def register(subparsers):
    p = subparsers.add_parser("diagnose", help="diagnose the sim-to-real gap of a model against real runs",
                              description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN.csv", help="fit runs (udrobot-run/1 CSV or a convertible log)")
    p.add_argument("--model", required=True, help="model name (pendulum:chin, ...) or a udrobot-model/1 file")
    p.add_argument("--json", required=True, metavar="REPORT.json", help="write the udrobot-diagnosis/1 report")
    p.add_argument("--holdout", nargs="+", default=[], metavar="RUN.csv", help="runs used only to score")
    p.add_argument("--plot", metavar="DIR", help="write residual and overlay figures to DIR")
    p.add_argument("--out-model", metavar="CORRECTED.json",
                   help="write the model with the significant effects added (udrobot-model/1 with an effects list)")
    p.add_argument("--window", type=float, default=8.0, help="multiple-shooting window, s (default 8)")
    p.add_argument("--mapping", help="log mapping for non-udrobot-run inputs (see udrobot-ctrl convert)")
    p.add_argument("--effects", help="comma-separated subset of the catalogue to test (default: all)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def _load(path, mapping):
    from udrobot_ctrl.io import load_any

    if not Path(path).exists():
        raise FileNotFoundError(f"run file {path} does not exist")
    return load_any(path, mapping)


def run(args) -> int:
    from udrobot_ctrl.gap.report import diagnose, summary, write_report

    fit = [_load(p, args.mapping) for p in args.runs]
    hold = [_load(p, args.mapping) for p in args.holdout]
    effects = [e.strip() for e in args.effects.split(",")] if args.effects else None
    if args.window <= 0:
        raise ValueError(f"--window must be > 0 s, got {args.window}")
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr))
    report, ctx = diagnose(args.model, fit, hold or None, window_s=args.window, effects=effects, log=log,
                           model_label=args.model)
    out = Path(args.json)
    if out.parent and not out.parent.exists():
        raise ValueError(f"--json {out}: directory {out.parent} does not exist")
    write_report(report, out)
    if args.out_model:
        from udrobot_ctrl.gap.report import corrected_model
        from udrobot_ctrl.vehicle import write_model_file

        write_model_file(corrected_model(args.model, report, fit + hold), args.out_model)
        print(f"wrote {args.out_model}", file=sys.stderr)
    if args.plot:
        from udrobot_ctrl.gap.plots import write_plots

        for f in write_plots(ctx, report, args.plot):
            print(f"wrote {f}", file=sys.stderr)
    print(summary(report))
    return 0
