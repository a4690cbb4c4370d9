"""``udrobot-ctrl`` command line: one subcommand per module, each registered lazily.

Each subcommand module exposes ``register(subparsers)`` (adds its parser and sets
``func``) so that importing the CLI never pulls in heavy dependencies it does not need.

Errors: the expected ones (:data:`EXPECTED_ERRORS`: bad input, missing or unreadable files, logs or mappings
that cannot be imported) are printed as one line ``udrobot-ctrl CMD: error: ...`` with exit status 2; anything
else is a bug and keeps its traceback. Output piped into a reader that closes early (``| head``) ends quietly.
"""
from __future__ import annotations

import argparse
import difflib
import importlib
import os
import re
import sys

from udrobot_ctrl import __version__

# subcommand -> module defining register(subparsers)
COMMANDS = {
    "demo": "udrobot_ctrl.cli.demo",
    "identify": "udrobot_ctrl.cli.identify",
    "model": "udrobot_ctrl.cli.model",
    "simulate": "udrobot_ctrl.cli.simulate",
    "compare": "udrobot_ctrl.cli.compare",
    "diagnose": "udrobot_ctrl.cli.diagnose",
    "sensitivity": "udrobot_ctrl.cli.sensitivity",
    "convert": "udrobot_ctrl.cli.convert",
    "design": "udrobot_ctrl.cli.design",
}

DESCRIPTION = """\
Control design for small underwater robots from identified hydrodynamic coefficients, and the
sim-to-real gap of a model against pool logs.

commands, in the order of a typical job:
  demo         start here: the whole chain on the shipped UDrobot data (about 30 s; the first run on a machine
               compiles its kernels once, 1.5-2 min):
               identification, five models, controllers on every design/plant pair, plots and an index
  identify     coefficients with 95 % intervals from free-decay spring or pendulum launches, or CFD tables
  model        export a model as udrobot-model/1 JSON, or show its masses, damping and thrusters
  convert      a ROS bag, ArduPilot .bin/.tlog or rostopic CSV -> udrobot-run/1 run log
  simulate     replay a run's logged commands through a model (what the model predicts)
  diagnose     where a model disagrees with real runs, which unmodelled effect explains it, how much
  compare      LQR, PID and MPC designed on one model and flown on another, for every pair
  sensitivity  which coefficient matters to a controller (local, Sobol or Morris)
  design       the vehicle's own ArduSub gains tuned on a model, written as a QGroundControl .params file

Models: the UDrobot as SET:FORM (cfd:chin, cfd:morison, free_decay:morison, pendulum:chin, pendulum:morison),
the BlueROV2 vehicles (bluerov2, bluerov2-heavy), or a udrobot-model/1 JSON or vehicle TOML file.
A run's model is the vehicle that logged it. Formats: docs/formats/ in the source.
"""

EPILOG = """\
first steps:
  udrobot-ctrl demo --out demo_out      then open demo_out/README.md

example (a BlueROV2 dive, from the raw log to a diagnosis; docs/tutorial.md goes on to a redesign):
  udrobot-ctrl convert dive.tlog --out dive.csv          (the sidecar dive.json names the vehicle)
  udrobot-ctrl simulate --model bluerov2 --input dive.csv --out dive_sim.csv
  udrobot-ctrl diagnose --model bluerov2 --json gap.json --plot gap_plots dive.csv

'udrobot-ctrl COMMAND --help' describes each command and its options."""


class CLIError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


# Errors that mean "bad input or environment", not a bug: printed as one line. The project's own errors
# (RunLogError, LogImportError, MappingError, LaunchError, SingularMassMatrixError, StudyMismatchError) are
# ValueErrors raised by input validation.
EXPECTED_ERRORS = (CLIError, ValueError, FileNotFoundError, FileExistsError, PermissionError, IsADirectoryError,
                   NotADirectoryError)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="udrobot-ctrl", description=DESCRIPTION, epilog=EPILOG,
                                     usage="%(prog)s [-h] [--version] COMMAND [OPTIONS ...]",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    # the commands are listed, in the order of a job, in DESCRIPTION; argparse's own list would repeat them
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help=argparse.SUPPRESS,
                                prog="udrobot-ctrl")
    for name, module in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=f"(see udrobot-ctrl {name} --help)", add_help=False)
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and (exc.name == module or module.startswith(exc.name + ".")):
                continue  # subcommand not available in this build
            raise
        mod.register(sub)
    return parser


NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+(e[-+]?\d+)?$", re.IGNORECASE)


def unknown_option(parser: argparse.ArgumentParser, argv: list) -> str | None:
    """A message naming the first option of ``argv`` that ``parser`` (a sub-command's) does not know, or None.

    argparse checks the required options before it reports an unknown one, so ``--modle x`` got "required:
    --model"; this names the mistake and the closest known option instead. Unique prefixes of a known option are
    accepted as argparse accepts them; negative numbers and everything after ``--`` are values.
    """
    nested = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    if nested is not None:  # identify spring|pendulum|cfd, model export|show: the options are the nested parser's
        choice = next((i for i, a in enumerate(argv) if a in nested.choices), None)
        if choice is not None:
            return unknown_option(nested.choices[argv[choice]], argv[choice + 1:])
    known = sorted(parser._option_string_actions)
    for token in argv:
        if token == "--":
            break
        if not token.startswith("-") or token == "-" or NEGATIVE_NUMBER.match(token):
            continue
        name = token.split("=", 1)[0]
        if name in known or (name.startswith("--") and sum(k.startswith(name) for k in known) == 1):
            continue
        close = difflib.get_close_matches(name, known, n=1)
        return f"unrecognized option {name}" + (f" (did you mean {close[0]}?)" if close else "")
    return None


def _quiet_broken_pipe() -> int:
    """The reader of stdout went away (``| head``): stop writing, without a traceback (Python docs' idiom)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return 1


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    try:
        parser = build_parser(first if first in COMMANDS else None)
        if first in COMMANDS:
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            command = sub.choices.get(first)
            message = command is not None and unknown_option(command, argv[argv.index(first) + 1:])
            if message:
                command.error(message)
        args = parser.parse_args(argv)
        try:
            status = int(args.func(args) or 0)
        except EXPECTED_ERRORS as exc:
            sys.stdout.flush()
            print(f"udrobot-ctrl {args.command}: error: {exc}", file=sys.stderr)
            return 2
        sys.stdout.flush()
        return status
    except BrokenPipeError:
        return _quiet_broken_pipe()


if __name__ == "__main__":
    sys.exit(main())
