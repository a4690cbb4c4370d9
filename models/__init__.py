"""Model data shipped with udrobot-ctrl (vehicle description and coefficient sets, TOML).

This directory is installed as the package ``udrobot_ctrl.models`` so that a plain
(non-editable) ``pip install .`` can load every model with :mod:`importlib.resources`.
"""
