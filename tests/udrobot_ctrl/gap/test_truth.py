"""The withheld-effect truth generator keeps its pool physical: the runs stay in the water, off the wall and the
seabed, so that an effect near a surface is what the diagnoser sees, not a vehicle behind the declared wall."""
from __future__ import annotations

import numpy as np
import pytest

from .truth import SEABED, WALL_Y, Truth, generate, random_magnitudes


def _true(runs, channel):
    return np.array([r.extra[f"true_{channel}"] for r in runs])


@pytest.fixture(scope="module")
def pools():
    """Stock-sensor runs (they carry the true state) without an effect and with the strongest wall effect drawn."""
    wall = random_magnitudes("wall_effect", np.random.default_rng(3)) | {"a": 0.22, "kappa": 3.0, "suction": 0.1}
    return {name: generate(eff, n_runs=4, duration=90.0, rate=10.0, seed=4, sensors="stock")
            for name, eff in (("none", None), ("wall", {"wall_effect": wall}))}


@pytest.mark.slow
@pytest.mark.parametrize("case", ["none", "wall"])
def test_the_runs_stay_in_the_water(pools, case):
    runs = pools[case]
    half = Truth().half_size  # hull half-sizes, m (contact)
    y, z = _true(runs, "y"), _true(runs, "z")
    assert np.all(WALL_Y - y > half[1] - 0.01), (WALL_Y - y).min()  # at most a 1 cm bump into the contact spring
    assert np.all(SEABED - z > half[2] - 0.01), (SEABED - z).min()
    if case == "none":  # no suction: the wall guard holds the near lanes off the contact
        assert np.all(WALL_Y - y > half[1] + 0.05), (WALL_Y - y).min()
        assert np.all(SEABED - z > 0.1), (SEABED - z).min()


@pytest.mark.slow
def test_near_runs_pass_the_wall_and_far_runs_do_not(pools):
    d = WALL_Y - _true(pools["none"], "y")
    near = d.min(axis=1) < 0.6
    assert list(near) == [True, False, True, False]  # runs alternate near (0.35-0.5 m) and far (1.2-2 m)
    assert np.all(np.mean(d[near] < 0.6, axis=1) > 0.25)  # a near run spends a quarter of its time within 0.6 m


def test_contact_pushes_the_hull_back_into_the_water():
    tr = Truth()
    x = np.zeros((2, 12))
    x[:, 2] = 1.0
    x[0, 1] = WALL_Y - tr.half_size[1] + 0.02  # 2 cm into the wall's contact spring
    x[1, 1] = WALL_Y - 1.0
    F, _ = tr.extra(x, 0.0)
    assert F[0, 1] < -50.0 and F[1, 1] == 0.0  # into the water (-y), nothing away from it
