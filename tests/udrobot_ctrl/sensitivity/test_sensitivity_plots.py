"""Tornado and Sobol-index plots are written for real results."""
import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402

from udrobot_ctrl.sensitivity.executor import SweepExecutor  # noqa: E402
from udrobot_ctrl.sensitivity.global_ import Ishigami, run_morris, run_sobol  # noqa: E402
from udrobot_ctrl.sensitivity.local import local_sensitivity  # noqa: E402
from udrobot_ctrl.sensitivity.plots import sobol_bars, tornado  # noqa: E402


class _Space:
    names = ["x1", "x2", "x3"]
    nominal = np.array([0.5, 0.5, 0.5])
    bounds = np.array([[-np.pi, np.pi]] * 3)


def test_plots_are_written(tmp_path):
    f = Ishigami()
    ex = SweepExecutor(workers=1)
    loc = local_sensitivity(f, _Space(), executor=ex, progress=False)
    fig = tornado(loc, "y", path=tmp_path / "tornado.png")
    # bars span the one-at-a-time range of each input: x2 swings sin^2 over [-pi, pi] -> 0 at both ends
    assert abs(loc.range_effect("y")[1]) < 1e-9
    sob = run_sobol(f, f.problem(), 256, executor=ex, progress=False)
    sobol_bars(sob, "y", path=tmp_path / "sobol.png")
    mor = run_morris(f, f.problem(), 8, executor=ex, progress=False)
    sobol_bars(mor, "y", path=tmp_path / "morris.png")
    for name in ("tornado.png", "sobol.png", "morris.png"):
        assert (tmp_path / name).stat().st_size > 5000
    assert fig.axes[0].get_yticklabels()
