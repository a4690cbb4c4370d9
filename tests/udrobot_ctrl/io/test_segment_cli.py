"""Launch segmentation (pendulum from a .tlog, spring from a bag), the convert CLI, and the Tartan AUV CSV pair."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io.runlog import read_run
from udrobot_ctrl.io.segment import find_launches

T0 = 1_700_000_000.0
SHARED = Path(__file__).resolve().parents[3] / ".." / "shared"
TARTAN = SHARED / "data" / "tartan_auv_2022-12-01"


def decay_signal(t, releases, amp, zeta=0.08, fn=0.7, hold=1.5):
    """Held at `amp` for `hold` s before each release, then a damped oscillation (exact free-decay solution)."""
    wn = 2 * np.pi * fn
    wd = wn * np.sqrt(1 - zeta**2)
    y = np.zeros_like(t)
    for tr in releases:
        h = (t >= tr - hold) & (t <= tr)
        y[h] = amp
        s = t - tr
        d = (s > 0)
        y[d] += amp * np.exp(-zeta * wn * s[d]) * (np.cos(wd * s[d]) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * s[d]))
        y[d & (t > tr + 14)] = 0.0  # back at rest before the next hold
    return y


def test_pendulum_launches_from_tlog(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    t = np.arange(0.0, 40.0, 0.01)  # ArduPilot EKF attitude at 100 Hz
    releases = [3.0, 22.0]
    theta = decay_signal(t, releases, 0.5)
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(tmp_path / "pendulum.tlog", "wb") as fh:
        for ti, th in zip(t, theta):
            msg = mav.attitude_encode(int(ti * 1000), 0.0, th, 0.0, 0.0, 0.0, 0.0)
            fh.write(struct.pack(">Q", int(round((T0 + ti) * 1e6))) + msg.pack(mav))
    code = main(["convert", str(tmp_path / "pendulum.tlog"), "--mapping", "ardusub", "--out",
                 str(tmp_path / "pend.csv"), "--allow-missing-inputs", "--segment", "theta"])
    assert code == 0
    run = read_run(tmp_path / "pend.csv")
    launches = find_launches(run.t, run.channels["theta"])
    assert [round(x.t_release, 2) for x in launches] == releases
    files = sorted(tmp_path.glob("pend_launch*.csv"))
    assert len(files) == 2
    header = files[0].read_text().splitlines()[0]
    assert header == "t,theta"
    data = np.loadtxt(files[0], delimiter=",", skiprows=1)
    assert data[0, 0] == 0.0 and data[0, 1] == pytest.approx(0.5, abs=1e-6)
    # the decay runs until the envelope is < 5 % of the release amplitude: exp(-zeta wn t) = 0.05
    t_end = np.log(20) / (0.08 * 2 * np.pi * 0.7)
    assert t_end - 1.5 < data[-1, 0] < t_end + 1.5
    # refusing to overwrite the launch files
    assert main(["convert", str(tmp_path / "pendulum.tlog"), "--out", str(tmp_path / "pend.csv"), "--force",
                 "--allow-missing-inputs", "--segment", "theta"]) == 2


def test_spring_launch_from_bag_with_custom_mapping(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    Float64 = store.types["std_msgs/msg/Float64"]
    t = np.arange(0.0, 20.0, 0.02)
    y = decay_signal(t, [2.0], 0.08, zeta=0.15, fn=1.2)
    with Writer(tmp_path / "spring.bag") as writer:
        conn = writer.add_connection("/encoder/position", "std_msgs/msg/Float64", typestore=store)
        for ti, yi in zip(t, y):
            writer.write(conn, int(round((T0 + ti) * 1e9)), store.serialize_ros1(Float64(data=yi), conn.msgtype))
    mapping = tmp_path / "spring.toml"
    mapping.write_text('''[mapping]
format = "udrobot-mapping/1"
name = "spring-encoder"
source = "ros"
input_kind = "thrust"
[[channels]]
to = "y"
stream = "/encoder/position"
field = "data"
scale = 0.001   # encoder in mm
''')
    (tmp_path / "spring_mm.bag").write_bytes(b"")  # unrelated file, never touched
    run = convert_log(tmp_path / "spring.bag", mapping, require_inputs=False)
    np.testing.assert_allclose(run.channels["y"], y * 1e-3, atol=1e-12)  # samples of the only stream
    launches = find_launches(run.t, run.channels["y"])
    assert len(launches) == 1 and launches[0].t_release == pytest.approx(2.0, abs=0.02)
    assert launches[0].amplitude == pytest.approx(0.08e-3, rel=1e-6)


def test_cli_errors_are_clean(tmp_path, capsys):
    assert main(["convert", str(tmp_path / "x.tlog"), "--out", str(tmp_path / "o.csv")]) == 2
    (tmp_path / "x.tlog").write_bytes(b"\x00" * 30)
    assert main(["convert", str(tmp_path / "x.tlog"), "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "byte offset 0" in err and not (tmp_path / "o.csv").exists()
    assert main(["convert", str(tmp_path / "x.tlog"), "--mapping", "nope", "--out", "o.csv"]) == 2
    assert "unknown mapping 'nope'" in capsys.readouterr().err


@pytest.mark.skipif(not TARTAN.is_dir(), reason="shared Tartan AUV data not present")
def test_tartan_pair_converts_to_tau_run(tmp_path):
    nav = TARTAN / "navigation_state_5.csv"
    before = nav.read_bytes()
    out = tmp_path / "tartan5.csv"
    assert main(["convert", str(nav), "--mapping", "tartan-auv", "--out", str(out)]) == 0
    run = read_run(out)
    assert nav.read_bytes() == before
    assert run.input_kind == "tau" and run.dt_median == pytest.approx(0.02)
    assert 55 < run.duration < 61
    assert {"x", "y", "z", "phi", "theta", "psi", "u", "v", "w"} <= set(run.channels)
    z = run.channels["z"]
    assert np.nanmin(z) >= 0 and np.nanmax(z) <= 1.7  # pool depth, positive down
    assert np.nanmax(np.abs(np.column_stack([run.channels[c] for c in "uvw"]))) < 0.5
    assert -40 < np.nanmean(run.channel("tau_Z")) < 40
    notes = run.metadata["notes"]
    assert "navigation_state: %time (bag record time) - header.stamp delay median" in notes
    assert "BODY-frame" in notes
    # the wrench's own record times are kept: t_source steps through them
    assert np.all(np.diff(run.extra["t_source"]) >= 0)


@pytest.mark.parametrize("channel, words", [("nosuch", ["--segment", "nosuch"]), ("phi", ["no launch", "'phi'"])])
def test_a_segment_that_cannot_be_cut_is_refused_before_the_run_is_written(tmp_path, capsys, channel, words):
    """Issue 62: --segment was checked only after --out had been written; now nothing is written."""
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    t = np.arange(0.0, 20.0, 0.01)
    theta = decay_signal(t, [3.0], 0.5)  # launches in theta only; phi stays at rest
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    log = tmp_path / "pendulum.tlog"
    with open(log, "wb") as fh:
        for ti, th in zip(t, theta):
            msg = mav.attitude_encode(int(ti * 1000), 0.0, th, 0.0, 0.0, 0.0, 0.0)
            fh.write(struct.pack(">Q", int(round((T0 + ti) * 1e6))) + msg.pack(mav))
    capsys.readouterr()
    assert main(["convert", str(log), "--mapping", "ardusub", "--out", str(tmp_path / "pend.csv"),
                 "--allow-missing-inputs", "--segment", channel]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and all(w in err for w in words), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pendulum.tlog"]  # no run, no sidecar, no launch
