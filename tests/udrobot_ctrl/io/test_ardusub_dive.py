"""A real ArduSub dive end to end: the vehicle from its active motor outputs, DVL and EKF velocities, autopilot context
columns, invalid rangefinder readings, surface / disarmed stretches cut out, growing QGC CSV rows. Dataflash logs are
packed with pymavlink's own format table (DFReader.FORMAT_TO_STRUCT), tlogs with pymavlink's encoder; the shared sea
dive (../shared/data/guided_above_terrain) when present."""
from __future__ import annotations

import json

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.udrobot_ctrl.io.test_field_logs import SHARED, T0, _mav, write_df, write_events
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import LogImportError
from udrobot_ctrl.io.mavlink import VehicleInfo, choose_vehicle, classify_outputs
from udrobot_ctrl.io.runlog import read_run, write
from udrobot_ctrl.io.streams import Stream

DIVE = SHARED / "data" / "guided_above_terrain" / "00000029_filtered.BIN"
DEG = np.pi / 180
BODY_VEL = np.array([0.3, -0.1, 0.05])  # m/s, body FRD
PHI, THETA = 0.05, -0.04  # rad


def psi_of(t):
    """Yaw (rad) turning at 2 deg/s from 30 deg (log time t, s)."""
    return (30.0 + 2.0 * (t - 100.0)) * DEG


def rotation(phi, theta, psi):
    """Body -> NED, ZYX: Rz(psi) Ry(theta) Rx(phi)."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    rz = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1]])
    ry = np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    rx = np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return rz @ ry @ rx


def depth_of(t):
    """At the surface until 110 s, down to 5 m at 120 s, held (log time, s)."""
    return np.interp(t, [100.0, 110.0, 120.0, 200.0], [0.0, 0.0, 5.0, 5.0])


# ------------------------------------------------------------------------------------------- dataflash

LAYOUTS = {
    "ATT": "Qffffff:TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw",
    "BARO": "QBff:TimeUS,I,Alt,Press",
    "RCOU": "Q" + "H" * 14 + ":TimeUS," + ",".join(f"C{k}" for k in range(1, 15)),
    "RCIN": "Q" + "H" * 14 + ":TimeUS," + ",".join(f"C{k}" for k in range(1, 15)),
    "RFND": "QBfBBb:TimeUS,Instance,Dist,Stat,Orient,Quality",
    "VISO": "Qffffffff:TimeUS,dt,AngDX,AngDY,AngDZ,PosDX,PosDY,PosDZ,conf",
    "XKF1": "QBffffffff:TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,PN,PE",
    "MODE": "QMBB:TimeUS,Mode,ModeNum,Rsn",
    "EV": "QB:TimeUS,Id",
    "CTUN": "Qff:TimeUS,DAlt,Alt",
    "RATE": "Qfffffffffffff:TimeUS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew",
    "MOTB": "Qfff:TimeUS,LiftMax,BatVolt,ThLimit",
    "PARM": "QNf:TimeUS,Name,Value",
}


def write_dataflash(path, records):
    """FMT records for LAYOUTS, then the data records (name, values) in the given order."""
    return write_df(path, records, LAYOUTS)


def motor_pwm(t, n_motors):
    """Motor outputs 1..n moving around 1500 us (each its own phase), lights on output n + 2, the rest 0."""
    out = [int(1500 + 60 * np.sin(0.7 * t + k)) + (20 if k % 2 else -20) for k in range(n_motors)]
    out += [0] * (14 - n_motors)
    out[n_motors + 1] = 1650 if t < 130 else 1700  # lights: 1594-1708 us, never near the motors' neutral
    return out


RFND_BAD = {"zero": [101.0, 121.0, 122.0, 123.0, 150.0], "stat": [124.0, 125.0, 126.0, 127.0],
            "quality": [128.0, 129.0, 131.0]}


def altitude_of(t):
    return 2.0 + 0.01 * (t - 100.0)


def dive_dataflash(path, n_motors=8, viso=True, lights=True):
    """60 s of an ArduSub dive (log time 100..160 s): at the surface until 110 s, 5 m from 120 s; armed at 105 s,
    disarmed 140..145 s; constant body velocity BODY_VEL while turning at 2 deg/s; bad DVL confidence and invalid
    rangefinder readings at known times."""
    recs = [("MODE", (int(100.0e6), 19, 19, 1)), ("EV", (int(105.0e6), 10)), ("EV", (int(106.0e6), 15)),
            ("EV", (int(140.0e6), 11)), ("EV", (int(145.0e6), 10)), ("MODE", (int(120.0e6), 2, 2, 1))]
    bad_viso = []
    for k, t in enumerate(np.arange(100.0, 160.0, 0.1)):
        us = int(round(t * 1e6))
        psi = psi_of(t)
        recs.append(("ATT", (us, 1.0, PHI / DEG, -2.0, THETA / DEG, 45.0 + t - 100.0, np.degrees(psi) % 360)))
        recs.append(("BARO", (us + 1, 1, -depth_of(t), 0.0)))
        pwm = motor_pwm(t, n_motors)
        if not lights:
            pwm[n_motors + 1] = 0
        recs.append(("RCOU", (us + 2, *pwm)))
        recs.append(("RCIN", (us + 3, *[1500 + 10 * c for c in range(1, 9)], *[0] * 6)))
        vned = rotation(PHI, THETA, psi) @ BODY_VEL
        recs.append(("XKF1", (us + 4, 0, 0.0, 0.0, 0.0, *vned, 0.02 * (t - 100.0), -0.01 * (t - 100.0))))
        recs.append(("XKF1", (us + 5, 1, 0.0, 0.0, 0.0, 9.0, 9.0, 9.0, 99.0, 99.0)))  # core 1: not used
        recs.append(("CTUN", (us + 6, -5.0, -depth_of(t))))
        recs.append(("RATE", (us + 7, 3.0, 0.0, 0.1, -4.0, 0.0, 0.2, 5.0, 0.0, -0.3, 0.0, 0.0, 0.45, 0.0)))
        recs.append(("MOTB", (us + 8, 0.9, 1.05, 1.0)))
        for j in range(2):  # rangefinder at 20 Hz
            tr = t + 0.05 * j
            bad = [kind for kind, times in RFND_BAD.items() if j == 0 and np.isclose(tr, times).any()]
            dist = 0.0 if bad == ["zero"] else altitude_of(tr)
            stat = 1 if bad == ["stat"] else 4
            quality = 5 if bad == ["quality"] else 80
            recs.append(("RFND", (int(round(tr * 1e6)) + 9, 0, dist, stat, 25, quality)))
        if viso and k % 5 != 4:  # 8 Hz: four deltas per 0.5 s
            dt = 0.125
            bad = k in (250, 251, 300)  # low confidence: garbage deltas the converter must drop
            delta = np.array([1.0, 1.0, 1.0]) if bad else BODY_VEL * dt
            if bad:
                bad_viso.append(t)
            recs.append(("VISO", (us + 10, dt, 0.0, 0.0, 0.0, *delta, 20.0 if bad else 95.0)))
    recs.sort(key=lambda r: r[1][0])
    return write_dataflash(path, recs)


def log_time(run):
    """Log time (s) of each row: the RCOU stamp at or before the first row (10 Hz) + t - t of the first row (t is the
    converted log's t, which a cut does not shift)."""
    return run.extra["t_source"][0] + run.t - run.t[0]


def test_dataflash_dive_heavy_from_outputs_dvl_context_and_cuts(tmp_path):
    run = convert_log(dive_dataflash(tmp_path / "00000007.BIN"), "ardusub")
    notes = run.metadata["notes"]
    # vehicle: 8 moving outputs, lights on output 10 not a motor, FRAME_CONFIG absent
    assert run.metadata["vehicle"] == "bluerov2-heavy" and run.inputs.shape[1] == 8
    assert "vehicle: inferred bluerov2-heavy (8 thrusters) from the logged outputs" in notes
    assert "RCOU output 10: other (1650..1700 us" in notes
    t = log_time(run)
    # every valid stretch kept, each a segment: from 0.3 m on the way down (110.6 s) to the disarm at 140 s, and
    # from the re-arm at 145 s to the end; each segment and each cut stretch listed with its span and reason
    seg = run.segment
    one = seg == 1
    assert set(np.unique(seg)) == {1, 2} and np.all(np.diff(seg) >= 0)
    assert 110.5 < t[one][0] < 110.75 and 139.85 < t[one][-1] < 140.0
    assert 144.95 < t[~one][0] < 145.15 and t[~one][-1] > 159.8
    assert "cut: kept 2 segment(s)" in notes and notes.count("cut: segment ") == 2
    assert "at or near the surface (z < 0.3 m, assumed threshold)" in notes
    assert notes.count("cut: left out") == 2 and "disarmed (armed = 0)" in notes
    # the same cut, recorded for the tools that read the sidecar: the span kept, its segments, of how many rows,
    # share failing each check; t is the converted log's t in the file, the notes and the record alike
    cut = run.metadata["cut"]
    segments = cut["kept"]["segments"]
    assert [s["segment"] for s in segments] == [1, 2]
    assert sum(s["rows"][1] - s["rows"][0] + 1 for s in segments) == run.n and cut["kept"]["of"] > run.n
    assert (cut["kept"]["t_start"], cut["kept"]["t_stop"]) == (run.t[0], run.t[-1])
    assert segments[1]["t_start"] == run.t[~one][0]
    assert 0 < cut["invalid_share"]["disarmed (armed = 0)"] < 1
    np.testing.assert_allclose(run.channels["z"], depth_of(t), atol=0.06)  # t from the 10 Hz stamp: 0.1 s x 0.5 m/s
    # inputs: RCOU C1..C8 held (10 Hz) -> exactly the logged values of the RCOU sample in force
    stamp = run.extra["t_source"]
    expected = np.array([motor_pwm(s - 2e-6, 8)[:8] for s in stamp], float)
    np.testing.assert_array_equal(run.inputs, expected)
    # u v w from the DVL (body, deltas over dt), the three low-confidence deltas dropped and counted
    for k, name in enumerate("uvw"):  # the last DVL delta is stamped mid-interval: the log's last rows have none
        vel = run.channels[name]
        assert np.isfinite(vel[one]).all() and np.isfinite(vel[~one]).mean() > 0.9
        np.testing.assert_allclose(vel[np.isfinite(vel)], BODY_VEL[k], atol=1e-6)
    assert "source: u/v/w <- VISO[PosDX,PosDY,PosDZ,dt]: DVL-measured" in notes
    assert "3 of 480 samples invalid and dropped (3 low DVL confidence" in notes
    # x y from the EKF (core 0 only), tagged as an estimate
    np.testing.assert_allclose(run.channels["x"], 0.02 * (t - 100.0), atol=2.1e-3)
    np.testing.assert_allclose(run.channels["y"], -0.01 * (t - 100.0), atol=1.1e-3)
    assert "source: x/y <- XKF1[PN,PE]: EKF-estimated" in notes
    # altitude: 12 invalid readings dropped, counted per reason (the one at 101 s lies outside the kept segments
    # but is counted: the counts are per log; the one at 150 s leaves a gap in segment 2)
    assert ("RFND[Dist] -> altitude: 12 of 1200 samples invalid and dropped (5 zero distance (no echo); 4 status not "
            "Good (Stat != 4); 3 low Quality") in notes
    alt = run.channels["altitude"]
    assert np.isfinite(alt[one]).all() and np.isfinite(alt[~one]).mean() > 0.9
    ok = np.isfinite(alt)
    np.testing.assert_allclose(alt[ok], altitude_of(t[ok]), atol=2e-3)
    assert "RNGFND1_MIN_CM, RNGFND1_MAX_CM not in the log" in notes
    # autopilot context columns, held
    ex = run.extra
    np.testing.assert_array_equal(ex["mode"], np.where(stamp < 120.0, 19.0, 2.0))
    np.testing.assert_array_equal(ex["armed"], 1.0)
    for c in range(1, 9):
        np.testing.assert_array_equal(ex[f"rcin_{c}"], 1500 + 10 * c)
    np.testing.assert_allclose(ex["roll_target"], 1.0 * DEG, rtol=1e-6)
    np.testing.assert_allclose(ex["pitch_target"], -2.0 * DEG, rtol=1e-6)
    np.testing.assert_allclose(ex["yaw_target"], (45.0 + stamp - 3e-6 - 100.0) * DEG, atol=1e-6)
    np.testing.assert_allclose(ex["z_target"], 5.0)
    np.testing.assert_allclose([ex["p_target"][0], ex["q_target"][0], ex["r_target"][0]],
                               np.array([3.0, -4.0, 5.0]) * DEG, rtol=1e-6)
    np.testing.assert_allclose([ex[f"out_{a}"][0] for a in ("roll", "pitch", "yaw", "throttle")],
                               [0.1, 0.2, -0.3, 0.45], rtol=1e-6)
    np.testing.assert_allclose([ex["lift_max"][0], ex["bat_volt_scale"][0]], [0.9, 1.05], rtol=1e-6)
    # the run round-trips with its extra columns
    write(run, tmp_path / "dive.csv")
    back = read_run(tmp_path / "dive.csv")
    assert back.inputs.shape[1] == 8 and "z_target" in back.extra and "armed" in back.extra


def test_ekf_velocity_is_rotated_to_body_when_there_is_no_dvl(tmp_path):
    """XKF1 VN/VE/VD is the NED velocity R(phi, theta, psi) v_body while yawing 2 deg/s: rotated back with the logged
    attitude it gives the body velocity (checks the rotation's direction and axes)."""
    run = convert_log(dive_dataflash(tmp_path / "e.BIN", viso=False), "ardusub", cut=False)
    ok = np.isfinite(run.channels["u"])
    assert ok.mean() > 0.99
    # ATT angles and XKF1 velocities are both linear in the 0.1 s interpolation: residual from the turn only
    for k, name in enumerate("uvw"):
        np.testing.assert_allclose(run.channels[name][ok], BODY_VEL[k], atol=2e-4)
    assert "source: u/v/w <- XKF1[VN,VE,VD]: EKF-estimated" in run.metadata["notes"]
    assert "cut:" not in run.metadata["notes"]  # cut=False keeps every row
    assert run.duration > 59.0


def test_six_outputs_give_bluerov2_and_ambiguous_outputs_are_refused(tmp_path):
    run = convert_log(dive_dataflash(tmp_path / "six.BIN", n_motors=6, viso=False), "ardusub")
    assert run.metadata["vehicle"] == "bluerov2" and run.inputs.shape[1] == 6
    assert "RCOU output 8: other" in run.metadata["notes"]  # the lights
    # seven moving outputs: no ArduSub frame has 7 -> refused, asking for --vehicle
    seven = dive_dataflash(tmp_path / "seven.BIN", n_motors=7, viso=False)
    with pytest.raises(LogImportError, match=r"seven.BIN: the log does not name its vehicle .*--vehicle NAME"):
        convert_log(seven, "ardusub")
    # a vehicle with fewer thrusters than the moving outputs would drop some: refused, naming them
    heavy = dive_dataflash(tmp_path / "eight.BIN", viso=False)
    with pytest.raises(LogImportError, match=r"vehicle bluerov2 has 6 thrusters .* output\(s\) 7, 8 also drive motors"):
        convert_log(heavy, "ardusub", vehicle="bluerov2")
    run = convert_log(seven, "ardusub", vehicle="bluerov2-heavy")
    assert run.inputs.shape[1] == 8 and "vehicle: bluerov2-heavy with 8 thrusters given by --vehicle" in \
        run.metadata["notes"]
    # its eighth output carries no pulse (0 us): an ESC without a signal stops its motor -> written as 1500 us, noted
    np.testing.assert_array_equal(run.inputs[:, 7], 1500.0)
    assert "pwm_8: " in run.metadata["notes"] and "at 0 us (no pulse: the ESC stops its motor)" in \
        run.metadata["notes"]
    with pytest.raises(LogImportError, match="unknown thruster count"):
        convert_log(seven, "ardusub", vehicle="nautilus")


def test_convert_cli_vehicle_option_and_refusal(tmp_path, capsys):
    seven = dive_dataflash(tmp_path / "seven.BIN", n_motors=7, viso=False)
    assert main(["convert", str(seven), "--out", str(tmp_path / "a.csv")]) == 2
    assert "--vehicle NAME" in capsys.readouterr().err
    assert main(["convert", str(seven), "--vehicle", "bluerov2-heavy", "--out", str(tmp_path / "a.csv")]) == 0
    out = capsys.readouterr().out
    assert "vehicle bluerov2-heavy" in out and "cut: kept 2 segment(s)" in out and "cut: segment 2: rows" in out
    assert read_run(tmp_path / "a.csv").inputs.shape[1] == 8


# ------------------------------------------------------------------------------------------- tlog


def dive_tlog(path, dvl=True):
    """A tlog of a BlueROV2 (6 moving outputs, lights on 8; no FRAME_CONFIG): HEARTBEAT armed from 10 s, disarmed
    again at 50 s; SCALED_PRESSURE2 depth (surface until 5 s, 3 m from 15 s); DVL VISION_POSITION_DELTA (or none);
    LOCAL_POSITION_NED; DISTANCE_SENSOR with out-of-range and low-quality readings; RC_CHANNELS; ATTITUDE_TARGET."""
    mav = _mav()
    ev = []
    for t in np.arange(0.0, 60.0, 1.0):
        armed = 10.0 <= t < 50.0
        ev.append((t, mav.heartbeat_encode(12, 3, 81 | (128 if armed else 0), 19 if t < 30 else 2, 4)))
    gcs = mav2.MAVLink(None, srcSystem=255, srcComponent=190)  # a ground station's heartbeat: never the vehicle's
    ev += [(t + 0.5, gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs)) for t in np.arange(0.0, 60.0, 1.0)]
    for t in np.arange(0.01, 60.0, 0.05):
        psi = psi_of(100.0 + t)
        ev.append((t, mav.attitude_encode(int(t * 1000), PHI, THETA, (psi + np.pi) % (2 * np.pi) - np.pi,
                                          0.0, 0.0, 2.0 * DEG)))
    for t in np.arange(0.02, 60.0, 0.1):
        depth = np.interp(t, [0, 5, 15, 60], [0.0, 0.0, 3.0, 3.0])
        ev.append((t, mav.scaled_pressure2_encode(int(t * 1000), (101325.0 + 9810.0 * depth) / 100.0, 0.0, 1200)))
        vned = rotation(PHI, THETA, psi_of(100.0 + t)) @ BODY_VEL
        ev.append((t + 0.001, mav.local_position_ned_encode(int(t * 1000), 0.1 * t, 0.05 * t, depth, *vned)))
        servo = [int(1500 + 50 * np.sin(0.5 * t + k)) for k in range(6)] + [0, 1650] + [0] * 8
        ev.append((t + 0.002, mav.servo_output_raw_encode(int(t * 1e6), 0, *servo)))
        ev.append((t + 0.003, mav.rc_channels_encode(int(t * 1000), 8, *[1500 + 10 * c for c in range(1, 9)],
                                                     *[0] * 10, 255)))
        q = [np.cos(0.05), 0.0, 0.0, np.sin(0.05)]  # yaw target 0.1 rad
        ev.append((t + 0.004, mav.attitude_target_encode(int(t * 1000), 0, q, 0.01, -0.02, 0.03, 0.5)))
        if dvl:
            k = int(round(t / 0.1))
            conf = 10.0 if k % 50 == 7 else 90.0
            delta = [1.0, 1.0, 1.0] if conf < 50 else list(BODY_VEL * 0.1)
            ev.append((t + 0.005, mav.vision_position_delta_encode(int(t * 1e6), 100_000, [0, 0, 0], delta, conf)))
    for k, t in enumerate(np.arange(0.03, 60.0, 0.2)):
        current, quality = 250, 90
        if k % 20 == 3:
            current = 10  # below min_distance 20 cm
        elif k % 20 == 5:
            quality = 4  # low signal quality
        ev.append((t, mav.distance_sensor_encode(int(t * 1000), 20, 5000, current, 1, 1, 25, 0,
                                                 signal_quality=quality)))
    return write_events(path, mav, ev)


def test_tlog_dive_bluerov2_dvl_context_and_cuts(tmp_path):
    run = convert_log(dive_tlog(tmp_path / "d.tlog"), "ardusub")
    notes = run.metadata["notes"]
    assert run.metadata["vehicle"] == "bluerov2" and run.inputs.shape[1] == 6
    t = run.extra["t_source"][0] - T0 + run.t - run.t[0]  # ATTITUDE receive time at or before the first row (20 Hz)
    # armed 10..50 s (heartbeats at 1 Hz: held), depth >= 0.3 m from 6 s: kept 10..50 s
    assert 9.95 < t[0] < 10.1 and 49.9 < t[-1] < 50.0
    np.testing.assert_array_equal(run.extra["armed"], 1.0)
    clear = np.abs(t - 30.0) > 0.1  # t is the 20 Hz ATTITUDE stamp at or before each row
    np.testing.assert_array_equal(run.extra["mode"][clear], np.where(t < 30.0, 19.0, 2.0)[clear])
    np.testing.assert_allclose(run.channels["z"], np.interp(t, [0, 5, 15, 60], [0.0, 0.0, 3.0, 3.0]), atol=0.016)
    np.testing.assert_allclose(run.channels["phi"], PHI, atol=1e-6)
    np.testing.assert_allclose(run.channels["theta"], THETA, atol=1e-6)
    np.testing.assert_allclose(run.channels["psi"], psi_of(100.0 + t), atol=2.0 * DEG * 0.051)
    np.testing.assert_allclose(run.channels["r"], 2.0 * DEG, atol=1e-6)
    assert "cut: left out" in notes and "disarmed (armed = 0)" in notes
    # DVL: body deltas over 0.1 s, the low-confidence ones dropped and counted
    for k, name in enumerate("uvw"):
        np.testing.assert_allclose(run.channels[name], BODY_VEL[k], atol=1e-6)
    assert "source: u/v/w <- VISION_POSITION_DELTA" in notes and "low DVL confidence" in notes
    assert "source: x/y <- LOCAL_POSITION_NED[x,y]: EKF-estimated" in notes
    np.testing.assert_allclose(run.channels["x"], 0.1 * t, atol=0.011)
    # DISTANCE_SENSOR: 15 below min_distance, 15 low quality of 300
    assert ("DISTANCE_SENSOR[current_distance] -> altitude: 30 of 300 samples invalid and dropped (15 outside the "
            "sensor's [min_distance, max_distance]; 15 low signal_quality") in notes
    np.testing.assert_allclose(run.channels["altitude"][np.isfinite(run.channels["altitude"])], 2.5)
    for c in range(1, 9):
        np.testing.assert_array_equal(run.extra[f"rcin_{c}"], 1500 + 10 * c)
    np.testing.assert_allclose(run.extra["yaw_target"], 0.1, atol=1e-6)
    np.testing.assert_allclose(run.extra["roll_target"], 0.0, atol=1e-6)
    np.testing.assert_allclose(run.extra["r_target"], 0.03, atol=1e-6)
    np.testing.assert_allclose(run.extra["q_target"], -0.02, atol=1e-6)


def test_tlog_ekf_velocity_rotated_to_body_without_dvl(tmp_path):
    run = convert_log(dive_tlog(tmp_path / "n.tlog", dvl=False), "ardusub")
    ok = np.isfinite(run.channels["u"])
    assert ok.mean() > 0.99
    for k, name in enumerate("uvw"):
        np.testing.assert_allclose(run.channels[name][ok], BODY_VEL[k], atol=3e-4)
    assert "source: u/v/w <- LOCAL_POSITION_NED[vx,vy,vz]: EKF-estimated" in run.metadata["notes"]


def test_log_entirely_at_the_surface_is_kept_with_a_warning(tmp_path):
    mav = _mav()
    ev = [(t, mav.heartbeat_encode(12, 3, 81 | 128, 19, 4)) for t in np.arange(0.0, 20.0, 1.0)]
    ev += [(t, mav.attitude_encode(int(t * 1000), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)) for t in np.arange(0.01, 20, 0.05)]
    ev += [(t, mav.scaled_pressure2_encode(int(t * 1000), 1013.25, 0.0, 1200)) for t in np.arange(0.02, 20, 0.1)]
    ev += [(t, mav.servo_output_raw_encode(int(t * 1e6), 0, *[int(1500 + 40 * np.sin(t + k)) for k in range(8)]))
           for t in np.arange(0.03, 20, 0.1)]
    run = convert_log(write_events(tmp_path / "s.tlog", mav, ev), "ardusub")
    assert run.duration > 19.0
    assert "cut: WARNING: no row of this run passes the checks (at or near the surface" in run.metadata["notes"]
    assert run.metadata["cut"]["kept"] is None
    assert run.metadata["cut"]["invalid_share"]["at or near the surface (z < 0.3 m, assumed threshold)"] == 1.0


def test_a_diagnosis_reports_a_log_the_plant_does_not_represent_not_diagnosed(tmp_path, capsys):
    """A log entirely at the surface, thrusters swept: converted, it is kept whole with the cut's verdict in the
    sidecar; `diagnose` reads that verdict and reports the run not diagnosed instead of naming an effect for the free
    surface the plant lacks (ardusub_log_tools/small.tlog named a CG-CB offset that way)."""
    mav = _mav()
    ev = [(t, mav.heartbeat_encode(12, 3, 81 | 128, 19, 4)) for t in np.arange(0.0, 40.0, 1.0)]
    ev += [(t, mav.attitude_encode(int(t * 1000), 0.02 * np.sin(t), 0.0, 0.0, 0.0, 0.0, 0.0))
           for t in np.arange(0.01, 40, 0.05)]
    ev += [(t, mav.scaled_pressure2_encode(int(t * 1000), 1013.25 + 0.5 * np.sin(t), 0.0, 1200))
           for t in np.arange(0.02, 40, 0.1)]
    ev += [(t, mav.servo_output_raw_encode(int(t * 1e6), 0, *[int(1500 + 200 * np.sin(t + k)) for k in range(8)]))
           for t in np.arange(0.03, 40, 0.1)]
    log = write_events(tmp_path / "surface.tlog", mav, ev)
    csv = tmp_path / "surface.csv"
    assert main(["convert", str(log), "--mapping", "ardusub", "--out", str(csv)]) == 0
    assert read_run(csv).metadata["cut"]["kept"] is None  # the verdict survives the sidecar
    out = tmp_path / "r.json"
    assert main(["diagnose", "--model", "bluerov2-heavy", "--json", str(out), str(csv)]) == 0
    report = json.loads(out.read_text())
    assert report["effects"] == [] and report["gap_before"]["value"] is None
    (u,) = report["unrepresented_runs"]
    assert u["run"] == "surface.csv"
    assert u["invalid_share"]["at or near the surface (z < 0.3 m, assumed threshold)"] == 1
    assert report["verdict"].startswith("not diagnosed: no run is left to diagnose (surface.csv: not represented")
    assert "not diagnosed: surface.csv: not represented by the plant" in capsys.readouterr().out
    # a replay of it still runs, with the same warning: its gap is not a model error
    assert main(["simulate", "--model", "bluerov2-heavy", "--input", str(csv), "--windows", "8"]) == 0
    assert "warning: surface.csv: not represented by the plant" in capsys.readouterr().err


def test_almost_all_invalid_rangefinder_readings_are_named(tmp_path):
    """A sonar whose readings nearly all have a low signal quality: the few good ones are used and the notes say the
    sensor is unusable in this log; with none good, altitude is missing and the counts still reach the notes."""
    def log(path, good_every):
        mav = _mav()
        ev = [(t, mav.attitude_encode(int(t * 1000), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)) for t in np.arange(0.01, 20, 0.05)]
        ev += [(t, mav.servo_output_raw_encode(int(t * 1e6), 0, *[int(1500 + 40 * np.sin(t + k)) for k in range(8)]))
               for t in np.arange(0.03, 20, 0.1)]
        ev += [(t, mav.distance_sensor_encode(int(t * 1000), 20, 5000, 300, 1, 1, 25, 0,
                                              signal_quality=90 if good_every and k % good_every == 0 else 3))
               for k, t in enumerate(np.arange(0.02, 20, 0.1))]
        return write_events(path, mav, ev)

    run = convert_log(log(tmp_path / "a.tlog", 20), "ardusub")
    assert "190 of 200 samples invalid and dropped (190 low signal_quality" in run.metadata["notes"]
    assert "ALMOST ALL (95 %) of the readings are invalid" in run.metadata["notes"]
    run = convert_log(log(tmp_path / "b.tlog", 0), "ardusub")
    assert "altitude" not in run.channels and "200 of 200 samples invalid" in run.metadata["notes"]


# ------------------------------------------------------------------------------------------- QGC CSV


def test_qgc_csv_rows_longer_than_the_header_are_read(tmp_path):
    """QGC adds battery1.* facts after writing its header: the extra cells have no name and are ignored, counted."""
    header = "Timestamp,roll,pitch,heading,altitudeRelative,battery0.voltage"
    rows = [header]
    for k in range(10):
        extra = ",15.1,2.0" if k >= 5 else ""
        rows.append(f"2024-05-01 10:00:{k:02d}.000,1.0,-1.0,{10 * k},{-0.2 * k:.1f},15.{k}{extra}")
    path = tmp_path / "qgc.csv"
    path.write_text("\n".join(rows) + "\n")
    run = convert_log(path, require_inputs=False)
    np.testing.assert_allclose(run.channels["z"], 0.2 * run.t, atol=1e-9)
    np.testing.assert_allclose(run.channels["voltage"], 15.0 + 0.1 * run.t, atol=1e-9)
    assert "5 of 10 rows have more cells than the header (first: row 7, up to 8 cells for 6 header columns" in \
        run.metadata["notes"]
    # a row shorter than the header is still an error naming it
    path.write_text("\n".join(rows[:3] + ["2024-05-01 10:00:10.000,1.0"]) + "\n")
    with pytest.raises(LogImportError, match="row 4 has 2 cells, the header 6"):
        convert_log(path, require_inputs=False)


# ------------------------------------------------------------------------------------------- the real dive


@pytest.mark.skipif(not DIVE.is_file(), reason="shared sea dive (guided_above_terrain) not present")
def test_shared_sea_dive_converts_as_a_heavy_with_dvl_velocities():
    """BlueROV2 off Pier 59, Seattle (7 Jan 2026; PROVENANCE.md): 8 active outputs + lights on C10, DVL A50 VISO,
    a transect at 12.4-13.8 m holding about 2 m above the seabed."""
    run = convert_log(DIVE)
    notes = run.metadata["notes"]
    assert run.metadata["vehicle"] == "bluerov2-heavy" and run.inputs.shape[1] == 8
    assert "RCOU output 10: other" in notes
    assert "source: u/v/w <- VISO[PosDX,PosDY,PosDZ,dt]: DVL-measured" in notes
    assert "source: x/y <- XKF1[PN,PE]: EKF-estimated" in notes
    z, alt = run.channels["z"], run.channels["altitude"]
    assert np.isfinite(z).all() and 12.4 <= z.min() and z.max() <= 13.8
    assert np.isfinite(alt).mean() > 0.99 and 1.7 <= np.nanmin(alt) and np.nanmax(alt) <= 2.4
    speed = np.hypot(run.channels["u"], run.channels["v"])
    assert np.isfinite(speed).mean() > 0.99 and np.nanmax(speed) < 0.4  # |VN|, |VE| <= 0.25 m/s
    assert run.duration > 199.0  # submerged throughout: nothing cut
    assert set(np.unique(run.extra["mode"][np.isfinite(run.extra["mode"])])) == {0.0, 2.0, 4.0, 21.0}
    np.testing.assert_allclose(np.nanmedian(run.extra["z_target"] - z), 0.0, atol=0.1)
    # the trimmed log holds no MOT_k_DIRECTION and no gains: both come from its own controller messages
    assert "MOT_k_DIRECTION not in the log; inferred" in notes
    assert "(1: -1, 2: -1, 3: +1, 4: +1, 5: -1, 6: +1, 7: +1, 8: -1)" in notes
    est = run.metadata["autopilot_params_estimated"]
    # ArduSub's rate-loop defaults (AC_AttitudeControl_Sub.h) are what this vehicle flew: recovered within 1-5 %
    assert est["ATC_RAT_RLL_P"] == pytest.approx(0.135, rel=0.01)
    assert est["ATC_RAT_YAW_P"] == pytest.approx(0.18, rel=0.01)
    assert est["ATC_RAT_PIT_I"] == pytest.approx(0.09, rel=0.05) and est["SCHED_LOOP_RATE"] == 200


def test_motors_of_a_transect_dive_are_motors_and_stepped_lights_are_not():
    """A dive flown on long transects: the horizontal thrusters sit 200 us off neutral most of the time (median
    1300 / 1700 us), with the stabilising loops' jitter (outputs 1, 2) or at exactly the stick's value between
    manoeuvres (3, 4: MANUAL, or a loop whose corrections round away); lights stepped between ArduSub's levels
    (1100 .. 1900 us) bracket the neutral too, and the second lights channel sits at 1500 us (half brightness)
    for most of the log, but each changes a handful of times."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 180.0, 0.1)
    cruise = (t > 5) & (t < 170)  # forward stick: +-200 us on the horizontal thrusters, 1500 at rest
    turns = np.zeros(t.size)
    for start in np.arange(10.0, 160.0, 5.0):  # 30 short yaw corrections: +-20 us on the horizontals
        turns[(t >= start) & (t < start + 0.5)] = 20.0
    fields = {}
    for k, sign in enumerate((-1, -1, 1, 1)):
        jitter = rng.normal(0, 6, t.size) if k < 2 else 0.0
        fields[f"C{k + 1}"] = np.round(1500 + sign * 200 * cruise + (-1) ** k * turns + jitter)
    for k in range(4, 8):  # verticals holding depth: around neutral
        fields[f"C{k + 1}"] = np.round(1500 + 40 * np.sin(0.3 * t + k) + rng.normal(0, 6, t.size))
    fields["C9"] = np.minimum(1100.0 + 100 * (t // 20), 1900.0)  # lights stepped up every 20 s: 9 levels
    fields["C10"] = np.where((t > 10) & (t < 170), 1500.0, 1100.0 + 800 * (t > 100))  # half brightness
    stream = Stream(name="RCOU", t=t, fields=fields, time_source="TimeUS")
    ev = classify_outputs(stream, "C{n}", 10)
    assert ev.servos("motor") == tuple(range(1, 9)), ev.describe()
    assert ev.servos("other") == (9, 10), ev.describe()
    assert np.median(fields["C1"]) < 1350 and np.median(fields["C3"]) > 1650  # far from neutral most of the time
    info = choose_vehicle(VehicleInfo(name=None, frame=None, motor_servos=(), notes=[]), ev)
    assert info.name == "bluerov2-heavy" and info.motor_servos == tuple(range(1, 9))
