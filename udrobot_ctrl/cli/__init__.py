"""``udrobot-ctrl`` command line: one module per command (:mod:`udrobot_ctrl.cli.main` dispatches)."""
from udrobot_ctrl.cli.main import CLIError, main

__all__ = ["CLIError", "main"]
