"""``udrobot-ctrl diagnose``: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks.

    udrobot-ctrl diagnose --model MODEL --json REPORT.json [--holdout RUN.csv ...] [--plot DIR] RUN.csv [...]

Positional runs fit the effects' parameters; ``--holdout`` runs only score (one run per ``--holdout``; repeat
the option for several). Without ``--holdout`` the last run is held out (a single run: its last third).
Options may come before or after the runs. The report format is ``udrobot-diagnosis/1`` (docs/formats/diagnosis.md).
A holdout run may not be a fit run (the same file, or a copy with identical content) nor repeat fit data (the
same samples shifted in time, written again, or a stretch of a fit run), a run whose sidecar names another
vehicle than --model is refused, and ``--json``, ``--out-model`` and the ``--plot`` files must be different
files and not inputs: all are refused before any work.
When every run is reported "not diagnosed" (unexcited, or not represented by the plant), ``--out-model`` is not
written (a message says so): there is no corrected model to write.
Exit 0 whenever the diagnosis ran; 2 with a message on bad input; 130 / 143 when stopped by Ctrl-C / SIGTERM (the
workers are stopped, no output is left half-written).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys
from pathlib import Path

from udrobot_ctrl.convert import load_any
from udrobot_ctrl.gap.plots import plot_paths, write_plots
from udrobot_ctrl.gap.report import (
    corrected_model,
    diagnose,
    nothing_diagnosed,
    run_label,
    split_runs,
    summary,
    write_report,
)
from udrobot_ctrl.gap.shrink import check_window
from udrobot_ctrl.io.overlap import check_unseen
from udrobot_ctrl.vehicle import MODEL_NAMES, VEHICLE_MODEL_NAMES, load_model, write_model_file
from udrobot_files.output import check_command, spec_files


def register(subparsers):
    p = subparsers.add_parser(
        "diagnose", help="diagnose the sim-to-real gap of a model against real runs",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__.replace("``", ""),
        epilog="example: udrobot-ctrl diagnose --model pendulum:chin --json gap.json --holdout run3.csv "
               "--plot gap_plots run1.csv run2.csv")
    p.add_argument("runs", nargs="+", metavar="RUN.csv", help="fit runs (udrobot-run/1 CSV or a convertible log)")
    p.add_argument("--model", required=True, help="model name (pendulum:chin, bluerov2-heavy, ...) or a model file")
    p.add_argument("--json", required=True, metavar="REPORT.json", help="write the udrobot-diagnosis/1 report")
    p.add_argument("--holdout", action="append", default=[], metavar="RUN.csv",
                   help="a run used only to score; repeat the option for several runs")
    p.add_argument("--plot", metavar="DIR", help="write residual and overlay figures to DIR")
    p.add_argument("--out-model", metavar="CORRECTED.json",
                   help="write the model with the significant effects added (udrobot-model/1 with an effects list)")
    p.add_argument("--window", type=float, default=8.0, help="multiple-shooting window, s (default 8)")
    p.add_argument("--selection", action="store_true",
                   help="also report the one-criterion selection table of the fit runs (experimental; it does not "
                        "decide; several times the run time)")
    p.add_argument("--mapping", help="log mapping for non-udrobot-run inputs (see udrobot-ctrl convert)")
    p.add_argument("--effects", help="comma-separated subset of the catalogue to test (default: all)")
    p.add_argument("--force", action="store_true", help="replace existing output files (never an input)")
    p.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    p.set_defaults(func=run)


def _load(path, mapping):
    if not Path(path).exists():
        raise FileNotFoundError(f"run file {path} does not exist")
    return load_any(path, mapping)


def _digest(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_holdout_not_fit(fit, holdout) -> None:
    """Refuse a holdout run that is one of the fit runs: the same file (resolved path, symbolic or hard link) or
    a copy of it (identical content, by SHA-256). Without ``--holdout`` the last fit run is held out, so it is
    checked against the others.

    Raises
    ------
    ValueError
        Naming both files: a holdout that repeats a fit run scores the fit on its own data.
    """
    if not holdout:
        fit, holdout = fit[:-1], fit[-1:]
    fit = [Path(p) for p in fit]
    digests = {}

    def digest(p):
        if p not in digests:
            digests[p] = _digest(p)
        return digests[p]

    for h in map(Path, holdout):
        for f in fit:
            if not (h.exists() and f.exists()):
                continue
            if h.resolve() == f.resolve() or os.path.samefile(h, f):
                how = "is the same file as"
            elif h.stat().st_size == f.stat().st_size and digest(h) == digest(f):
                how = "is a copy (identical content) of"
            else:
                continue
            raise ValueError(f"holdout run {h} {how} the fit run {f}: a holdout must be data the fit has not seen; "
                             f"give a different run as holdout")


#: the vehicles a run's sidecar can name that a model can be matched against (the ArduSub mapping's default
#: vehicle "udrobot" and the shipped BlueROV2 models)
KNOWN_VEHICLES = ("udrobot", *VEHICLE_MODEL_NAMES)
#: the ArduSub frame of each shipped BlueROV2 model (models/bluerov2*.toml ardusub_frame)
VEHICLE_FRAMES = {"bluerov2": "VECTORED", "bluerov2-heavy": "VECTORED_6DOF"}


def model_vehicle(spec, vehicle) -> str | None:
    """The vehicle (of :data:`KNOWN_VEHICLES`) a ``--model`` is, or None when it cannot be told: ``SET:FORM`` is
    the UDrobot, a shipped vehicle is itself, a model file is the vehicle its name starts with (a corrected
    model is named ``BASE+effects``) or, failing that, the shipped model of its ArduSub frame."""
    text = str(spec)
    if text in MODEL_NAMES:
        return "udrobot"
    if text in VEHICLE_MODEL_NAMES:
        return text
    base = str(vehicle.name).split("+")[0].strip()
    if base in MODEL_NAMES:
        return "udrobot"
    if base in VEHICLE_MODEL_NAMES:
        return base
    frame = (vehicle.extras or {}).get("ardusub_frame")
    return next((name for name, f in VEHICLE_FRAMES.items() if f == frame), None)


def check_run_vehicles(spec, runs, paths) -> None:
    """Refuse a run whose sidecar names another vehicle than ``--model`` (both known, :func:`model_vehicle`):
    its data would be diagnosed on the wrong vehicle's plant.

    Raises
    ------
    ValueError
        Naming the run, the sidecar's vehicle and the model's.
    """
    named = [(r, p, r.metadata.get("vehicle")) for r, p in zip(runs, paths)]
    named = [(r, p, v) for r, p, v in named if v in KNOWN_VEHICLES]
    if not named:
        return
    ours = model_vehicle(spec, load_model(spec))
    for _, path, vehicle in named:
        if ours is not None and vehicle != ours:
            raise ValueError(f"run {path}: its sidecar names the vehicle {vehicle!r}, but --model {spec} is the "
                             f"{ours}; diagnose a run with its own vehicle's model (or, if the sidecar is wrong, "
                             f"convert the log again with --vehicle)")


def run(args) -> int:
    inputs = [*args.runs, *args.holdout, *spec_files(args.model), *spec_files(args.mapping)]
    files = {"--json": args.json, "--out-model": args.out_model}
    # the outputs checked and claimed before the runs are read; the figures' names (one per run segment) once
    # they are, still before any work
    check_command(files, inputs, force=args.force, folders={"--plot": (args.plot, ()) if args.plot else None})
    check_holdout_not_fit(args.runs, args.holdout)
    fit = [_load(p, args.mapping) for p in args.runs]
    hold = [_load(p, args.mapping) for p in args.holdout]
    check_run_vehicles(args.model, fit + hold, [*args.runs, *args.holdout])
    if hold:  # a holdout repeating fit data (shifted, re-written, a stretch of it): before any work
        check_unseen(fit, args.runs, hold, args.holdout)
    elif len(fit) > 1:  # without --holdout the last run is held out
        check_unseen(fit[:-1], args.runs[:-1], fit[-1:], args.runs[-1:])
    if args.plot:
        fit_s, hold_s, _ = split_runs(fit, hold or None)
        plots = plot_paths(args.plot, [run_label(r) for r in fit_s], [run_label(r) for r in hold_s])
        check_command(files, inputs, force=args.force,
                      folders={"--plot": (args.plot, [Path(f).name for f in plots])})
    effects = [e.strip() for e in args.effects.split(",")] if args.effects else None
    check_window(args.window, ())
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr))
    report, ctx = diagnose(args.model, fit, hold or None, window_s=args.window, effects=effects, log=log,
                           model_label=args.model, selection=args.selection)
    write_report(report, Path(args.json), protect=inputs)
    if args.out_model and nothing_diagnosed(report):
        print(f"udrobot-ctrl diagnose: {args.out_model} not written: no run was diagnosed (the report's verdict says "
              f"why), so there is no corrected model", file=sys.stderr)
    elif args.out_model:
        corrected, not_placed = corrected_model(args.model, report, fit + hold)
        write_model_file(corrected, args.out_model, protect=inputs)
        print(f"wrote {args.out_model} with effects: {', '.join(e.name for e in corrected.effects) or 'none'}",
              file=sys.stderr)
        for name, why in not_placed.items():
            print(f"udrobot-ctrl diagnose: warning: {name} is not in {args.out_model}: {why}", file=sys.stderr)
        for e in report["effects"]:
            if e.get("at_bound_reason"):
                print(f"udrobot-ctrl diagnose: note: {e['name']} is not in {args.out_model}: its fit ends at the edge "
                      f"of its range ({', '.join(e['at_bound'])}), evidence of a missing term, not a finding",
                      file=sys.stderr)
            if e.get("held_at_nominal"):
                print(f"udrobot-ctrl diagnose: note: {e['name']} is in {args.out_model} with "
                      f"{', '.join(e['held_at_nominal'])} at nominal (its fit ended at a bound, or the holdout did not "
                      f"confirm it on its own)", file=sys.stderr)
    if args.plot:
        for f in write_plots(ctx, report, args.plot, protect=inputs):
            print(f"wrote {f}", file=sys.stderr)
    print(summary(report))
    return 0
