"""``udrobot-ctrl convert IN --mapping MAP --out RUN.csv``: a ROS bag, MAVLink/dataflash log or rostopic CSV
to a ``udrobot-run/1`` run, optionally cut into free-decay launches for identification."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from udrobot_ctrl.cli.main import CLIError
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import log_input_files
from udrobot_ctrl.io.mapping import UNAIDED_NOTE
from udrobot_ctrl.io.runlog import write
from udrobot_ctrl.io.segment import find_launches, idle_mask, write_launches
from udrobot_files.output import check_command, run_files


def register(subparsers) -> None:
    p = subparsers.add_parser("convert", help="convert a bag / .tlog / .bin / rostopic CSV to udrobot-run/1",
                              description=__doc__.replace("``", "") + "\nThe run-log format is defined in "
                              "docs/formats/runlog.md, the mappings in docs/mappings.md.",
                              epilog="example: udrobot-ctrl convert pool.bag --mapping bluerov2-mavros --out pool.csv")
    p.add_argument("input", help="log: .bag, .mcap, .db3, ROS 2 bag directory, .tlog, .bin, rostopic echo -p .csv")
    p.add_argument("--mapping", help="mapping TOML file or shipped name (ardusub, bluerov2-mavros, tartan-auv); "
                                     "default: bluerov2-mavros for bags, ardusub for .tlog/.bin")
    p.add_argument("--out", help="output udrobot-run/1 CSV (sidecar JSON written next to it)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("--vehicle", metavar="NAME",
                   help="the vehicle of a .tlog/.bin (bluerov2, bluerov2-heavy, or the mapping's default vehicle): "
                        "overrides FRAME_CONFIG and the inference from the active motor outputs; needed when the log "
                        "does not name its vehicle and its outputs do not tell it")
    p.add_argument("--no-cut", action="store_true",
                   help="keep every row: do not cut the stretches the plant cannot represent (surface, disarmed, "
                        "upside down; the mapping's [cut])")
    p.add_argument("--allow-missing-inputs", action="store_true",
                   help="write nan input columns when the log has no commands (e.g. a launch test)")
    p.add_argument("--segment", metavar="CHANNEL",
                   help="also cut free-decay launches from this channel (e.g. theta for a pendulum, y for a spring)")
    p.add_argument("--segment-column", choices=("theta", "y"), help="column name in the launch CSVs "
                                                                     "(default: theta for angles, else y)")
    p.add_argument("--segment-dir", help="directory for STEM_launchK.csv (default: next to --out)")
    p.set_defaults(func=run)


def run(args) -> int:
    if not args.out and not args.segment:
        raise ValueError("nothing to do: give --out RUN.csv and/or --segment CHANNEL")
    inputs = log_input_files(args.input, args.mapping)  # the log, its mapping file, a rostopic set's other files
    check_command({"--out": run_files(args.out) if args.out else None}, inputs, force=args.force,
                  folders={"--segment-dir": (args.segment_dir, ()) if args.segment_dir else None})
    run_ = convert_log(args.input, args.mapping, require_inputs=not args.allow_missing_inputs, vehicle=args.vehicle,
                       cut=not args.no_cut)
    bounds = run_.segment_bounds()
    kept_s = sum(float(run_.t[b - 1] - run_.t[a]) for a, b in bounds)
    span = (f"{kept_s:.3f} s in {len(bounds)} segments (t {run_.t[0]:.3f}..{run_.t[-1]:.3f} s)" if len(bounds) > 1
            else f"{run_.duration:.3f} s")
    print(f"{args.input}: {run_.n} samples, {span}, dt {run_.dt_median * 1e3:.2f} ms, "
          f"channels {', '.join(run_.channels) or 'none'}, inputs {run_.input_kind} x{run_.inputs.shape[1]}"
          + (f", vehicle {run_.metadata['vehicle']}" if run_.metadata.get("vehicle") else ""))
    for line in run_.metadata.get("notes", "").splitlines():
        if line.startswith(("cut: WARNING", "cut: kept", "cut: segment", UNAIDED_NOTE)) or "ALMOST ALL" in line:
            print(line)
    launches = []
    if args.segment:  # the channel and its launches checked (and their files) before anything is written
        try:
            y = run_.channel(args.segment)
        except KeyError as exc:  # an unknown channel name is the user's input, not a bug
            raise CLIError(f"--segment: {exc.args[0]}") from None
        angle = args.segment in ("phi", "theta", "psi")
        column = args.segment_column or ("theta" if angle else "y")
        # a launch needs a free vehicle: thrusters idle from the release on (rows without commands: a rig)
        free = idle_mask(run_.input_kind, run_.inputs)
        launches = [replace(launch, start=launch.start + a, stop=launch.stop + a)  # none across a cut
                    for a, b in bounds for launch in find_launches(run_.t[a:b], y[a:b], angle=angle, free=free[a:b])]
        if not launches:
            raise ValueError(f"{args.input}: no launch (hold then release with the thrusters idle) found in channel "
                             f"'{args.segment}' ({100 * free.mean():.0f} % of the rows have idle thrusters)")
        out_dir = args.segment_dir or (Path(args.out).parent if args.out else Path("."))
        stem = Path(args.out).stem if args.out else Path(args.input).stem
        names = [f"{stem}_launch{k}.csv" for k in range(1, len(launches) + 1)]  # as segment.write_launches names
        check_command({"--out": run_files(args.out) if args.out else None}, inputs, force=args.force,
                      folders={"--segment-dir" if args.segment_dir else "--segment": (out_dir, names)})
        for name in names:  # launch files are never replaced (write_launches), --force or not
            if (Path(out_dir) / name).exists():
                raise ValueError(f"{Path(out_dir) / name}: exists; refusing to overwrite a launch file")
    if args.out:
        path = write(run_, args.out, overwrite=args.force, protect=inputs)
        print(f"wrote {path} and {Path(path).with_suffix('.json')}")
    if launches:
        for launch, path in zip(launches, write_launches(run_.t, y, launches, out_dir, stem, column, angle,
                                                                  protect=inputs)):
            print(f"launch at t = {launch.t_release:.3f} s, amplitude {launch.amplitude:.4g}, "
                  f"{launch.stop - launch.start} samples -> {path}")
    return 0
