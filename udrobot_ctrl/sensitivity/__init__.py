"""Coefficient sensitivity studies (local, Sobol, Morris) on executors."""
