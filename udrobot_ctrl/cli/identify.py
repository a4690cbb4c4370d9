"""``udrobot-ctrl identify spring|pendulum|cfd FILES...``: identification from raw test files.

Examples
--------
Spring launches (encoder counts or metres), the paper's 30 % model on K = 63.6 N/m::

    udrobot-ctrl identify spring data/spring/*.csv --json spring.json --plot plots/

Pendulum launches on a 0.30 m arm, written as a coefficient set usable by ``--model SET.toml:chin``::

    udrobot-ctrl identify pendulum data/pend/*.csv --length 0.30 --out my_pendulum.toml

CFD force tables, one per axis (``speed,force``; axis from the file name)::

    udrobot-ctrl identify cfd cfd_surge.csv cfd_sway.csv cfd_heave.csv --base pendulum --out my_cfd.toml
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from identification.identify import KINDS, RigOptions, coefficient_set_values, format_table, identify_files
from identification.plots import plot_report
from identification.sets import write_coefficient_set
from udrobot_ctrl.vehicle import coefficient_set, full_size_vehicle
from udrobot_files.output import atomic_write, check_command, spec_files


def _area(text):
    """``0.0044`` or ``surge=0.0044,sway=0.0081,heave=0.0081`` (m^2)."""
    if "=" not in text:
        return float(text)
    out = {}
    for part in text.split(","):
        k, _, v = part.partition("=")
        k = k.strip().lower()
        k = {"x": "surge", "y": "sway", "z": "heave"}.get(k, k)
        if k not in ("surge", "sway", "heave"):
            raise ValueError(f"--area: unknown axis {k!r} (expected surge, sway, heave)")
        out[k] = float(v)
    return out


def register(subparsers):
    p = subparsers.add_parser("identify", help="identify coefficients from spring/pendulum launches or CFD tables",
                              description=__doc__.replace("``", "").replace("::", ":"),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("kind", choices=KINDS, help="test type")
    p.add_argument("files", nargs="+", help="launch CSVs (t,y | t,counts | t,theta) or CFD tables (speed,force); "
                                            "directories are searched for *.csv")
    p.add_argument("--json", metavar="REPORT.json", help="write the full report as JSON")
    p.add_argument("--out", metavar="SET.toml", help="write the full-scale coefficient set (udrobot-coefficients/1)")
    p.add_argument("--plot", metavar="DIR", help="write fit and coefficient-vs-Reynolds plots")
    p.add_argument("--fit", choices=("output-error", "graphical"), default="output-error",
                   help="launch fit (default output-error; graphical = the paper's peak method)")
    p.add_argument("--axis", choices=("surge", "sway", "heave"), help="axis of every file (default: from file names)")
    p.add_argument("--mass", type=float, help="tested model mass, kg (default: the paper's model)")
    p.add_argument("--volume", type=float, help="tested model displaced volume, m^3 (default: the paper's model)")
    p.add_argument("--stiffness", type=float, help="spring constant, N/m (default 63.6)")
    p.add_argument("--area", type=_area, help="projected area for C_D, m^2: a number or surge=..,sway=..,heave=.. "
                                              "(default: models/udrobot.toml areas x scale^2)")
    p.add_argument("--length", type=float, help="pendulum arm, pivot to the model's centre, m (required: pendulum)")
    p.add_argument("--gravity", type=float, default=9.81, help="m/s^2 (default 9.81)")
    p.add_argument("--rho", type=float, default=1000.0, help="water density, kg/m^3 (default 1000)")
    p.add_argument("--scale", type=float, help="model/full-size length ratio (default 0.30 spring, 0.22 pendulum, "
                                               "1 CFD)")
    p.add_argument("--mechanical-damping", type=float,
                   help="spring rig's own linear damping measured in air, N s/m (default: unknown, taken as 0; "
                        "the spring's K_L is then not written with --out)")
    p.add_argument("--pivot-inertia", type=float, default=0.0, help="pendulum arm+pivot inertia, kg m^2 (default 0)")
    p.add_argument("--reference-mass", default="vehicle",
                   help="full-size displaced mass for the added mass: vehicle (models/udrobot.toml), geometric "
                        "(rho V_model / scale^3) or a number in kg (9.2 reproduces the paper)")
    p.add_argument("--kl-law", choices=("reynolds", "froude"), default="reynolds", help="K_L scaling law")
    p.add_argument("--base", help="with --out: coefficient set (cfd, free_decay, pendulum or .toml) that supplies "
                                  "axes/quantities not identified here, tagged assumed")
    p.add_argument("--name", help="set name written with --out (default: the file stem)")
    p.add_argument("--quiet", action="store_true", help="do not print the table")
    p.add_argument("--force", action="store_true", help="replace existing output files (never an input)")
    p.set_defaults(func=run)


def expand_files(items) -> list[Path]:
    """Files as given; directories expand to their ``*.csv`` (sorted)."""
    out = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(path.glob("*.csv"))
            if not found:
                raise ValueError(f"{path}: directory holds no *.csv files")
            out.extend(found)
        else:
            out.append(path)
    return out


def run(args) -> int:
    files = expand_files(args.files)
    inputs = [*files, *spec_files(args.base)]
    force = getattr(args, "force", False)
    check_command({"--out": args.out, "--json": args.json}, inputs, force=force,
                  folders={"--plot": (args.plot, ()) if args.plot else None})
    opts = RigOptions(mass=args.mass, volume=args.volume, stiffness=args.stiffness, area=args.area,
                      length=args.length, gravity=args.gravity, rho=args.rho, scale=args.scale,
                      mechanical_damping=args.mechanical_damping, pivot_inertia=args.pivot_inertia,
                      reference_mass=args.reference_mass, KL_law=args.kl_law, axis=args.axis,
                      vehicle=full_size_vehicle())
    report = identify_files(args.kind, files, opts, fit=args.fit, keep_fits=bool(args.plot))
    launches = report.pop("_launches", None)
    if not args.quiet:
        print(format_table(report))
    if args.out and not report["n_ok"]:
        print(f"udrobot-ctrl identify: nothing identified (every file failed, see the table): {args.out} not written",
              file=sys.stderr)
    elif args.out:
        name = args.name or Path(args.out).stem
        per_axis, prov, desc = coefficient_set_values(report, name,
                                                      coefficient_set(args.base) if args.base else None)
        write_coefficient_set(args.out, name, per_axis, prov, desc, protect=inputs)
        print(f"wrote {args.out} (use --model {args.out}:chin or :morison)")
    if args.json:
        atomic_write(args.json, json.dumps(report, indent=1, default=_json_default), protect=inputs)
        print(f"wrote {args.json}")
    if args.plot:
        paths = plot_report(report, launches, args.plot, args.kind, protect=inputs)
        print(f"wrote {len(paths)} plots to {args.plot}")
    return 0 if report["n_ok"] else 1


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
