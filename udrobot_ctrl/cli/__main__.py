"""``python -m udrobot_ctrl.cli``."""
from udrobot_ctrl.cli.main import console

console()
