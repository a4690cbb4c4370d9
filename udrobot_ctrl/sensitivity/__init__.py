"""Coefficient sensitivity studies (local, Sobol, Morris) on executors."""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used
_EXPORTS = {
    "Parameter": "parameters", "ParameterSpace": "parameters", "default_space": "parameters",
    "MissionEvaluator": "evaluators",
    "SweepExecutor": "executor",
    "LocalResult": "local", "local_sensitivity": "local",
    "GlobalResult": "global_", "run_sobol": "global_", "run_morris": "global_", "MonteCarloResult": "global_",
    "run_monte_carlo": "global_",
    "tornado": "plots", "sobol_bars": "plots",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
