"""udrobot_ctrl.io"""
