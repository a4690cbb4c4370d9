"""The report's account of the gap the significant effects leave (``remaining``): each channel's NRMSE back in its
own units, so that a regulated attitude's or a steady transect's small error reads as the small error it is."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.constants import STATE_INDEX
from udrobot_ctrl.gap.report import closed_loop_shares, remaining_gap, remaining_line
from udrobot_ctrl.gap.shrink import SIM_COLUMNS, gap


def _run(n=2000, seed=0):
    """A held-level pitch (spread 0.3 deg) replayed 1 deg off, and a heave at 0.5 m/s amplitude replayed 5 cm/s off."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    theta = np.radians(0.3) * np.sin(0.7 * t) + np.radians(0.05) * rng.standard_normal(n)
    w = 0.5 * np.sin(0.3 * t)
    sim = np.full((n, SIM_COLUMNS), np.nan)
    sim[:, STATE_INDEX["theta"]] = theta + np.radians(1.0)
    sim[:, STATE_INDEX["w"]] = w + 0.05
    prep = SimpleNamespace(name="run", meas={"theta": theta, "w": w}, smoothed=None)
    return prep, sim


def test_the_remaining_gap_gives_each_channels_error_in_its_units():
    prep, sim = _run()
    after = gap([prep], [sim])
    assert set(after.scored) == {"theta", "w"}
    rem = remaining_gap(after, {"theta": 0.1, "w": 0.02}, {"theta": 1.0})
    by = {r.channel: r for r in rem}
    # the replay is off by a constant: the RMS error is that offset, whatever the channel's spread
    assert by["theta"].rms_error == pytest.approx(np.radians(1.0), rel=1e-9)
    assert by["w"].rms_error == pytest.approx(0.05, rel=1e-9)
    assert by["theta"].spread == pytest.approx(np.std(prep.meas["theta"]), rel=1e-9)
    assert by["theta"].unit == "rad" and by["w"].unit == "m/s"
    # the pitch held within a fraction of a degree scores the larger NRMSE for the smaller error, and holds the gap
    assert [r.channel for r in rem] == ["theta", "w"]
    assert sum(r.share for r in rem) == pytest.approx(1.0)
    assert by["theta"].closed_loop == 1.0 and by["w"].closed_loop == 0.0
    line = remaining_line([r.to_json() for r in rem])
    assert line.startswith("  what remains: theta ") and "replayed in closed loop" in line
    assert "w " not in line  # theta alone holds more than REMAINING_SHOWN of it


def test_closed_loop_shares_count_the_stabilised_samples_of_the_closed_axes():
    fb = SimpleNamespace(axes=np.array([True, True, False]), stabilised=np.r_[np.ones(300, bool), np.zeros(100, bool)])
    runs = [SimpleNamespace(n=400, feedback=fb), SimpleNamespace(n=400, feedback=None)]
    shares = closed_loop_shares(runs)
    assert shares["phi"] == shares["q"] == pytest.approx(300 / 800)
    assert shares["psi"] == shares["r"] == 0.0
