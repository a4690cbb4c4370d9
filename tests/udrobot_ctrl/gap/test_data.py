"""Preparing runs for the diagnoser: which surfaces a run knows its distance to."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tests.udrobot_ctrl.gap.truth import generate
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.gap.data import ALTITUDE_VALID_MIN, prepare, without_stabilised
from udrobot_ctrl.gap.identifiability import EffectCheck, Identifiability, ParameterCheck, describe_missing
from udrobot_ctrl.gap.report import diagnose, summary
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


def test_a_stabilised_attitude_logged_slower_than_its_loop_leaves_the_equation_error():
    """ArduSub's angle loop (P 6 -> time constant 0.17 s): outputs every 0.5 s (QGC's 2 Hz) miss its corrections
    between samples, so K, M, N leave the equation error; every 0.1 s (dataflash RCOU) they stay; an open-loop
    replay, or a run with no other DOF, keeps them."""
    ok = np.ones(6, bool)
    ok[:2] = False  # no DVL: X, Y not observed

    def loop(interval, axes=(True, True, True)):
        return SimpleNamespace(interval=interval, axes=np.array(axes), attitude=SimpleNamespace(angle_p=(6, 6, 6)))
    dofs, note = without_stabilised(ok, loop(0.5), "dive")
    np.testing.assert_array_equal(dofs, [False, False, True, False, False, False])
    assert note.startswith("dive: equation error without K, M, N") and "500 ms" in note
    dofs, note = without_stabilised(ok, loop(0.5, (True, True, False)))  # a frame without a yaw loop
    np.testing.assert_array_equal(dofs, [False, False, True, False, False, True])
    for fast in (without_stabilised(ok, loop(0.1)), without_stabilised(ok, None),
                 without_stabilised(np.array([0, 0, 0, 1, 1, 1], bool), loop(0.5))):
        assert fast[1] == ""
    np.testing.assert_array_equal(without_stabilised(ok, loop(0.1))[0], ok)


def test_pwm_thrust_follows_the_logged_battery_voltage():
    """A 4S battery sags from 16.8 V to 13 V over a dive and a T200's thrust at a given PWM with it (about 30 %):
    the diagnosis converts each sample at its own logged voltage, not at the model's supply voltage."""
    hv = plant_parameters(load_model("bluerov2-heavy"))
    n = 200
    t = np.arange(n) * 0.02
    volts = np.linspace(16.8, 13.0, n)
    pwm = np.full((n, 8), 1500.0)
    pwm[:, 4:] = 1700.0  # the four vertical thrusters pushing
    ch = {c: np.zeros(n) for c in ("z", "phi", "theta", "psi", "p", "q", "r")}
    ch["voltage"] = volts
    run = Run(path="v.csv", t=t, channels=ch, input_kind="pwm", inputs=pwm, extra={}, metadata={})
    prep = prepare(run, hv, "v.csv")
    want = np.clip(pwm_to_thrust(pwm, volts[:, None]), hv.f_min, hv.f_max)
    assert prep.f == pytest.approx(want, rel=1e-9)
    assert prep.f[0, 4] > 1.2 * prep.f[-1, 4]  # the sag is in the thrust


NO_FIX = "horizontal UNAIDED (dead reckoning): EK3_SRC1_VELXY = 3 (GPS): GPS: 0 of 50 samples with a 3D fix"
UNAIDED_SIDECAR = {"channels": {
    **{c: {"source": "XKF1.VN/VE/VD (world_to_body)", "kind": "estimated-unaided", "aiding": NO_FIX} for c in "uvw"},
    **{c: {"source": f"XKF1.P{'N' if c == 'x' else 'E'}", "kind": "estimated-unaided", "aiding": NO_FIX}
       for c in "xy"},
    "z": {"source": "BARO[1].Alt", "kind": "measured"}, "phi": {"source": "ATT.Roll", "kind": "estimated"}}}


def _drifting_run(metadata=None, n=400):
    """A run that logs u v w and x y as an EKF with no velocity source gives them (a drifting dead-reckoned surge)."""
    run = _run(0.0, metadata, n)
    run.channels["u"] = 0.2 + 0.01 * run.t
    run.channels["x"] = np.cumsum(run.channels["u"]) * 0.05
    del run.channels["altitude"]
    return run


def test_unaided_estimates_are_not_observed(p):
    """The sidecar marks u v w x y estimated-unaided: prepare leaves them out of meas (so nothing downstream fits,
    scores or counts them), X and Y are not observed, Z still is (through the measured depth); estimated but aided
    columns (phi) stay. The same run without the entry observes every DOF."""
    plain = prepare(_drifting_run(), p, "r.csv")
    assert plain.observed.all() and "u" in plain.meas and not plain.unaided
    prep = prepare(_drifting_run(UNAIDED_SIDECAR), p, "r.csv")
    assert not any(c in prep.meas for c in "uvwxy") and "z" in prep.meas and "phi" in prep.meas
    assert list(prep.observed) == [False, False, True, True, True, True]
    assert not prep.dof_ok[:2].any()
    assert sorted(prep.unaided) == ["u", "v", "w", "x", "y"]
    assert prep.unaided["u"].source == "XKF1.VN/VE/VD (world_to_body)"
    note = next(n for n in prep.notes if "estimated-unaided" in n)
    assert "u, v, w, x, y logged but estimated-unaided" in note and "not fitted, scored or counted" in note


def test_the_unidentifiable_reason_names_the_unaided_column(p):
    """An effect not identified for the horizontal velocity: its entry's ``missing`` carries ``not_observed`` and one
    ``unaided_estimate`` per unaided horizontal column (u, v, x, y: not w, which is heave) with its source and
    evidence; the console sentence is rendered from the code."""
    prep = prepare(_drifting_run(UNAIDED_SIDECAR), p, "r.csv")
    chk = EffectCheck("added_mass", [ParameterCheck("dm_X", 0.05, 0.0, False, ("horizontal",))])
    ident = Identifiability({"added_mass": chk}, prep.observed, prep.reconstructed, unaided=prep.unaided)
    (entry,) = ident.report()
    codes = [(m["code"], m.get("column", m.get("dofs"))) for m in entry["missing"]]
    assert codes == [("not_observed", "horizontal"), ("unaided_estimate", "u"), ("unaided_estimate", "v"),
                     ("unaided_estimate", "x"), ("unaided_estimate", "y")]
    u = entry["missing"][1]
    assert u["source"] == "XKF1.VN/VE/VD (world_to_body)" and "EK3_SRC1_VELXY = 3 (GPS)" in u["why"]
    assert describe_missing(u).startswith("u is logged but is an estimate without aiding (XKF1.VN/VE/VD")
    # no unaided column: the entry has no such code
    (plain,) = Identifiability({"added_mass": chk}, prep.observed, prep.reconstructed).report()
    assert [m["code"] for m in plain["missing"]] == ["not_observed"]


def test_a_diagnosis_on_dead_reckoned_velocities_scores_none_of_them():
    """Two simulated pool runs whose sidecars mark u v w x y estimated-unaided (an EKF with no velocity source): the
    diagnosis leaves them out (sensors: not logged, X and Y not scored, listed under unaided), every run notes it, and
    the effects the horizontal velocity would identify are unidentifiable with the ``unaided_estimate`` code naming
    each column and its source."""
    runs = generate({}, n_runs=2, duration=60.0, rate=20.0, seed=3)
    for r in runs:
        r.metadata = {**r.metadata, **UNAIDED_SIDECAR}
    report, _ = diagnose("pendulum:chin", runs)
    sensors = report["sensors"]
    assert not set("uvwxy") & set(sensors["logged"]) and not {"X", "Y"} & set(sensors["scored_dofs"])
    assert sensors["unaided"]["u"] == "XKF1.VN/VE/VD (world_to_body)"
    assert sum("u, v, w, x, y logged but estimated-unaided" in n for n in report["notes"]) == 2
    assert report["unidentifiable"] and not any(e["significant"] for e in report["effects"])
    horizontal = [u for u in report["unidentifiable"] if {"code": "not_observed", "dofs": "horizontal"} in u["missing"]]
    assert horizontal
    for u in horizontal:
        named = {m["column"]: m["source"] for m in u["missing"] if m["code"] == "unaided_estimate"}
        assert named == {"u": "XKF1.VN/VE/VD (world_to_body)", "v": "XKF1.VN/VE/VD (world_to_body)",
                         "x": "XKF1.PN", "y": "XKF1.PE"}
    # the console says it in words, once per column of each such effect
    text = summary(report)
    assert text.count("u is logged but is an estimate without aiding (XKF1.VN/VE/VD (world_to_body)") == len(horizontal)
