"""Preparing runs for the diagnoser: which surfaces a run knows its distance to."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import ALTITUDE_VALID_MIN, prepare
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model


@pytest.fixture(scope="module")
def p():
    return plant_parameters(load_model("pendulum:chin"))


def _run(valid_fraction, metadata=None, n=400):
    """A hovering run whose altimeter returns a range (2.0-2.4 m) in the first ``valid_fraction`` of the samples."""
    t = np.arange(n) * 0.05
    altitude = np.full(n, np.nan)
    k = int(valid_fraction * n)
    altitude[:k] = 2.2 + 0.2 * np.sin(t[:k])
    ch = {c: np.zeros(n) for c in ("x", "y", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    ch["z"] = 1.0 + 0.1 * np.sin(0.5 * t)
    ch["altitude"] = altitude
    return Run(path="r.csv", t=t, channels=ch, input_kind="thrust", inputs=np.zeros((n, 4)), extra={},
               metadata=metadata or {})


def test_a_mostly_valid_altitude_places_the_seabed(p):
    prep = prepare(_run(0.8), p, "r.csv")
    assert [s[2] for s in prep.surfaces] == ["seabed (altitude)"]
    assert prep.surfaces[0][0][:10] == pytest.approx(2.2 + 0.2 * np.sin(np.arange(10) * 0.05))
    assert not any("altitude" in note for note in prep.notes)


def test_a_mostly_invalid_altitude_is_reported_not_used(p):
    prep = prepare(_run(0.3), p, "r.csv")
    assert prep.surfaces == []
    note = next(note for note in prep.notes if "altitude" in note)
    assert "120 of 400 samples (30%" in note and f"{100 * ALTITUDE_VALID_MIN:g}%" in note
    assert "wall_effect cannot be tested" in note and "2-2.4 m" in note
    # with the seabed depth in the sidecar, that is used instead
    prep = prepare(_run(0.3, {"seabed_depth": 3.0}), p, "r.csv")
    assert [s[2] for s in prep.surfaces] == ["seabed"]
    assert prep.surfaces[0][0] == pytest.approx(3.0 - prep.eta[:, 2])
    assert any("seabed_depth is used instead" in note for note in prep.notes)
