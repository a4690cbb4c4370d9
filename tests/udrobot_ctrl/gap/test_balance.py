"""The steady-flight balance (udrobot_ctrl/gap/balance.py): what the thrusters held against what the model needs."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tests.udrobot_ctrl.gap.truth import generate
from udrobot_ctrl.dynamics.plant import restoring_forces
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import residual
from udrobot_ctrl.gap.balance import (
    BALANCE_Z,
    MIN_STEADY_S,
    BalanceBin,
    DofBalance,
    SteadyBalance,
    balance_lines,
    steady_balance,
    steady_samples,
)
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.gap.report import prepare_inputs

BUOYANCY = {"dB0": 2.0, "beta": 0.1}  # the truth's compressible foam: dB = dB0 (1 - beta z), N


def _inputs(effects, seed, n_runs=2):
    runs = generate(effects, n_runs=n_runs, duration=90.0, rate=20.0, seed=seed)
    return prepare_inputs("pendulum:chin", runs[:-1], runs[-1:], None, 8.0)


def _slice(run, t0, t1):
    """The rows of ``run`` with t0 <= t < t1 (s)."""
    m = (run.t >= t0) & (run.t < t1)
    return replace(run, path=f"{run.path}[{t0:g}-{t1:g} s]", t=run.t[m], inputs=run.inputs[m],
                   channels={c: v[m] for c, v in run.channels.items()}, extra={c: v[m] for c, v in run.extra.items()})


def _balance(inp, hooks=()):
    return steady_balance(inp.fit, inp.holdout, [residual(pr, inp.p) for pr in inp.fit],
                          [residual(pr, inp.p) for pr in inp.holdout], hooks)


@pytest.fixture(scope="module")
def buoyant():
    return _inputs({"buoyancy_offset": BUOYANCY}, seed=4)


@pytest.fixture(scope="module")
def exact_runs():
    """Two runs of a truth without a withheld effect."""
    return generate({}, n_runs=2, duration=90.0, rate=20.0, seed=4)


@pytest.mark.slow
def test_a_buoyancy_error_is_the_heave_force_the_thrusters_held_beyond_the_models_need(buoyant):
    """The truth's extra heave force F (its foam's buoyancy change, a force acting beside the thrusters) is what the
    thrusters did *not* have to hold in steady flight: held - nominal need = -F, bin by bin, within 3 standard
    errors plus 5 % (the smoothing's bias on a slowly varying force)."""
    bal = _balance(buoyant)
    assert bal.bins, "the runs hold steady flight"
    for b in bal.bins:
        preps = buoyant.fit if b.part == "fit" else buoyant.holdout
        truth = []
        for pr in preps:  # the truth's force on the bin's steady samples
            s = steady_samples(pr)
            speed = np.linalg.norm(pr.nu[:, :3], axis=1)
            s &= (speed >= b.speed[0]) & (speed < b.speed[1])
            x = pr.raw_state()[s]
            dB = BUOYANCY["dB0"] * (1 - BUOYANCY["beta"] * x[:, 2])
            truth.append(dB * restoring_forces(x[:, :6], 0.0, 1.0, buoyant.p.r_g, buoyant.p.r_b)[:, 2])
        want = float(np.mean(np.concatenate(truth)))  # -F
        z = b.dofs["Z"]
        assert z.held - z.nominal == pytest.approx(want, abs=BALANCE_Z * z.se + 0.05 * abs(want)), (b, want)
        assert z.imbalanced and abs(want) > 1.5


@pytest.mark.slow
def test_without_a_withheld_effect_every_steady_bin_balances(exact_runs):
    """The nominal model is the truth: no DOF of any steady bin is imbalanced beyond 3 standard errors (the standard
    error's correlation time, the smoothing window, is not an underestimate)."""
    inp = prepare_inputs("pendulum:chin", exact_runs[:1], exact_runs[1:], None, 8.0)
    bal = _balance(inp)
    assert bal.bins
    for b in bal.bins:
        assert not any(d.imbalanced for d in b.dofs.values()), b


@pytest.mark.slow
def test_the_corrected_column_takes_the_effects_force_off(buoyant):
    """With the truth's buoyancy change given as a corrected model's force (the catalogue template at the runs'
    mean depth), the corrected need moves to what was held."""
    h0 = buoyant.holdout[0]
    act = Actuation(h0.B, h0.inflow, h0.f_ref, np.asarray(buoyant.p.M_A, float))
    z_mean = float(np.nanmean(np.concatenate([pr.eta[:, 2] for pr in buoyant.runs])))
    # the truth's dB adds buoyancy (its force is -dB times the unit restoring force), as the template's dB_N does
    fitted = {"dB_N": BUOYANCY["dB0"] * (1 - BUOYANCY["beta"] * z_mean)}
    hooks = [fx.catalogue()["buoyancy_offset"].hooks(fitted, buoyant.p, act)]
    bal = _balance(buoyant, hooks)
    for b in bal.bins:
        z = b.dofs["Z"]
        assert abs(z.held - z.corrected) < 0.2 * abs(z.held - z.nominal), (b, fitted)
    assert all(b.dofs["Z"].corrected_imbalanced is not None for b in bal.bins)


@pytest.mark.slow
def test_a_speed_the_holdout_never_flies_steadily_is_named(exact_runs):
    """A holdout cut to its first surge leg (4-18 s, no hover long enough) leaves the fit runs' steady hover
    untested by it: the balance lists that bin as uncovered and the console says so."""
    runs = exact_runs
    fit = prepare_inputs("pendulum:chin", runs[:1], runs[1:], None, 8.0)
    secs = {b.speed: b.seconds for b in _balance(fit).bins if b.part == "fit"}
    short = _slice(runs[1], 4.0, 18.0)
    inp = prepare_inputs("pendulum:chin", runs[:1], [short], None, 8.0)
    bal = _balance(inp)
    held = {b.speed for b in bal.bins if b.part == "holdout"}
    missing = [s for s, sec in secs.items() if sec >= MIN_STEADY_S and s not in held]
    assert missing, (secs, held)
    assert {u[0] for u in bal.uncovered if u[1] == "fit"} == set(missing)
    text = "\n".join(balance_lines(bal.to_json()))
    assert "the holdout runs hold no steady flight at" in text


def test_the_console_names_what_was_held_against_each_need_and_the_untested_speeds():
    """An imbalanced DOF is printed with what was held and what the nominal and corrected models need; a balanced bin
    in one line; a speed only the fit runs fly steadily, as untested by the holdout."""
    off = DofBalance(held=4.1, nominal=-0.94, corrected=-0.93, se=0.06, unit="N")
    fixed = DofBalance(held=1.95, nominal=0.04, corrected=1.9, se=0.03, unit="N m")
    spoilt = DofBalance(held=0.05, nominal=0.0, corrected=0.48, se=0.02, unit="N m")
    calm = DofBalance(held=0.1, nominal=0.12, corrected=0.11, se=0.05, unit="N")
    assert off.imbalanced and off.corrected_imbalanced and not calm.imbalanced
    assert fixed.imbalanced and not fixed.corrected_imbalanced
    assert not spoilt.imbalanced and spoilt.corrected_imbalanced
    bal = SteadyBalance(bins=(BalanceBin("fit", (0.0, 0.1), 88.0, {"Z": off, "X": calm}),
                              BalanceBin("holdout", (0.1, 0.25), 51.0, {"M": fixed, "N": spoilt, "X": calm}),
                              BalanceBin("holdout", (0.25, 0.5), 9.0, {"X": calm})),
                        uncovered=(((0.0, 0.1), "fit", 88.0),), effects=("drag_centre_offset",))
    lines = balance_lines(bal.to_json())
    assert lines[1] == ("    fit, 0-0.1 m/s (88 s): Z held +4.10 N, nominal needs -0.94 N, corrected -0.93 N "
                        "(se 0.06)")
    assert "M held +1.95 N m, nominal needs +0.04 N m, corrected +1.90 N m" in lines[2]
    assert "N held +0.05 N m" in lines[2] and "X held" not in lines[2]
    assert lines[3] == "    holdout, 0.25-0.5 m/s (9 s): balanced within 3 standard errors in X"
    assert lines[4] == ("    the named effects add a steady force the thrusters did not hold (a part of them that "
                        "steady flight contradicts): N in holdout 0.1-0.25 m/s (corrected needs +0.48 N m, held "
                        "+0.05 N m)")
    assert lines[5].startswith("    the holdout runs hold no steady flight at 0-0.1 m/s (the fit runs 88 s)")
    assert balance_lines(None) == [] and balance_lines(SteadyBalance((), (), ()).to_json()) == []
