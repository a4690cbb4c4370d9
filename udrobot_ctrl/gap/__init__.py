"""The sim-to-real gap diagnosis (where the gap lies, which unmodelled effect causes it) and its report."""
from udrobot_files.exports import lazy_exports

# the public API (docs/api): name -> the module of this package defining it, imported when first used
_EXPORTS = {
    "diagnose": "report", "Diagnosis": "report", "write_report": "report",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
