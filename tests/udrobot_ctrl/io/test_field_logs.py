"""Field logs as ArduSub users hold them: damaged tlogs and dataflash built with pymavlink's own encoder, slow
QGC streams, mid-dive starts, flat or noisy EKF depth, BlueROV2 / Heavy frames, QGC CSV; and the shared real logs."""
from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import LogImportError, log_kind
from udrobot_ctrl.io.mapping import parse_mapping
from udrobot_ctrl.io.runlog import read_run, write

T0 = 1_700_000_000.0
RHO_G = 1000.0 * 9.81  # Pa per m of fresh water, as the converter uses (rho = 1000 BARO_SPEC_GRAV, g = 9.81)
# ../shared next to the repository (as the other tests); UDROBOT_SHARED overrides it (e.g. from a git worktree)
SHARED = Path(os.environ.get("UDROBOT_SHARED", Path(__file__).resolve().parents[3] / ".." / "shared"))
ARDUSUB_LOGS = SHARED / "data" / "ardusub_log_tools"
# a disarmed BlueROV2 Heavy: its 8 motor outputs at the 1500 us neutral, the unused outputs at 0 (as ArduSub logs
# them); without FRAME_CONFIG the converter infers bluerov2-heavy from them
DISARMED_HEAVY = [1500] * 8 + [0] * 8


def _mav():
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    return mav2.MAVLink(None, srcSystem=1, srcComponent=1)


def write_events(path, mav, events):
    """tlog framing: 8-byte big-endian receive time (µs) + frame; events (t, message or raw frame bytes)."""
    events = sorted(events, key=lambda e: e[0])
    with open(path, "wb") as fh:
        for t, msg in events:
            frame = msg if isinstance(msg, (bytes, bytearray)) else msg.pack(mav)
            fh.write(struct.pack(">Q", int(round((T0 + t) * 1e6))) + frame)
    return path


def params_events(mav, params, t=0.0):
    return [(t + 1e-4 * k, mav.param_value_encode(name.encode(), float(v), 9, len(params), k))
            for k, (name, v) in enumerate(params.items())]


def dive_tlog(path, depth, duration=60.0, p_rate=2.0, servo_rate=2.0, params=None, vfr_alt=None, servo=None,
              extra=(), jitter=0.0, seed=0):
    """ATTITUDE 20 Hz, SCALED_PRESSURE2 and SERVO_OUTPUT_RAW at the given rates (QGC default 2 Hz), RAW_IMU 2 Hz;
    the servo outputs of a disarmed Heavy unless ``servo`` is given.

    depth(t) -> m; pressure = 101325 + rho g depth (the surface at the standard atmosphere); vfr_alt(t) -> VFR_HUD
    alt at 10 Hz if given; servo(t) -> 16 servo values.
    """
    rng = np.random.default_rng(seed)
    mav = _mav()
    ev = [(0.0, mav.heartbeat_encode(12, 3, 81, 19, 3))]
    ev += params_events(mav, params or {}, 0.001)
    for t in np.arange(0.01, duration, 0.05):
        ev.append((t, mav.attitude_encode(int(t * 1000), 0.01, -0.02, 1.0, 0.0, 0.0, 0.0)))
    for t in np.arange(0.02, duration, 1.0 / p_rate):
        rt = t + (rng.uniform(0, jitter) if jitter else 0.0)
        ev.append((rt, mav.scaled_pressure2_encode(int(t * 1000), (101325.0 + RHO_G * depth(t)) / 100.0, 0.0, 1200)))
        ev.append((rt + 1e-4, mav.raw_imu_encode(int(t * 1e6), 10, -20, -1000, 0, 0, 0, 0, 0, 0)))
    for t in np.arange(0.03, duration, 1.0 / servo_rate):
        values = servo(t) if servo else DISARMED_HEAVY
        ev.append((t + (rng.uniform(0, jitter) if jitter else 0.0),
                   mav.servo_output_raw_encode(int(t * 1e6), 0, *[int(v) for v in values])))
    if vfr_alt is not None:
        for t in np.arange(0.04, duration, 0.1):
            ev.append((t, mav.vfr_hud_encode(0.0, 0.0, 0, 0, vfr_alt(t), 0.0)))
    ev += list(extra)
    return write_events(path, mav, ev)


def _depth_check(run, depth, tol):
    t_abs = run.extra["t_source"] - T0  # ATTITUDE time at or before each grid point (<= 50 ms before)
    t = run.t + (t_abs[0])
    z = run.channels["z"]
    ok = np.isfinite(z)
    assert ok.mean() > 0.97
    np.testing.assert_allclose(z[ok], depth(t[ok]), atol=tol)


# ------------------------------------------------------------------------------------------- damage


def test_damaged_tlog_bad_crc_garbage_and_cut_tail(tmp_path):
    """1 in 3 DISTANCE_SENSOR frames with a bad CRC (22-byte payload as BlueOS writes them), 100 bytes of
    garbage inside a frame, a cut tail: everything else is read, each damage kind counted at its offset."""
    mav = _mav()
    ev = [(0.0, mav.heartbeat_encode(12, 3, 81, 19, 3))]
    for t in np.arange(0.01, 20.0, 0.05):
        ev.append((t, mav.attitude_encode(int(t * 1000), 0.1, 0.0, 0.0, 0.0, 0.0, 0.0)))
    for t in np.arange(0.03, 20.0, 0.5):
        ev.append((t, mav.servo_output_raw_encode(int(t * 1e6), 0, *DISARMED_HEAVY)))
    n_bad = 0
    for k, t in enumerate(np.arange(0.02, 20.0, 0.1)):
        frame = bytearray(mav.distance_sensor_encode(int(t * 1000), 20, 5000, 300 + k, 1, 1, 25, 0).pack(mav))
        if k % 3 == 0:
            frame[-1] ^= 0x5A  # CRC byte wrong
            n_bad += 1
        ev.append((t, bytes(frame)))
        # a forward-looking sonar (orientation 0) on the same message: not an altitude
        ev.append((t + 0.001, mav.distance_sensor_encode(int(t * 1000), 20, 5000, 1000, 1, 2, 0, 0)))
    path = write_events(tmp_path / "d.tlog", mav, ev)
    data = bytearray(path.read_bytes())
    garbage_at = len(data) // 2
    data[garbage_at:garbage_at] = bytes(range(7, 107))
    data = data[:-9]
    path.write_bytes(bytes(data))

    run = convert_log(path, "ardusub")
    notes = run.metadata["notes"]
    assert f"damage: bad CRC DISTANCE_SENSOR (132): {n_bad} " in notes
    assert "damage: garbage (no frame start): 1 (" in notes
    assert "damage: truncated tail: 1 (" in notes
    # the good altitude frames decode to their values (k not divisible by 3 -> 3.0 + 0.01 k m)
    alt = run.channels["altitude"]
    assert np.nanmin(alt) >= 3.01 - 1e-9 and np.nanmax(alt) <= 3.0 + 0.01 * 199 + 1e-9
    assert "DISTANCE_SENSOR: 200 of " in notes and "samples dropped (kept where orientation = 25)" in notes
    assert np.all(np.isfinite(run.channels["phi"][:10]))
    np.testing.assert_allclose(np.nanmean(run.channels["phi"]), 0.1, atol=1e-6)


def write_df(path, records, layouts=None):
    """Dataflash bytes: FMT records for each type of ``layouts`` (name -> "format:columns"; these tests' own by
    default), then the data records (name, values) in order, packed by pymavlink's FORMAT_TO_STRUCT."""
    formats = {"FMT": (128, "BBnNZ", "Type,Length,Name,Format,Columns")}
    layouts = layouts or {"ATT": "Qfff:TimeUS,Roll,Pitch,Yaw", "BARO": "QBff:TimeUS,I,Alt,Press",
               "RCOU": "Q" + "H" * 14 + ":TimeUS," + ",".join(f"C{k}" for k in range(1, 15)),
               "PARM": "QNf:TimeUS,Name,Value", "MSG": "QZ:TimeUS,Message", "RFND": "QBf:TimeUS,Instance,Dist",
               "IMU": "QBffffff:TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", "CTUN": "Qf:TimeUS,Alt"}
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    out = []
    codes = {}
    fmt_struct = struct.Struct("<BB4s16s64s")

    def fmt_record(mtype, name, form, cols):
        length = 3 + struct.calcsize("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in form))
        return b"\xa3\x95\x80" + fmt_struct.pack(mtype, length, name.encode(), form.encode(), cols.encode())

    out.append(fmt_record(128, "FMT", *formats["FMT"][1:]))
    for k, (name, spec) in enumerate(layouts.items()):
        form, cols = spec.split(":")
        codes[name] = (129 + k, form)
        out.append(fmt_record(129 + k, name, form, cols))
    for name, values in records:
        mtype, form = codes[name]
        packed = [v.encode() if isinstance(v, str) else v for v in values]
        layout = "<" + "".join(FORMAT_TO_STRUCT[c][0] for c in form)
        out.append(b"\xa3\x95" + bytes([mtype]) + struct.pack(layout, *packed))
    path.write_bytes(b"".join(out))
    return path


def test_truncated_dataflash_with_rangefinder_imu_and_frame(tmp_path):
    """A BlueROV2 (FRAME_CONFIG 1) dataflash log cut mid-record with a garbage block: RFND -> altitude, IMU
    AccX.. -> ax ay az (m/s^2, FRD as logged), RCOU C1..C6 -> pwm_1..6, damage counted."""
    recs = [("PARM", (0, "FRAME_CONFIG", 1.0)), ("MSG", (0, "ArduSub V4.1.0 (89639005)"))]
    recs += [("PARM", (0, f"SERVO{k}_FUNCTION", 32.0 + k)) for k in range(1, 7)]
    for t in np.arange(10.0, 30.0, 0.1):
        us = int(t * 1e6)
        recs.append(("ATT", (us, 1.0, -2.0, 90.0)))
        recs.append(("BARO", (us + 1, 0, -9.5, 99000.0)))
        recs.append(("BARO", (us + 2, 1, -(1.0 + 0.1 * (t - 10.0)), 0.0)))  # Alt = -depth
        recs.append(("RFND", (us + 3, 0, 4.0 - 0.1 * (t - 10.0))))
        recs.append(("RCOU", (us + 4, *[1500 + 10 * k for k in range(1, 15)])))
        recs.append(("IMU", (us + 5, 0, 0.0, 0.0, 0.01, 0.1, -0.2, -9.8)))
    path = write_df(tmp_path / "00000042.BIN", recs)
    data = bytearray(path.read_bytes())
    at = len(data) // 2
    data[at:at + 40] = b"\0" * 40
    path.write_bytes(bytes(data[:-5]))
    run = convert_log(path, "ardusub")
    notes = run.metadata["notes"]
    assert run.metadata["vehicle"] == "bluerov2"
    assert run.inputs.shape[1] == 6
    np.testing.assert_array_equal(run.inputs[0], [1510, 1520, 1530, 1540, 1550, 1560])
    t = run.t + 10.0
    ok = np.isfinite(run.channels["altitude"])
    assert ok.mean() > 0.95
    np.testing.assert_allclose(run.channels["altitude"][ok], 4.0 - 0.1 * (t[ok] - 10.0), atol=2e-3)
    np.testing.assert_allclose(run.channels["z"][ok], 1.0 + 0.1 * (t[ok] - 10.0), atol=2e-3)
    np.testing.assert_allclose(np.nanmean(run.channels["az"]), -9.8, atol=1e-5)
    np.testing.assert_allclose(np.nanmean(run.channels["ax"]), 0.1, atol=1e-6)
    assert "damage: truncated tail (" in notes and "damage: garbage (no record header): 1 (" in notes


# ------------------------------------------------------------------------------------------- depth


def test_mid_dive_start_takes_the_shallowest_point_as_surface(tmp_path):
    """Log starts at 5 m, surfaces at 20 s, dives to 3 m; no BARO2_GND_PRESS: the first sample is not the surface."""
    def depth(t):
        return np.interp(t, [0, 20, 25, 60], [5.0, 0.0, 0.0, 3.0])

    run = convert_log(dive_tlog(tmp_path / "m.tlog", depth), "ardusub")
    _depth_check(run, depth, 0.01)
    assert "log starts mid-dive" in run.metadata["notes"]


def test_surface_parameter_is_used_and_log_start_at_surface(tmp_path):
    """With BARO2_GND_PRESS logged (here 500 Pa above the standard atmosphere: 0.051 m), it is the surface."""
    def depth(t):
        return np.interp(t, [0, 10, 60], [0.0, 0.0, 9.4])

    path = dive_tlog(tmp_path / "g.tlog", depth, params={"BARO2_GND_PRESS": 101825.0, "BARO_SPEC_GRAV": 1.0})
    run = convert_log(path, "ardusub")
    _depth_check(run, lambda t: depth(t) - 500.0 / RHO_G, 0.01)
    assert "log parameter BARO2_GND_PRESS = 101825 Pa" in run.metadata["notes"]
    assert run.metadata["water_density"] == 1000.0 and "from log parameter BARO_SPEC_GRAV = 1" in run.metadata["notes"]
    # a calibration that does not fit the log (1 m of water too high) is named and replaced by the log's own surface
    run = convert_log(dive_tlog(tmp_path / "w.tlog", depth, params={"BARO2_GND_PRESS": 101325.0 + RHO_G}), "ardusub")
    _depth_check(run, depth, 0.01)
    assert "log parameter BARO2_GND_PRESS = 111135 Pa" in run.metadata["notes"] and "above the surface: not used" in \
        run.metadata["notes"]
    # without it, the pre-dive samples are the surface (stated as assumed)
    run = convert_log(dive_tlog(tmp_path / "f.tlog", depth), "ardusub")
    _depth_check(run, depth, 0.01)
    assert "assumed taken at the surface before the dive" in run.metadata["notes"]


def test_flat_vfr_hud_is_rejected_even_when_listed_first(tmp_path):
    """VFR_HUD.alt is 0 without a home position (ArduSub 4.1) while the pressure shows a 9 m dive. A mapping that
    lists VFR_HUD first still ends with the pressure depth, and the notes say why."""
    def depth(t):
        return np.interp(t, [0, 10, 50, 60], [0.0, 0.0, 9.0, 9.0])

    path = dive_tlog(tmp_path / "v.tlog", depth, vfr_alt=lambda t: 0.0)
    run = convert_log(path, "ardusub")
    _depth_check(run, depth, 0.01)
    notes = run.metadata["notes"]
    assert "source: z candidate VFR_HUD[alt] not used: rejected: flat" in notes
    mapping = parse_mapping("""
[mapping]
format = "udrobot-mapping/1"
source = "mavlink"
rate_hz = 20.0
time_base = "ATTITUDE"
input_kind = "pwm"
[select.z]
[[channels]]
to = ["phi", "theta", "psi"]
stream = "ATTITUDE"
fields = ["roll", "pitch", "yaw"]
[[channels]]
to = "z"
stream = "VFR_HUD"
field = "alt"
scale = -1.0
role = "estimate"
[[channels]]
to = "z"
stream = "SCALED_PRESSURE2"
field = "press_abs"
scale = 100.0
transform = "pressure_to_depth"
role = "measurement"
[[channels]]
to = ["pwm_1", "pwm_2"]
stream = "SERVO_OUTPUT_RAW"
fields = ["servo1_raw", "servo2_raw"]
""", "vfr-first")
    run = convert_log(path, mapping)
    _depth_check(run, depth, 0.01)
    assert "source: z <- SCALED_PRESSURE2[press_abs], chosen by evidence" in run.metadata["notes"]


def test_noisy_ekf_depth_is_rejected(tmp_path):
    """GLOBAL_POSITION_INT.relative_alt swinging +-0.3 m while the pressure is steady: named noisy, not used."""
    rng = np.random.default_rng(3)
    mav = _mav()

    def depth(t):
        return np.interp(t, [0, 30, 60], [2.0, 2.5, 2.0])

    extra = [(t, mav.global_position_int_encode(int(t * 1000), 0, 0, 0,
                                                 int(-1000 * (depth(t) + 0.3 * np.sin(t) + rng.normal(0, 0.05))),
                                                 0, 0, 0, 0))
             for t in np.arange(0.05, 60.0, 1 / 3)]
    mapping = parse_mapping((Path(__file__).resolve().parents[3] / "models" / "mappings" / "ardusub.toml")
                            .read_text().replace('stream = "SCALED_PRESSURE2"', 'stream = "SCALED_PRESSURE2_X"'),
                            "ardusub-no-pressure-first")
    # with the pressure candidate renamed away, the EKF estimate has no reference: used, and said so
    path = dive_tlog(tmp_path / "n.tlog", depth, extra=extra, params={"BARO2_GND_PRESS": 101325.0})
    run = convert_log(path, mapping)
    assert "source: z <- GLOBAL_POSITION_INT[relative_alt], chosen by evidence: ok (no measurement" in \
        run.metadata["notes"]
    run = convert_log(path, "ardusub")
    _depth_check(run, depth, 0.01)
    assert "source: z candidate GLOBAL_POSITION_INT[relative_alt] not used: rejected: disagrees with " \
        "SCALED_PRESSURE2[press_abs]" in run.metadata["notes"]


# ------------------------------------------------------------------------------------------- rates


def test_two_hz_streams_are_kept_and_named(tmp_path):
    """2 Hz pressure and servo streams with 0.4 s of receive jitter (QGC bursts): no nan from the gap limit;
    a real 12 s dropout of the pressure becomes nan and is named."""
    def depth(t):
        return 1.0 + 0.02 * t

    run = convert_log(dive_tlog(tmp_path / "s.tlog", depth, jitter=0.4), "ardusub")
    z = run.channels["z"]
    assert np.isfinite(z).all()
    notes = run.metadata["notes"]
    assert "rate: pwm_1..pwm_8 from SERVO_OUTPUT_RAW at 2.0 Hz" in notes
    assert "cannot resolve command changes" in notes
    assert "rate: z from SCALED_PRESSURE2 at 2.0 Hz" in notes
    # dropout
    path = tmp_path / "gap.tlog"
    mav = _mav()
    from udrobot_ctrl.io.mavlink import iter_tlog

    src = dive_tlog(tmp_path / "s2.tlog", depth)
    keep = [(t - T0, m) for _, _, t, m in iter_tlog(src)
            if not (m.get_type() == "SCALED_PRESSURE2" and 20.0 < t - T0 < 32.0)]
    write_events(path, mav, [(t, m.get_msgbuf()) for t, m in keep])
    run = convert_log(path, "ardusub")
    z = run.channels["z"]
    t = run.t + (run.extra["t_source"][0] - T0)
    # last pressure sample before the dropout at 19.52 s, first after it at 32.02 s
    assert np.isnan(z[(t > 20.1) & (t < 31.9)]).all() and np.isfinite(z[t < 19.5]).all()
    assert 0.15 < np.isnan(z).mean() < 0.25
    assert "gaps: z is nan in" in run.metadata["notes"]


# ------------------------------------------------------------------------------------------- vehicle


def test_heavy_frame_maps_all_eight_motors_in_motor_order(tmp_path):
    """FRAME_CONFIG 2 with a permuted SERVOn_FUNCTION map: pwm_m is the servo that drives motor m."""
    servo_of_motor = [3, 1, 2, 4, 8, 7, 5, 6]
    params = {"FRAME_CONFIG": 2.0, **{f"SERVO{s}_FUNCTION": 32.0 + m for m, s in enumerate(servo_of_motor, 1)},
              "SERVO9_FUNCTION": 59.0}
    mav = _mav()
    extra = [(0.5, mav.statustext_encode(6, b"Frame: VECTORED_6DOF"))]
    # old firmware sends servos 9-16 as a second SERVO_OUTPUT_RAW with port = 1: never motor outputs 1-8
    extra += [(t, mav.servo_output_raw_encode(int(t * 1e6), 1, *[1900] * 16)) for t in np.arange(0.035, 60.0, 0.5)]
    path = dive_tlog(tmp_path / "h.tlog", lambda t: 1.0 + 0 * t, params=params, extra=extra,
                     servo=lambda t: [1100 + 10 * n for n in range(1, 17)])
    run = convert_log(path, "ardusub")
    assert run.metadata["vehicle"] == "bluerov2-heavy"
    assert run.inputs.shape[1] == 8
    np.testing.assert_array_equal(run.inputs, np.tile([1100 + 10 * s for s in servo_of_motor], (run.n, 1)))
    assert "motor 1 = servo 3" in run.metadata["notes"]
    write(run, tmp_path / "h.csv")
    assert json.loads((tmp_path / "h.json").read_text())["vehicle"] == "bluerov2-heavy"
    assert read_run(tmp_path / "h.csv").inputs.shape[1] == 8


def test_frame_from_text_only_and_other_frames(tmp_path):
    mav = _mav()
    path = dive_tlog(tmp_path / "b.tlog", lambda t: 1.0 + 0 * t,
                     extra=[(0.5, mav.statustext_encode(6, b"Frame: VECTORED"))],
                     servo=lambda t: [1100 + 10 * n for n in range(1, 17)])
    run = convert_log(path, "ardusub")
    assert run.metadata["vehicle"] == "bluerov2" and run.inputs.shape[1] == 6
    assert "ArduSub default assumed: motor k on servo k" in run.metadata["notes"]
    run = convert_log(dive_tlog(tmp_path / "s4.tlog", lambda t: 1.0 + 0 * t, params={"FRAME_CONFIG": 5.0}),
                      "ardusub")
    assert run.metadata["vehicle"] == "ardusub-frame-5" and run.inputs.shape[1] == 4


# ------------------------------------------------------------------------------------------- QGC CSV


def test_qgc_telemetry_csv_is_recognised_and_converted(tmp_path):
    rows = ["Timestamp,roll,pitch,heading,rollRate,pitchRate,yawRate,altitudeRelative,flightMode,battery0.voltage"]
    for k in range(30):
        rows.append(f"2024-05-01 10:00:{k:02d}.000,{2.0},{-1.0},{(350 + 2 * k) % 360},0,0,{2.0},"
                    f"{-0.1 * k:.2f},Manual,{15.5 - 0.01 * k:.2f}")
    path = tmp_path / "2024-05-01 10-00-00 vehicle1.csv"
    path.write_text("\n".join(rows) + "\n")
    assert log_kind(path) == "qgc_csv"
    with pytest.raises(LogImportError, match="input column"):
        convert_log(path)
    run = convert_log(path, require_inputs=False)
    np.testing.assert_allclose(run.channels["phi"], np.radians(2.0))
    np.testing.assert_allclose(run.channels["z"], 0.1 * run.t, atol=1e-9)
    psi = np.degrees(np.unwrap(run.channels["psi"]))
    np.testing.assert_allclose(np.diff(psi), 2.0, atol=1e-9)  # continuous through 360 -> 0
    np.testing.assert_allclose(run.channels["r"], np.radians(2.0))
    assert "non-numeric QGC columns not read: flightMode" in run.metadata["notes"]
    # a udrobot-run/1 file is still a run
    write(run, tmp_path / "r.csv")
    assert log_kind(tmp_path / "r.csv") == "run"


# ------------------------------------------------------------------------------------------- real logs


@pytest.mark.skipif(not ARDUSUB_LOGS.is_dir(), reason="shared ArduSub logs not present")
def test_shared_ardusub_logs_convert_with_damage_depth_and_vehicle():
    """The research counts (1,967 bad frames of which 1,949 DISTANCE_SENSOR; 4 camera frames in small.tlog), the
    Bar30 depth with BARO2_GND_PRESS, Heavy tlogs and a 6-thruster BlueROV2 BIN."""
    run = convert_log(ARDUSUB_LOGS / "2023-04-18 11-03-34.tlog", "ardusub")
    notes = run.metadata["notes"]
    assert "damage: 1967 damaged item(s)" in notes
    assert "damage: bad CRC DISTANCE_SENSOR (132): 1949 (81858 bytes), first byte offsets 933, 1605, 1765" in notes
    assert "source: z <- SCALED_PRESSURE2[press_abs]" in notes and "BARO2_GND_PRESS = 103210 Pa" in notes
    assert "VFR_HUD[alt] not used: rejected: flat" in notes
    z = run.channels["z"]
    assert np.isfinite(z).all() and -0.005 < z.min() and z.max() < 0.03  # at the surface: Bar30 moves < 3 cm
    assert run.metadata["vehicle"] == "bluerov2-heavy" and run.inputs.shape[1] == 8
    np.testing.assert_allclose(np.nanmedian(run.channels["az"]), -9.3, atol=0.8)  # pitched ~20-45 deg
    assert np.isfinite(run.channels["voltage"]).mean() > 0.97

    run = convert_log(ARDUSUB_LOGS / "small.tlog", "ardusub")
    notes = run.metadata["notes"]
    assert "damage: 4 damaged item(s)" in notes
    for kind in ("CAMERA_INFORMATION (259): 1 (159 bytes), first byte offsets 11888",
                 "VIDEO_STREAM_INFORMATION (269): 1", "CAMERA_SETTINGS (260): 1", "CAMERA_CAPTURE_STATUS (262): 1"):
        assert f"damage: bad CRC {kind}" in notes
    assert "source: z <- SCALED_PRESSURE2[press_abs]" in notes
    z = run.channels["z"]
    assert np.isfinite(z).all() and 0.0 < z.min() and z.max() < 0.04
    assert run.metadata["vehicle"] == "bluerov2-heavy" and run.inputs.shape[1] == 8
    assert np.isfinite(run.channels["voltage"]).all()  # 2 Hz SYS_STATUS: no longer 43 % nan
    assert np.nanmax(run.inputs) > 1700 and np.nanmin(run.inputs) < 1350  # armed stretch: thrusters commanded

    run = convert_log(ARDUSUB_LOGS / "small.BIN", "ardusub")
    notes = run.metadata["notes"]
    assert "damage: none found" in notes
    assert run.metadata["vehicle"] == "bluerov2" and run.inputs.shape[1] == 6
    assert "source: z <- BARO[1][Alt]" in notes
    assert 0.0 <= np.nanmin(run.channels["z"]) and np.nanmax(run.channels["z"]) < 0.02
    np.testing.assert_allclose(np.nanmean(run.channels["az"]), -9.8, atol=0.15)


def _ardupilot_files():
    if not ARDUSUB_LOGS.is_dir():
        return []
    return sorted(p for p in ARDUSUB_LOGS.iterdir() if p.suffix.lower() in (".tlog", ".bin"))


@pytest.mark.skipif(not ARDUSUB_LOGS.is_dir(), reason="shared ArduSub logs not present")
@pytest.mark.parametrize("path", _ardupilot_files(), ids=lambda p: p.name)
def test_every_shared_ardupilot_file_converts(path):
    """Each file converts with a damage statement, a named vehicle with all its motors, a finite depth at the
    surface (none of the shared logs is a dive: the Bar30 moves < 4 cm) and the depth source stated."""
    run = convert_log(path, "ardusub")
    notes = run.metadata["notes"]
    assert "damage: " in notes and "source: z <- " in notes
    assert run.metadata["vehicle"] in ("bluerov2", "bluerov2-heavy")
    assert run.inputs.shape[1] == {"bluerov2": 6, "bluerov2-heavy": 8}[run.metadata["vehicle"]]
    z = run.channels["z"]
    assert np.isfinite(z).mean() > 0.99 and -0.01 < np.nanmin(z) and np.nanmax(z) < 0.04
    assert {"ax", "ay", "az"} <= set(run.channels)


def test_late_sonar_does_not_shorten_the_run(tmp_path):
    """A downward sonar that only reports from 30 s to 40 s: the run keeps its 60 s of states and commands,
    altitude is nan outside the sonar's span and the notes name it."""
    mav = _mav()
    extra = [(t, mav.distance_sensor_encode(int(t * 1000), 20, 5000, 250, 1, 1, 25, 0))
             for t in np.arange(30.0, 40.0, 0.1)]
    run = convert_log(dive_tlog(tmp_path / "late.tlog", lambda t: 1.0 + 0 * t, extra=extra), "ardusub")
    assert run.duration > 59.0
    alt = run.channels["altitude"]
    t = run.t + (run.extra["t_source"][0] - T0)
    assert np.isnan(alt[t < 29.9]).all() and np.isnan(alt[t > 40.0]).all()
    np.testing.assert_allclose(alt[(t > 30.1) & (t < 39.8)], 2.5)
    assert "gaps: altitude is nan in" in run.metadata["notes"] and "DISTANCE_SENSOR covers only 30.0..39.9 s" in \
        run.metadata["notes"]


def test_unknown_message_id_is_counted_not_damage(tmp_path):
    """A well-framed v2 frame with a message id the dialect does not know (a vendor message) is stepped over and
    counted once under frames:, not as damage."""
    unknown = bytes([0xFD, 4, 0, 0, 0, 1, 1]) + (60000).to_bytes(3, "little") + b"\x01\x02\x03\x04" + b"\xaa\xbb"
    run = convert_log(dive_tlog(tmp_path / "u.tlog", lambda t: 1.0 + 0 * t, extra=[(5.0, unknown), (6.0, unknown)]),
                      "ardusub")
    notes = run.metadata["notes"]
    assert "frames: 2 of " in notes and "damage: none found" in notes


def test_reboot_mid_log_is_named(tmp_path):
    """ATTITUDE time_boot_ms restarting at 30 s receive time: stated as a reboot, the receive clock kept."""
    mav = _mav()
    ev = [(t, mav.attitude_encode(int(((t if t < 30 else t - 30.0) + 100.0) * 1000), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
          for t in np.arange(0.01, 60.0, 0.05)]
    ev += [(t, mav.servo_output_raw_encode(int(t * 1e6), 0, *DISARMED_HEAVY)) for t in np.arange(0.03, 60.0, 0.5)]
    run = convert_log(write_events(tmp_path / "r.tlog", mav, ev), "ardusub")
    assert run.duration > 59.0
    assert "ATTITUDE: the autopilot clock goes back 1 time(s)" in run.metadata["notes"]
