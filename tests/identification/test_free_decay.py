"""Spring free-decay test (Cely 2019 sec. 3.2, eqs. 6-9): physics of the identification.

Launches here are simulated independently of the package (scipy ``solve_ivp`` on eq. 6 written in forces),
so a shared mistake in the package's simulator and its fit could not cancel out.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from identification import decay, free_decay, statistics, synthetic
from identification.free_decay import SpringRig

# Table 2 model on the 63.6 N/m spring (sec. 3.2.1)
MASS, VOLUME, K, RHO = 0.97, 344_868e-9, 63.6, 1000.0
Q_M = 1e-3 / free_decay.COUNTS_PER_MM  # encoder step, m


def spring_trace(added_mass, c, cd, area, amplitude, offset=0.0, fs=100.0, duration=6.0, hold=0.4, noise=0.0,
                 seed=0, mass=MASS, stiffness=K):
    """Eq. 6, (m + m') y'' + c y' + 1/2 rho C_D A |y'| y' + K y = 0, released from rest; held before."""
    M = mass + added_mass
    kq = 0.5 * RHO * cd * area

    def rhs(_, s):
        y, v = s
        return [v, -(c * v + kq * abs(v) * v + stiffness * y) / M]

    t = np.arange(0.0, hold + duration, 1.0 / fs)
    moving = t >= hold
    sol = solve_ivp(rhs, (t[moving][0], t[-1]), [amplitude, 0.0], t_eval=t[moving], rtol=1e-10, atol=1e-12,
                    method="DOP853")
    y = np.full(t.size, float(amplitude))
    y[moving] = sol.y[0]
    y = y + offset + noise * np.random.default_rng(seed).standard_normal(t.size)
    return t, y


def write_csv(path, t, values, column):
    path.write_text(f"t,{column}\n" + "".join(f"{a:.4f},{b:.10g}\n" for a, b in zip(t, values)))
    return path


@pytest.mark.parametrize("omega_n, cm_paper", [(7.1142, 0.8172), (7.8268, 0.1945), (6.8188, 1.1564)])
def test_table7_added_mass_coefficients(omega_n, cm_paper):
    """Eq. 7 from Table 7's omega_n, K = 63.6 N/m and Table 2's 0.97 kg / 344,868 mm^3 gives its C_m."""
    ma = free_decay.added_mass_from_frequency(omega_n, K, MASS)
    cm = free_decay.mass_coefficient(ma, RHO, VOLUME)
    assert cm == pytest.approx(cm_paper, rel=0.02)
    # and the frequency of the identified system is the measured one
    assert math.sqrt(K / (MASS + ma)) == pytest.approx(omega_n, rel=1e-12)


def test_damping_ratio_from_decrement_is_exact_for_linear_decay():
    """zeta from the log decrement of an exactly linear decay (x ~ exp(-zeta wn t) cos(wd t))."""
    for zeta in (0.01, 0.1, 0.3, 0.6):
        delta = 2 * math.pi * zeta / math.sqrt(1 - zeta ** 2)
        assert float(free_decay.damping_ratio_from_decrement(delta)) == pytest.approx(zeta, rel=1e-12)


def test_eq9_energy_balance():
    """zeta_f of eq. 9 is the equivalent linear damping of quadratic drag: energy lost per cycle matches."""
    M, area, X = 1.25, 0.0044, 0.02
    wn = math.sqrt(K / M)
    zeta_f = 0.05
    cd_eq = float(free_decay.drag_coefficient_from_fluid_damping(zeta_f, M, RHO, area, X))
    # energy per cycle: linear pi c wn X^2 with c = 2 zeta M wn; quadratic (8/3) K_Q wn^2 X^3
    e_lin = math.pi * (2 * zeta_f * M * wn) * wn * X ** 2
    e_quad = 8 / 3 * (0.5 * RHO * cd_eq * area) * wn ** 2 * X ** 3
    assert e_quad == pytest.approx(e_lin, rel=1e-12)
    # the paper's 2-D form with D x 1 m as area
    assert float(free_decay.drag_coefficient_paper_eq9(zeta_f, M, RHO, 0.1, X)) == pytest.approx(
        float(free_decay.drag_coefficient_from_fluid_damping(zeta_f, M, RHO, 0.1, X)))


@pytest.mark.parametrize("offset", [0.25, -0.08])
def test_metres_log_with_rest_offset_recovers_eq6(tmp_path, offset):
    """A t,y log in metres (continuous sensor, 0.1 mm noise) hanging at a nonzero rest reading."""
    area, ma, c, cd = 0.0050, 0.30, 0.4, 1.2
    t, y = spring_trace(ma, c, cd, area, 0.03, offset=offset, noise=1e-4, seed=3)
    launch = free_decay.read_spring_launch(write_csv(tmp_path / "surge_metres.csv", t, y, "y"))
    assert launch.resolution == 0.0  # continuous: no quantisation step
    res = free_decay.identify_launch(launch, SpringRig(MASS, VOLUME, K, area))
    cm = ma / (RHO * VOLUME)
    assert res["Cm"] == pytest.approx(cm, rel=0.02)
    assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
    assert res["CD"] == pytest.approx(cd, rel=0.05)
    assert res["KQ"] == pytest.approx(0.5 * RHO * cd * area, rel=0.05)
    assert res["KL"] == pytest.approx(c, rel=0.20)  # no mechanical damping given: all linear damping
    assert res["amplitude"] == pytest.approx(0.03, rel=0.02)  # measured from the rest offset
    lo, hi = res["Cm_ci95"]
    assert lo < res["Cm"] < hi
    # peak speed of the launch: below the undamped A wn, above half of it
    wn = math.sqrt(K / (MASS + ma))
    assert 0.5 * 0.03 * wn < res["v_max"] < 0.03 * wn


def test_counts_and_metres_logs_agree(tmp_path):
    """The same quantised launch as encoder counts and as metres gives the same coefficients."""
    tr = synthetic.paper_spring_truth()["sway"]
    x = synthetic.spring_launch(tr, 0.02, np.random.default_rng(5))
    p_counts = synthetic.write_launch(x, tmp_path / "a.csv")
    q = 1e-3 / free_decay.COUNTS_PER_MM
    p_m = write_csv(tmp_path / "b.csv", x.t, x.values * q, "y")
    a = free_decay.read_spring_launch(p_counts)
    b = free_decay.read_spring_launch(p_m)
    assert a.resolution == pytest.approx(q)
    assert b.resolution == pytest.approx(q, rel=1e-6)  # the quantisation step is found in a metres log
    rig = SpringRig(tr.mass, tr.volume, tr.stiffness, tr.area)
    ra, rb = free_decay.identify_launch(a, rig), free_decay.identify_launch(b, rig)
    for k in ("Cm", "CD", "KL"):
        assert ra[k] == pytest.approx(rb[k], rel=1e-4)


def test_heavier_model_and_stiffer_spring():
    """Beyond Table 2: a 2 kg model on a 150 N/m spring, with strong linear damping (zeta_s ~ 0.1)."""
    area, ma, c, cd = 0.012, 0.9, 3.5, 0.8
    t, y = spring_trace(ma, c, cd, area, 0.04, offset=0.1, noise=1e-4, seed=4, mass=2.0, stiffness=150.0)
    rig = SpringRig(2.0, 1.2e-3, 150.0, area, mechanical_damping=3.0)
    res = free_decay.identify_launch(decay.Launch("heavy.csv", t, y), rig)
    assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
    assert res["Cm"] == pytest.approx(ma / (RHO * 1.2e-3), rel=0.02)
    assert res["CD"] == pytest.approx(cd, rel=0.05)
    assert res["KL"] == pytest.approx(c - 3.0, rel=0.20)  # fluid part after the rig's damping


@pytest.mark.slow
def test_graphical_method_agrees_on_Cm_and_its_CD_carries_the_rig_damping():
    """The paper's peak method: C_m as the output-error fit; C_D biased by linear damping unless it is given.

    Eq. 9 attributes all of zeta to quadratic drag. A linear damping c adds zeta_s = c / (2 M wn), an
    equivalent drag 3 pi c / (4 rho A wn X) that grows as the amplitude X falls; the output-error fit
    separates the two terms and is unaffected.
    """
    truth = synthetic.paper_spring_truth()
    launches = synthetic.protocol("spring", truth, seed=7)
    q = 1e-3 / free_decay.COUNTS_PER_MM
    for axis, tr in truth.items():
        xs = [x for x in launches if x.axis == axis]
        logs = [decay.Launch(x.name, x.t, x.values * q, q) for x in xs]
        bare = SpringRig(tr.mass, tr.volume, tr.stiffness, tr.area)
        known = SpringRig(tr.mass, tr.volume, tr.stiffness, tr.area, mechanical_damping=tr.mechanical_damping)
        oe = [free_decay.identify_launch(x, bare) for x in logs]
        g_bare = [free_decay.identify_launch(x, bare, method="graphical") for x in logs]
        g_known = [free_decay.identify_launch(x, known, method="graphical") for x in logs]
        oe_known = [free_decay.identify_launch(x, known) for x in logs]
        cm_oe = statistics.aggregate([r["Cm"] for r in oe], [r["Cm_se"] for r in oe])["value"]
        cm_g = statistics.aggregate([r["Cm"] for r in g_bare])["value"]
        assert cm_g == pytest.approx(cm_oe, rel=0.02)
        assert cm_g == pytest.approx(tr.Cm, rel=0.02)
        # output-error C_D does not depend on the rig damping being known; K_L moves by exactly c
        for a, b in zip(oe, oe_known):
            assert a["CD"] == pytest.approx(b["CD"], rel=1e-9)
            assert a["KL"] - b["KL"] == pytest.approx(tr.mechanical_damping, rel=1e-9)
        # graphical: with c known it is unbiased on the aggregate; without, every launch reads too high
        cd_known = statistics.aggregate([r["CD"] for r in g_known])["value"]
        assert cd_known == pytest.approx(tr.CD, rel=0.10)
        excess = np.array([b["CD"] - tr.CD for b in g_bare])
        assert np.all(excess > 0)
        amps = np.array([abs(x.amplitude) for x in xs])
        # the excess falls like 1/amplitude: between 10 mm and 40 mm launches by a factor near 4
        ratio = np.median(excess[amps < 0.015]) / np.median(excess[amps > 0.035])
        assert 2.5 < ratio < 5.5, ratio
        # and its size is the energy-balance equivalent drag of c at the cycle amplitude
        for b, k in zip(g_bare, g_known):
            x_cycle = 3 * math.pi * tr.mechanical_damping / (4 * RHO * tr.area * b["omega_n"] * (b["CD"] - k["CD"]))
            assert 0.5 < x_cycle / abs(b["amplitude"]) < 1.0  # amplitude of the first cycle after release


def test_rig_validation():
    with pytest.raises(ValueError, match="stiffness"):
        SpringRig(MASS, VOLUME, -1.0, 0.01)
    with pytest.raises(ValueError, match="area"):
        SpringRig(MASS, VOLUME, K, float("nan"))
    with pytest.raises(ValueError, match="unknown fit method"):
        t, y = spring_trace(0.3, 0.4, 1.2, 0.005, 0.03)
        free_decay.identify_launch(decay.Launch("x.csv", t, y), SpringRig(MASS, VOLUME, K, 0.005), method="bogus")


def test_peak_speed_and_reynolds_number_of_both_methods():
    """The launch's peak speed (for Re, Fig. 17-18) from a quantised encoder log is close to the true one.

    True peak speed from the independent simulation; raw differences of 0.41 mm encoder steps at 100 Hz
    would overstate it by tens of per cent.
    """
    area, ma, c, cd = 0.0044, 0.28, 0.5, 1.4
    for amp in (0.01, 0.04):
        t, y = spring_trace(ma, c, cd, area, amp, offset=0.1, noise=2e-4, seed=int(amp * 1e3))
        t_fine, y_fine = spring_trace(ma, c, cd, area, amp, fs=2000.0)
        v_true = float(np.max(np.abs(np.gradient(y_fine, t_fine))))
        counts = np.round(y / Q_M)
        launch = decay.Launch("enc.csv", t, counts * Q_M, Q_M)
        rig = SpringRig(MASS, VOLUME, K, area)
        for method in ("output-error", "graphical"):
            res = free_decay.identify_launch(launch, rig, method=method)
            assert res["v_max"] == pytest.approx(v_true, rel=0.06), (amp, method)
            assert res["Re"] == pytest.approx(res["v_max"] * math.sqrt(area) / free_decay.NU_WATER)


def test_log_that_records_rest_and_the_pull_before_the_release():
    """A real log may start with the model at rest, pulled out by hand, held, then released."""
    area, ma, c, cd = 0.0044, 0.28, 0.5, 1.4
    t, y = spring_trace(ma, c, cd, area, -0.03, offset=0.1, noise=2e-4, seed=1, hold=1.0)
    pre_t = np.arange(0.0, 1.5, 0.01)
    pull = np.where(pre_t < 1.0, 0.0, -0.03 * (pre_t - 1.0) / 0.5)  # 1 s at rest, 0.5 s pull
    pre = pull + 0.1 + 2e-4 * np.random.default_rng(2).standard_normal(pre_t.size)
    log = decay.Launch("pulled.csv", np.concatenate([pre_t, t + 1.5]), np.concatenate([pre, y]))
    plain = free_decay.identify_launch(decay.Launch("plain.csv", t, y), SpringRig(MASS, VOLUME, K, area))
    res = free_decay.identify_launch(log, SpringRig(MASS, VOLUME, K, area))
    assert res["amplitude"] == pytest.approx(0.03, rel=0.02)
    assert res["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
    assert res["CD"] == pytest.approx(cd, rel=0.05)
    for k in ("Cm", "CD", "KL"):
        assert res[k] == pytest.approx(plain[k], rel=1e-6)


def test_irregular_time_stamps():
    """Serial samples stamped on arrival (irregular, ~110 Hz): the ODE fit integrates between the stamps."""
    area, ma, c, cd = 0.0044, 0.28, 0.5, 1.4
    t, y = spring_trace(ma, c, cd, area, 0.03, offset=0.1, noise=2e-4, seed=1, fs=1000.0)
    idx = np.sort(np.random.default_rng(0).choice(t.size, 700, replace=False))
    launch = decay.Launch("jitter.csv", t[idx], y[idx])
    t_fine, y_fine = spring_trace(ma, c, cd, area, 0.03, fs=2000.0)
    v_true = float(np.max(np.abs(np.gradient(y_fine, t_fine))))
    res = free_decay.identify_launch(launch, SpringRig(MASS, VOLUME, K, area))
    assert res["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
    assert res["CD"] == pytest.approx(cd, rel=0.05)
    assert res["KL"] == pytest.approx(c, rel=0.20)
    graph = free_decay.identify_launch(launch, SpringRig(MASS, VOLUME, K, area, mechanical_damping=c),
                                       method="graphical")
    assert graph["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
    assert graph["v_max"] == pytest.approx(v_true, rel=0.06)
