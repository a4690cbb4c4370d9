"""Lazy re-exports: a package's public names importable from the package without importing its modules early.

A package ``__init__`` lists its public API as ``{name: module}`` and hands the mapping to
:func:`lazy_exports`; ``from package import name`` then imports ``package.module`` only when the name is first
asked for. Importing a subpackage for one of its modules (``import udrobot_ctrl.dynamics.plant``) therefore
loads nothing else of the package, and the re-exports add no import edge between subpackages (no cycle).
"""
from __future__ import annotations

import importlib


def lazy_exports(package: str, exports: dict):
    """Module-level ``__getattr__`` and ``__dir__`` serving ``exports`` lazily.

    Parameters
    ----------
    package : str
        The package's ``__name__`` (e.g. ``"udrobot_ctrl.dynamics"``).
    exports : dict
        Public name -> name of the submodule of ``package`` that defines it (e.g. ``{"simulate": "sim"}``).

    Returns
    -------
    getattr_ : callable
        ``__getattr__(name)`` for the package: imports ``package.<module>`` and returns its attribute ``name``;
        raises :class:`AttributeError` for a name not in ``exports`` (so ``hasattr`` and ``import`` behave).
    dir_ : callable
        ``__dir__()`` for the package: its module globals and the exported names.

    Examples
    --------
    In ``package/__init__.py``::

        _EXPORTS = {"simulate": "sim"}
        __all__ = list(_EXPORTS)
        __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
    """
    def getattr_(name: str):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    def dir_():
        return sorted(set(vars(importlib.import_module(package))) | set(exports))

    return getattr_, dir_
