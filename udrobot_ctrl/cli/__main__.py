"""``python -m udrobot_ctrl.cli``."""
import sys

from udrobot_ctrl.cli.main import main

sys.exit(main())
