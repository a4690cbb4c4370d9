"""The noise floor of the location: a model that matches the runs is at its floor in every channel and DOF."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.attribute import residual
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.locate import ForceFloor, Located, Location, excess_shares, force_floor, noise_floor
from udrobot_ctrl.gap.shrink import gap, simulate_windows
from udrobot_ctrl.vehicle import load_model

from .truth import generate


def test_excess_is_in_units_of_the_floor_and_never_negative():
    f = ForceFloor(rms=np.array([1.0, 2.0, 0.5, np.nan, 3.0, 1.0]), floor=np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.5]),
                   rel_se=np.array([0.01, 0.01, 0.01, 0.01, 0.1, 0.01]))
    ex = f.excess()
    assert ex[0] == 0.0 and ex[2] == 0.0 and ex[3] == 0.0  # at or below the floor; an unscored DOF
    assert ex[1] == pytest.approx(4.0 - 1.0 - 0.03)
    assert ex[4] == pytest.approx(9.0 - 1.0 - 0.3)
    assert ex[5] == pytest.approx(ex[1])  # the same ratio counts the same, whatever the unit (N or N m)


def test_replay_excess_shares():
    sh = excess_shares({"p": 0.74, "u": 0.30, "z": 0.05}, {"p": 0.74, "u": 0.10, "z": 0.04})
    assert list(sh)[0] == "u" and sh["p"] == 0.0
    assert sh["u"] == pytest.approx((0.09 - 0.01) / (0.09 - 0.01 + 0.0025 - 0.0016))
    assert excess_shares({"p": 0.5}, {"p": 0.6}) == {"p": 0.0}


def test_replay_to_floor_pools_the_channels_with_a_floor():
    loc = Located((), {"p": 0.4, "r": 0.3, "u": 9.0}, {"p": 0.4, "r": 0.1}, {}, {}, {})
    assert loc.replay_to_floor() == pytest.approx((0.16 + 0.09) / (0.16 + 0.01))
    assert np.isnan(Located((), {"p": 0.4}, {}, {}, {}, {}).replay_to_floor())


@pytest.fixture(scope="module")
def no_effect():
    """Two 40 s runs of the truth plant with nothing withheld, and their nominal replays."""
    p = plant_parameters(load_model("pendulum:chin"))
    preps = [prepare(r, p, r.path) for r in generate({}, n_runs=2, duration=40.0, rate=20.0, seed=11)]
    sims = [simulate_windows(pr, p, (), 8.0) for pr in preps]
    return p, preps, sims


@pytest.mark.slow
def test_replay_floor_matches_the_gap_of_a_model_without_error(no_effect):
    """With no unmodelled effect, each channel's NRMSE is its floor: noise, start-state error and passive modes.
    Tolerance: two Monte Carlo draws over 40 s windows and the unmodelled part of the smoother's bias."""
    p, preps, sims = no_effect
    g = gap(preps, sims)
    floor = noise_floor(preps, sims, p, 8.0, g.scale)
    for c in g.scored:
        assert 0.7 < floor[c] / g.per_channel[c] < 1.4, (c, floor[c], g.per_channel[c])
    # the roll rate's error is large for any model (small spread against its noise), and so is its floor
    assert floor["p"] > 3 * floor["z"]


@pytest.mark.slow
def test_force_balance_of_a_model_without_error_is_at_its_floor(no_effect):
    """Every DOF's residual force is what the measurement noise produces (ratio 1; the tolerance covers one draw of
    the floor over 40 s and the smoother's systematic error, which the equation error keeps below 50 %)."""
    p, preps, _ = no_effect
    ff = force_floor(preps, p, [residual(pr, p) for pr in preps])
    assert np.all(np.isfinite(ff.rms)), ff
    assert np.all((ff.rms / ff.floor > 0.5) & (ff.rms / ff.floor < 1.5)), ff
    assert np.all(ff.excess() < 0.5)


@pytest.mark.slow
def test_stock_floor_holds_the_reconstruction_error():
    """Without a DVL the windows start from the smoother's surge and sway, whose error carries into the yaw rate
    and the attitude through the Munk moment and the drag: with no unmodelled effect the replay stays within its
    floor, because the floor restarts its windows from a draw of the smoother's posterior std (a floor that restarts
    them from the reconstruction itself put the yaw rate at 6 x its floor). Tolerance: three 40 s runs, two draws."""
    p = plant_parameters(load_model("pendulum:chin"))
    preps = [prepare(r, p, r.path) for r in generate({}, n_runs=3, duration=40.0, rate=20.0, seed=5,
                                                      sensors="stock")]
    assert all(pr.reconstructed[0] and pr.smoothed is not None for pr in preps)
    sims = [simulate_windows(pr, p, (), 8.0) for pr in preps]
    g = gap(preps, sims)
    floor = noise_floor(preps, sims, p, 8.0, g.scale)
    ratio = {c: g.per_channel[c] / floor[c] for c in g.scored}
    assert all(v < 1.6 for v in ratio.values()), ratio
    loc = Located((), dict(g.per_channel), floor, {}, {}, {})
    assert loc.replay_to_floor() < 1.5


def test_gap_dofs_count_each_location_for_its_dof():
    """A channel ranked by its DOF's residual force counts for that DOF, a replayed one for the DOF it measures;
    DOFs holding less than GAP_SHARE of the gap are left out, the rest ranked by share."""
    def at(channel, share, dof=None):
        return Location(channel, share, float("nan"), 0.0, "", [], "", {}, dof)
    located = Located((at("w", 0.6, "Z"), at("r", 0.15), at("psi", 0.1), at("phi", 0.15)), {}, {}, {}, {}, {})
    assert located.gap_dofs() == {2: pytest.approx(0.6), 5: pytest.approx(0.25)}
    assert located.gap_dofs(min_share=0.5) == {2: pytest.approx(0.6)}
