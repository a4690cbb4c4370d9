"""``udrobot-ctrl`` command line: one subcommand per module, each registered lazily.

Each subcommand module exposes ``register(subparsers)`` (adds its parser and sets
``func``) so that importing the CLI never pulls in heavy dependencies it does not need.
"""
from __future__ import annotations

import argparse
import importlib
import sys

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
}


class CLIError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="udrobot-ctrl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
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


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(first if first in COMMANDS else None)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CLIError, ValueError, FileNotFoundError, KeyError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"udrobot-ctrl {args.command}: error: {msg}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
