"""Physically impossible coefficients are rejected with the reason, never reported as ok (issue 12 item 6).

A decay that oscillates faster than the rig's mass allows (the field-log case: a roll trace with the
thrusters running, ``identify pendulum`` gave C_m = -1.02) fits a negative added mass with a tight interval.
"""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from identification.decay import physical_check
from identification.identify import RigOptions, format_table, identify_files
from identification.synthetic import SpringTruth, spring_launch, write_launch
from tests.identification.test_pendulum import AREA, MASS, VOLUME, pendulum_trace
from udrobot_ctrl.vehicle import full_size_vehicle

UDROBOT = full_size_vehicle()  # the full-size vehicle the scale-model results are referred to

R = 0.30  # m, pendulum arm


def _write(path, t, th):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "theta"])
        w.writerows(zip(t, th))
    return path


@pytest.fixture()
def launches(tmp_path):
    """Two good launches (true added mass 0.10 kg) and one whose decay implies -0.06 kg (C_m ~ -0.56)."""
    files = []
    for i, (ma, amp) in enumerate(((0.10, 10), (0.10, 12), (-0.06, 10))):
        t, th = pendulum_trace(MASS, VOLUME, R, ma, 0.04, 2.2, math.radians(amp), seed=i)
        files.append(_write(tmp_path / f"surge_L{i + 1}_{i}.csv", t, th))
    return files


def test_negative_added_mass_launch_is_rejected_with_its_reason(launches):
    rep = identify_files("pendulum", launches,
                         RigOptions(vehicle=UDROBOT, mass=MASS, volume=VOLUME, length=R, area=AREA))
    bad = rep["launches"][2]
    assert not bad["ok"] and not bad["used"]
    assert bad["Cm"] == pytest.approx(-0.06 / (1000 * VOLUME), rel=0.05)  # the fitted value is kept for the record
    assert bad["Cm_ci95"][1] < 0  # a tight interval, all below zero
    assert "physically impossible" in bad["error"] and "C_m = -0.5" in bad["error"]
    assert any("negative added mass" in r for r in bad["impossible"])
    assert rep["n_ok"] == 2 and rep["n_used"] == 2
    # the aggregate comes from the two good launches only
    assert rep["aggregate"]["added_mass_kg"]["value"] == pytest.approx(0.10, rel=0.03)
    text = format_table(rep)
    assert "REJECTED" in text and "negative added mass" in text
    good = rep["launches"][0]
    assert good["ok"] and good["impossible"] == []


def test_graphical_fit_rejects_negative_values_too(launches):
    rep = identify_files("pendulum", launches[2:],
                         RigOptions(vehicle=UDROBOT, mass=MASS, volume=VOLUME, length=R, area=AREA), fit="graphical")
    assert rep["n_ok"] == 0 and "physically impossible" in rep["launches"][0]["error"]


def test_negative_but_consistent_with_zero_is_doubtful_not_impossible():
    check = physical_check({"Cm": 0.8, "Cm_se": 0.05, "KL": -0.058, "KL_se": 0.027, "KL_ci95": [-0.112, -0.005],
                            "KQ": 2.0, "KQ_se": 0.1})
    # 2.1 s.e. below 0: outside the 95 % interval but a true K_L = 0 does that in 2 % of launches: doubtful
    assert check.impossible == () and len(check.doubtful) == 1 and "K_L = -0.058" in check.doubtful[0]
    check = physical_check({"KQ": -11.2, "graphical": {"Cm": -1.02}})  # no standard errors: the sign decides
    assert len(check.impossible) == 2
    assert any(r.startswith("K_Q = -11.2") and "feeds energy" in r for r in check.impossible)
    assert any(r.startswith("graphical fit: C_m = -1.02") for r in check.impossible)
    assert physical_check({"KL": float("nan"), "Cm": 0.0}).impossible == ()
    assert len(physical_check({"Cm": -1.02, "Cm_se": 0.05}).impossible) == 1  # the field-log case: 20 s.e.


def test_spring_fluid_damping_below_zero_is_rejected(tmp_path):
    """The rig's mechanical damping given too large (0.6 N s/m, truly 0.1): the fluid K_L = c - 0.6 < 0."""
    truth = SpringTruth("surge", Cm=0.8, CD=1.0, area=0.01, mechanical_damping=0.1)
    path = write_launch(spring_launch(truth, 0.05, np.random.default_rng(0), as_counts=False),
                        tmp_path / "surge_spring.csv")
    opts = RigOptions(vehicle=UDROBOT, mass=truth.mass, volume=truth.volume, stiffness=truth.stiffness, area=truth.area,
                      mechanical_damping=0.6)
    e = identify_files("spring", [path], opts)["launches"][0]
    assert not e["ok"] and e["KL"] == pytest.approx(-0.5, abs=0.1) and e["KL"] + 3.29 * e["KL_se"] < 0
    assert "K_L = -0." in e["error"] and "feeds energy" in e["error"]
    # the same launch with the right rig damping is ok
    opts = RigOptions(vehicle=UDROBOT, mass=truth.mass, volume=truth.volume, stiffness=truth.stiffness, area=truth.area,
                      mechanical_damping=0.1)
    assert identify_files("spring", [path], opts)["launches"][0]["ok"]
