"""Identification of hydrodynamic coefficients from free-decay, pendulum and CFD data.

Modules
-------
free_decay  : spring free-decay test (Cely 2019 eqs. 6-9)
pendulum    : pendulum free-decay test, Chin and Morison forms (eqs. 10-16)
cfd         : force-speed regressions (Table 5)
similitude  : scale-model -> full-scale laws
statistics  : launch groups, pairwise tests, outliers
fossen      : coefficient set -> Fossen-form M_A and D(nu)
"""
