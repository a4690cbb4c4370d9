"""``udrobot-ctrl`` command line: one subcommand per module, each registered lazily.

Each subcommand module exposes ``register(subparsers)`` (adds its parser and sets
``func``) so that importing the CLI never pulls in heavy dependencies it does not need.

Errors: the expected ones (:data:`EXPECTED_ERRORS`: bad input, missing or unreadable files, logs or mappings
that cannot be imported) are printed as one line ``udrobot-ctrl CMD: error: ...`` with exit status 2; anything
else is a bug and keeps its traceback. Output piped into a reader that closes early (``| head``) ends quietly.

Signals: SIGINT (Ctrl-C) and SIGTERM stop the command: its worker processes are stopped
(:func:`udrobot_ctrl.parallel.stop_workers`), its temporary files removed
(:func:`udrobot_files.output.remove_temporaries`; outputs already renamed into place stay), and it exits with
128 + the signal number (130, 143) after one line ``udrobot-ctrl CMD: interrupted by SIGTERM ...``, no traceback.
"""
from __future__ import annotations

import argparse
import difflib
import importlib
import multiprocessing
import os
import re
import signal
import sys
import threading
from pathlib import Path

from udrobot_ctrl import __version__
from udrobot_ctrl.parallel import stop_workers
from udrobot_files.locks import release_claims
from udrobot_files.nesting import too_deep
from udrobot_files.output import check_distinct_outputs, remove_temporaries, run_files

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
  demo         start here: the whole chain on the shipped UDrobot data (about 20 s; the first run on a machine
               compiles its kernels once, about 1 min):
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


class Interrupted(KeyboardInterrupt):
    """The command was stopped by a signal (SIGINT or SIGTERM); a KeyboardInterrupt, so that code which lets a
    Ctrl-C through lets it through too."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_STOPPING = {"pid": None, "signum": None}  # the CLI process and the first signal it received
_LAST_STOP: dict = {"signum": None}  # the signal that stopped the last main() of this process, if one did


def _on_signal(signum, frame):
    """SIGINT/SIGTERM handler of the CLI process: stop the workers at once (they may be what the caller waits for)
    and raise :class:`Interrupted` there; later signals are ignored while it unwinds. A forked worker that still
    carries this handler dies (SIGTERM) or leaves it to the caller (SIGINT)."""
    if os.getpid() != _STOPPING["pid"]:
        if signum == signal.SIGTERM:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        return
    if _STOPPING["signum"] is not None:
        return
    _STOPPING["signum"] = signum
    for child in multiprocessing.active_children():
        try:
            child.terminate()
        except (OSError, ValueError):
            pass
    raise Interrupted(signum)


def _install_signal_handlers() -> dict:
    """Install :func:`_on_signal` for SIGINT and SIGTERM (main thread only); returns the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    _STOPPING.update(pid=os.getpid(), signum=None)
    # a SIGINT ignored by whoever started us (a background job of a shell) stays ignored
    return {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)
            if signal.getsignal(sig) is not signal.SIG_IGN}


def _stopped(command: str, signum: int) -> int:
    """Stop the workers, remove the temporaries, say so in one line; the exit status 128 + ``signum``."""
    _LAST_STOP["signum"] = signum
    stop_workers()
    removed = remove_temporaries()
    sys.stdout.flush()
    name = signal.Signals(signum).name
    print(f"udrobot-ctrl {command}: interrupted by {name}: workers stopped, "
          f"{len(removed)} temporary file{'s' if len(removed) != 1 else ''} removed; outputs not yet written are "
          f"missing", file=sys.stderr)
    return 128 + signum


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


#: options that name an output file or folder, whatever the command (a bool --plot is a switch, not a path)
OUTPUT_OPTIONS = ("json", "out", "out_model", "plot", "segment_dir", "report")


def check_output_options(args) -> None:
    """Refuse two output options of the command naming the same file (:func:`check_distinct_outputs`), for every
    command, before it starts: a run CSV ``--out`` brings its sidecar ``NAME.json``.

    Raises
    ------
    udrobot_files.output.OutputError
        Naming both options and the file.
    """
    outputs = {}
    for name in OUTPUT_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value:
            option = "--" + name.replace("_", "-")
            outputs[option] = run_files(value) if value.lower().endswith(".csv") else value
    if len(outputs) > 1:
        check_distinct_outputs(outputs)


_PATH_NAMES = ("path", "source", "src", "source_name", "study_path", "file", "filename")


def _too_deep(exc: RecursionError) -> str:
    """The message for a RecursionError that no reader turned into its own error: the file being read (the innermost
    frame with a local variable naming an existing file), nested too deeply."""
    found, tb = None, exc.__traceback__
    while tb is not None:
        for name in _PATH_NAMES:
            value = tb.tb_frame.f_locals.get(name)
            if isinstance(value, (str, Path)) and value and len(str(value)) < 4096:
                try:
                    if Path(value).is_file():
                        found = value
                        break
                except (OSError, ValueError):
                    pass
        tb = tb.tb_next
    if found is None:
        return (f"an input nested too deeply to read (over about {sys.getrecursionlimit()} levels of brackets or "
                f"tables): a damaged or wrong file")
    return str(too_deep(found, "TOML" if str(found).lower().endswith(".toml") else "JSON"))


def _quiet_broken_pipe() -> int:
    """The reader of stdout went away (``| head``): stop writing, without a traceback (Python docs' idiom)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return 1


def console() -> None:
    """The ``udrobot-ctrl`` console script and ``python -m udrobot_ctrl.cli``: :func:`main`, then exit with its status.

    After a signal stopped the command (its workers stopped, temporaries removed, the line printed) the process
    ends at once (``os._exit``), without the interpreter's exit handlers: those join the process pools' queue
    threads, which can wait forever on a queue lock a stopped worker held.
    """
    _LAST_STOP["signum"] = None
    status = main()
    if _LAST_STOP["signum"] is not None:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    previous = _install_signal_handlers()
    unraisable = sys.unraisablehook
    sys.unraisablehook = _quiet_interrupted(unraisable)
    command = first if first in COMMANDS else ""
    try:
        status = _main(argv, first)
        if _STOPPING["signum"] is not None:  # the Interrupted raised in the handler was lost (raised where Python
            return _stopped(command, _STOPPING["signum"])  # ignores errors: an at-fork callback, a finaliser)
        return status
    except KeyboardInterrupt as exc:  # Interrupted, or a Ctrl-C before the handlers were installed
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        return _stopped(command, signum)
    except BaseException:
        if _STOPPING["signum"] is None:
            raise
        return _stopped(command, _STOPPING["signum"])  # what the stopped workers left (a broken pool): the signal
    finally:
        release_claims()  # the outputs this command claimed (udrobot_files.output.check_command)
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        sys.unraisablehook = unraisable
        _STOPPING.update(pid=None, signum=None)


def _quiet_interrupted(hook):
    """``sys.unraisablehook`` that says nothing of an :class:`Interrupted` raised where Python cannot propagate it
    (a signal arriving in an at-fork callback or a finaliser): :func:`main` still ends as interrupted."""
    def quiet(unraisable):
        if not isinstance(unraisable.exc_value, Interrupted):
            hook(unraisable)
    return quiet


def _main(argv: list, first: str | None) -> int:
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
            check_output_options(args)
            status = int(args.func(args) or 0)
        except EXPECTED_ERRORS as exc:
            if _STOPPING["signum"] is not None:  # a consequence of the stop (workers gone), not the user's input
                raise Interrupted(_STOPPING["signum"]) from None
            sys.stdout.flush()
            print(f"udrobot-ctrl {args.command}: error: {exc}", file=sys.stderr)
            return 2
        except RecursionError as exc:  # a parser following a file nested too deeply (the readers name it first)
            sys.stdout.flush()
            print(f"udrobot-ctrl {args.command}: error: {_too_deep(exc)}", file=sys.stderr)
            return 2
        sys.stdout.flush()
        return status
    except BrokenPipeError:
        return _quiet_broken_pipe()


if __name__ == "__main__":
    console()
