"""Launch segmentation on a field log (issue 12 item 6): angles unwrapped, only free (thrusters idle) decays."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.io.segment import find_launches, idle_mask, pwm_deadband_us, unwrap_angle, write_launches

T0 = 1_700_000_000.0
ZETA, FN, AMP = 0.08, 0.7, 0.4  # free roll decay: damping ratio, natural frequency (Hz), release roll (rad)
T_FREE = 40.0  # s, release of the free launch (thrusters go idle)


def _decay(s, amp, zeta=ZETA, fn=FN):
    wn = 2 * np.pi * fn
    wd = wn * np.sqrt(1 - zeta**2)
    return amp * np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * s))


def synthetic_dive(dt=0.02, n_thr=8):
    """Roll (rad, wrapped to (-pi, pi]) and PWM (us) of a dive.

    0-8 s: powered, level. 8-14 s: a powered barrel roll through +-180 deg (roll 0 -> 2 pi, wrapped).
    14-16 s: powered hold at 0.5 rad, then 16-30 s a decay-shaped roll *with the thrusters running* (a pilot
    rocking the vehicle): looks like a launch but is not free. 30-32 s: level. 32-40 s: thrusters hold
    0.4 rad, then at 40 s they go idle (inside the dead band, +-8 us jitter) and the vehicle decays freely.
    """
    t = np.arange(0.0, 70.0, dt)
    roll = np.zeros_like(t)
    barrel = (t >= 8) & (t < 14)
    roll[barrel] = 2 * np.pi * (t[barrel] - 8) / 6
    roll[t >= 14] = 2 * np.pi
    hold1 = (t >= 14) & (t < 16)
    roll[hold1] += 0.5
    s1 = (t >= 16) & (t < 30)
    roll[s1] += _decay(t[s1] - 16, 0.5, zeta=0.05, fn=0.6)
    hold2 = (t >= 32) & (t < T_FREE)
    roll[hold2] += AMP
    free = t >= T_FREE
    roll[free] += _decay(t[free] - T_FREE, AMP)
    wrapped = (roll + np.pi) % (2 * np.pi) - np.pi
    rng = np.random.default_rng(7)
    pwm = np.full((t.size, n_thr), 1500.0)
    pwm[t < T_FREE] = 1500 + rng.choice([-1, 1], size=(np.sum(t < T_FREE), n_thr)) * rng.uniform(80, 200, (np.sum(
        t < T_FREE), n_thr))
    pwm[free] = 1500 + rng.uniform(-8, 8, size=(free.sum(), n_thr))
    synthetic_dive.true_roll = roll
    return t, wrapped, pwm


def test_idle_mask_uses_the_t200_dead_band():
    band = pwm_deadband_us()
    assert 20 < band < 45  # us: T200 zero band, 27.7 us at 20 V .. 40 us at 10 V
    pwm = np.array([[1500, 1500 + band - 1], [1500, 1500 + band + 1], [1500, np.nan]])
    np.testing.assert_array_equal(idle_mask("pwm", pwm), [True, False, False])
    np.testing.assert_array_equal(idle_mask("pwm", np.full((3, 4), np.nan)), [True] * 3)  # a rig: no commands
    np.testing.assert_array_equal(idle_mask("thrust", [[0.1, -0.2], [0.0, 5.0]]), [True, False])
    with pytest.raises(ValueError, match="input kind"):
        idle_mask("rpm", np.zeros((2, 2)))


def test_powered_stretch_gives_no_launch_and_the_free_one_is_found(tmp_path):
    t, roll, pwm = synthetic_dive()
    # the logged roll jumps by 2 pi through +-180 deg; unwrapped it is the true roll again
    assert np.max(np.abs(np.diff(roll))) > 6
    np.testing.assert_allclose(unwrap_angle(roll), synthetic_dive.true_roll, atol=1e-9)
    # the old segmentation (no unwrapping, no free mask) cuts "launches" out of the powered stretch, at the
    # wrap jump among others: the checks below are not vacuous
    naive = find_launches(t, roll)
    assert any(x.t_release < T_FREE - 1 for x in naive) and any(x.amplitude > 2.5 for x in naive)
    assert any(x.t_release < T_FREE - 1 for x in find_launches(t, roll, angle=True))
    free = idle_mask("pwm", pwm)
    launches = find_launches(t, roll, angle=True, free=free)
    assert len(launches) == 1
    ln = launches[0]
    assert ln.t_release == pytest.approx(T_FREE, abs=0.05)
    assert ln.amplitude == pytest.approx(AMP, rel=0.02)
    assert 1 / FN == pytest.approx(ln.period, rel=0.05)
    # runs until the envelope exp(-zeta wn s) is 5 % of the release amplitude
    t_end = np.log(20) / (ZETA * 2 * np.pi * FN)
    assert t_end - 1.5 < t[ln.stop - 1] - T_FREE < t_end + 1.5
    path, = write_launches(t, roll, launches, tmp_path, "dive", "theta", angle=True)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    # written about the rest angle 0 (the barrel roll's 2 pi removed), within +-pi for the pendulum reader
    assert data[0, 1] == pytest.approx(AMP, abs=1e-3) and np.max(np.abs(data[:, 1])) <= AMP + 1e-3
    np.testing.assert_allclose(data[:, 1], _decay(data[:, 0], AMP), atol=0.02)


def test_power_returning_early_cuts_or_drops_the_launch():
    t, roll, pwm = synthetic_dive()
    free = idle_mask("pwm", pwm)
    free_short = free & (t < T_FREE + 0.8)  # power back after 0.8 s: about half a period of decay
    assert find_launches(t, roll, angle=True, free=free_short) == []
    free_cut = free & (t < T_FREE + 4.0)  # 2.8 periods: kept, cut at the first powered sample
    ln, = find_launches(t, roll, angle=True, free=free_cut)
    assert t[ln.stop - 1] < T_FREE + 4.0 and t[ln.stop] >= T_FREE + 4.0 - 1e-9


def test_convert_segments_only_the_free_launch_from_a_tlog(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    t, roll, pwm = synthetic_dive(dt=0.05)
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(tmp_path / "dive.tlog", "wb") as fh:
        for k, (ti, ph) in enumerate(zip(t, roll)):
            stamp = struct.pack(">Q", int(round((T0 + ti) * 1e6)))
            fh.write(stamp + mav.attitude_encode(int(ti * 1000), float(ph), 0.0, 0.0, 0.0, 0.0, 0.0).pack(mav))
            servo = [int(round(v)) for v in pwm[k]]
            fh.write(stamp + mav.servo_output_raw_encode(int(ti * 1e6), 0, *servo).pack(mav))
    code = main(["convert", str(tmp_path / "dive.tlog"), "--mapping", "ardusub", "--out", str(tmp_path / "dive.csv"),
                 "--allow-missing-inputs", "--segment", "phi"])
    assert code == 0
    files = sorted(tmp_path.glob("dive_launch*.csv"))
    assert len(files) == 1
    data = np.loadtxt(files[0], delimiter=",", skiprows=1)
    assert data[0, 1] == pytest.approx(AMP, abs=0.02) and np.max(np.abs(data[:, 1])) < np.pi
