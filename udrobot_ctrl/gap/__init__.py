"""udrobot_ctrl.gap"""
