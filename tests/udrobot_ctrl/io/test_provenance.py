"""How each column was obtained (the sidecar's ``channels``): EKF velocities and positions judged from the log's own
configuration (EK3_SRC1_*, GPS_TYPE and fixes, VISO_TYPE, the sensors' records), on synthetic dataflash logs (packed
with pymavlink's format table) and tlogs (pymavlink's encoder); a Ping Viewer ``.bin`` refused naming what it is; the
shared ArduSub logs when present."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from tests.udrobot_ctrl.io.test_ardusub_dive import (
    BODY_VEL,
    DEG,
    LAYOUTS,
    PHI,
    THETA,
    dive_tlog,
    motor_pwm,
    psi_of,
    rotation,
)
from tests.udrobot_ctrl.io.test_field_logs import ARDUSUB_LOGS, SHARED, T0, _mav, write_df
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import LogImportError
from udrobot_ctrl.io.mapping import load_mapping, sidecar_channels
from udrobot_ctrl.io.mavlink import LogFacts, ekf_aiding, ping_viewer_signature, read_bin_streams
from udrobot_ctrl.io.runlog import UNAIDED, read_run, unaided_channels, write

DIVE = SHARED / "data" / "guided_above_terrain" / "00000029_filtered.BIN"
#: ArduSub as the reported dives were set up: the EKF's horizontal sources are the GPS, which has no fix under water
UNAIDED_PARAMS = {"EK3_SRC1_POSXY": 3, "EK3_SRC1_VELXY": 3, "EK3_SRC1_POSZ": 1, "EK3_SRC1_VELZ": 3, "GPS_TYPE": 1,
                  "VISO_TYPE": 0, "AHRS_EKF_TYPE": 3}
#: a DVL through AP_VisualOdom feeding the EKF's horizontal velocity (ExternalNav = 6)
DVL_PARAMS = {**UNAIDED_PARAMS, "EK3_SRC1_VELXY": 6, "EK3_SRC1_VELZ": 0, "VISO_TYPE": 1}
DF_LAYOUTS = {**LAYOUTS, "GPS": "QBBB:TimeUS,I,Status,NSats"}


def ekf_dive_dataflash(path, params, viso=False, gps_status=1):
    """30 s of a dive at 3 m (armed throughout): ATT, BARO[1], RCOU (8 moving motors), XKF1 core 0 with the NED
    velocity of BODY_VEL and a drifting position, GPS at 5 Hz with ``gps_status`` (1 = no fix), the DVL's VISO at
    8 Hz when ``viso``, and PARM records ``params``."""
    recs = [("EV", (int(99.0e6), 10))]
    recs += [("PARM", (int(99.0e6) + k, name.encode(), float(v))) for k, (name, v) in enumerate(params.items())]
    for k, t in enumerate(np.arange(100.0, 130.0, 0.1)):
        us = int(round(t * 1e6))
        psi = psi_of(t)
        recs.append(("ATT", (us, 0.0, PHI / DEG, 0.0, THETA / DEG, 0.0, np.degrees(psi) % 360)))
        recs.append(("BARO", (us + 1, 1, -3.0, 0.0)))
        recs.append(("RCOU", (us + 2, *motor_pwm(t, 8))))
        vned = rotation(PHI, THETA, psi) @ BODY_VEL
        recs.append(("XKF1", (us + 3, 0, 0.0, 0.0, 0.0, *vned, 0.02 * (t - 100.0), -0.01 * (t - 100.0))))
        if k % 2 == 0:
            recs.append(("GPS", (us + 4, 0, gps_status, 0 if gps_status < 3 else 9)))
        if viso and k % 5 != 4:
            recs.append(("VISO", (us + 5, 0.125, 0.0, 0.0, 0.0, *(BODY_VEL * 0.125), 95.0)))
    recs.sort(key=lambda r: r[1][0])
    return write_df(path, recs, DF_LAYOUTS)


def test_dataflash_ekf_without_a_velocity_source_is_marked_unaided(tmp_path):
    """EK3_SRC1_VELXY = POSXY = 3 (GPS), GPS with no fix, VISO_TYPE 0, no DVL: XKF1's u v w and x y are dead
    reckoning; depth from the external baro is measured, the attitude estimated (AHRS aided by accelerometer and
    compass), the gyro measured."""
    run = convert_log(ekf_dive_dataflash(tmp_path / "d.BIN", UNAIDED_PARAMS), "ardusub")
    ch = run.metadata["channels"]
    for c in "uvwxy":
        assert ch[c]["kind"] == UNAIDED, c
        assert "EK3_SRC1_VELXY = 3 (GPS): GPS: 0 of 150 samples with a 3D fix" in ch[c]["aiding"]
    assert ch["u"]["source"] == "XKF1.VN/VE/VD (world_to_body)" and ch["x"]["source"] == "XKF1.PN"
    assert ch["z"] == {"source": "BARO[1].Alt", "kind": "measured"}
    assert ch["phi"]["kind"] == "estimated" and ch["psi"]["kind"] == "estimated"
    notes = run.metadata["notes"]
    assert "provenance: unaided: u, v, w, x, y <- XKF1: estimated-unaided (horizontal UNAIDED (dead reckoning)" in notes
    assert notes.count("provenance: unaided: ") == 1  # judged again on the rows the cut kept: one line, not two
    # the values are still written for the user to see, and the entry survives the sidecar round trip
    np.testing.assert_allclose(run.channels["u"][np.isfinite(run.channels["u"])], BODY_VEL[0], atol=3e-4)
    write(run, tmp_path / "d.csv")
    back = read_run(tmp_path / "d.csv")
    assert sorted(unaided_channels(back.metadata)) == ["u", "v", "w", "x", "y"]


def test_dataflash_ekf_fed_by_a_dvl_is_estimated(tmp_path):
    """The same dive with a DVL (VISO_TYPE 1, EK3_SRC1_VELXY = 6 ExternalNav, VISO records): u v w come from the DVL
    itself (measured), the EKF's x y are estimated (the integral of a measured velocity); the EKF's velocity is judged
    aided too."""
    path = ekf_dive_dataflash(tmp_path / "v.BIN", DVL_PARAMS, viso=True)
    run = convert_log(path, "ardusub")
    ch = run.metadata["channels"]
    assert all(ch[c]["kind"] == "measured" and ch[c]["source"].startswith("VISO.") for c in "uvw")
    assert ch["x"]["kind"] == ch["y"]["kind"] == "estimated"
    assert "EK3_SRC1_VELXY = 6 (ExternalNav): VISO_TYPE = 1; VISO x240" in ch["x"]["aiding"]
    assert not unaided_channels(run.metadata)
    # without the DVL's own channel (a mapping that maps only the EKF) the XKF1 velocity is estimated, not unaided
    facts = read_bin_streams(path, load_mapping("ardusub")).facts
    xkf1 = next(r for r in load_mapping("ardusub").rules if r.stream == "XKF1" and "u" in r.to)
    entries, notes = sidecar_channels([xkf1], ekf_aiding(facts).of)
    assert {entries[c]["kind"] for c in "uvw"} == {"estimated"} and not notes


def facts_with(params=None, records=(), gps=None):
    """LogFacts of a log with ``params``, records ``(name, times)`` and GPS samples ``(name, times, fix types)``."""
    facts = LogFacts(params=dict(params or {}))
    for name, times in records:
        for t in times:
            facts.add_time(name, float(t))
        facts.counts[name] = len(times)
    if gps is not None:
        name, times, fixes = gps
        for t, fix in zip(times, fixes):
            facts.add_fix(name, int(fix), float(t))
    return facts


ROWS = np.arange(0.0, 100.0, 0.02)  # a run's rows, log time (s)
BARO = ("BARO", np.arange(0.0, 100.0, 0.05))


def test_a_gps_fix_aids_the_ekf_and_vertical_needs_its_own_source(tmp_path):
    """A 3D fix (Status 3) on the GPS source: aided. With the vertical sources none (POSZ = VELZ = 0) the NED velocity
    (each body axis mixes all three components) is unaided even though the horizontal is aided."""
    run = convert_log(ekf_dive_dataflash(tmp_path / "g.BIN", UNAIDED_PARAMS, gps_status=3), "ardusub")
    assert {run.metadata["channels"][c]["kind"] for c in "uvwxy"} == {"estimated"}
    t = np.arange(0.0, 100.0, 0.2)
    aiding = ekf_aiding(facts_with({**UNAIDED_PARAMS, "EK3_SRC1_POSZ": 0, "EK3_SRC1_VELZ": 0}, [BARO],
                                   ("GPS", t, np.full(t.size, 3))))
    assert aiding.of("position_xy", ROWS).aided and not aiding.of("position_z", ROWS).aided
    assert not aiding.of("velocity", ROWS).aided and "vertical UNAIDED" in aiding.of("velocity", ROWS).why


def test_a_fix_lost_for_longer_than_the_ekf_timeout_makes_the_run_unaided():
    """EKF3 leaves its aided mode after 7 s without position or velocity data (AP_NavEKF3.h posRetryTimeNoVel_ms):
    a UGPS fix (1 Hz) lost for 5 s keeps the run aided; lost for 20 s (the last fix at 39 s, the next at 60 s) it
    leaves the rows of 46..60 s dead-reckoned (unaided: the kind holds for the whole column); rows after the last fix
    likewise."""
    t = np.arange(0.0, 100.0, 1.0)
    params = {**UNAIDED_PARAMS, "GPS_TYPE": 14}
    for lost, unaided_rows in ((5.0, 0), (20.0, (60.0 - 39.0 - 7.0) / 0.02)):
        fix = np.where((t >= 40.0) & (t < 40.0 + lost), 0, 3)
        judged = ekf_aiding(facts_with(params, [BARO], ("GPS_INPUT", t, fix))).of("position_xy", ROWS)
        assert judged.aided == (unaided_rows == 0)
        if unaided_rows:
            n = int(judged.why.split(" in ")[1].split(" of ")[0])
            assert abs(n - unaided_rows) <= 2 and f"of {ROWS.size} rows" in judged.why
    late = ekf_aiding(facts_with(params, [BARO], ("GPS_INPUT", t[t < 50], np.full(50, 3)))).of("position_xy", ROWS)
    assert not late.aided


def test_a_log_without_parameters_is_judged_from_its_records():
    """A trimmed log (no EK3_SRC*, no VISO_TYPE: the shared sea dive): ArduPilot's defaults (GPS) are assumed, so a
    GPS without a fix leaves the EKF unaided, unless the EKF logged XKFD (its body-odometry innovations: a DVL fed
    it), from the first row on when the records start within the timeout of it (a log trimmed mid-dive)."""
    t = np.arange(0.0, 100.0, 2.0)
    gps = ("GPS", t, np.ones(t.size))
    viso = ("VISO", np.arange(0.1, 100.0, 0.125))
    bare = ekf_aiding(facts_with(records=[BARO, viso], gps=gps))
    assert not bare.of("position_xy", ROWS).aided and bare.of("position_z", ROWS).aided
    assert "not in the log: ArduPilot's default assumed" in bare.of("position_xy").why
    fused = ekf_aiding(facts_with(records=[BARO, viso, ("XKFD", np.arange(0.2, 100.0, 0.125))], gps=gps))
    assert fused.of("velocity", ROWS).aided and "799 XKFD records" in fused.of("velocity").why
    # GPS_TYPE 0 disables the GPS whatever the messages say
    off = ekf_aiding(facts_with({"GPS_TYPE": 0}, [BARO], ("GPS_INPUT", t, np.full(t.size, 3))))
    assert not off.of("position_xy", ROWS).aided and "GPS_TYPE = 0" in off.of("position_xy").why


def _tlog_with(path, params, extra):
    """dive_tlog without its DVL (LOCAL_POSITION_NED is the only velocity), with PARAM_VALUEs and extra frames
    appended (receive times inside the log)."""
    dive_tlog(path, dvl=False)
    mav = _mav()
    frames = [(0.5 + 1e-3 * k, mav.param_value_encode(n.encode(), float(v), 9, len(params), k))
              for k, (n, v) in enumerate(params.items())] + extra(mav)
    with open(path, "ab") as fh:
        for t, msg in frames:
            fh.write(struct.pack(">Q", int(round((T0 + t) * 1e6))) + msg.pack(mav))
    return path


def _gps_raw(fix):
    return lambda mav: [(t, mav.gps_raw_int_encode(int(t * 1e6), fix, 0, 0, 0, 65535, 65535, 0, 0, 0))
                        for t in np.arange(0.2, 60.0, 1.0)]


def test_tlog_local_position_without_a_fix_is_unaided_and_with_a_ugps_fix_estimated(tmp_path):
    run = convert_log(_tlog_with(tmp_path / "n.tlog", UNAIDED_PARAMS, _gps_raw(0)), "ardusub")
    ch = run.metadata["channels"]
    assert {ch[c]["kind"] for c in "uvwxy"} == {UNAIDED}
    assert ch["u"]["source"] == "LOCAL_POSITION_NED.vx/vy/vz (world_to_body)"
    assert "GPS_RAW_INT: 0 of 60 samples with a 3D fix" in ch["u"]["aiding"]
    assert ch["z"]["kind"] == "measured" and ch["p"]["kind"] == "measured" and ch["theta"]["kind"] == "estimated"
    # an underwater GPS (GPS_TYPE 14, MAVLink GPS_INPUT) with a 3D fix: the EKF's position and velocity are aided
    ugps = {**UNAIDED_PARAMS, "GPS_TYPE": 14}
    run = convert_log(_tlog_with(tmp_path / "g.tlog", ugps, _gps_raw(3)), "ardusub")
    assert {run.metadata["channels"][c]["kind"] for c in "uvwxy"} == {"estimated"}


# ------------------------------------------------------------------------------------------- not a dataflash log

def ping_viewer_log(path):
    """A Ping Viewer sensor log as the application writes it (Qt QDataStream, big-endian): the header QString
    (uint32 byte length + UTF-16BE), version, build strings, sensor family/type, then (timestamp, Ping frame)."""
    def qstring(text):
        data = text.encode("utf-16-be")
        return struct.pack(">I", len(data)) + data
    # a Ping1D distance_simple frame: 'B' 'R', payload length, id 1211, source and destination ids, payload, checksum
    payload = struct.pack("<IB", 2500, 90)
    frame = b"BR" + struct.pack("<HHBB", len(payload), 1211, 0, 0) + payload
    frame += struct.pack("<H", sum(frame) & 0xFFFF)
    head = qstring("PingViewer sensor log file") + struct.pack(">i", 1)
    head += b"".join(qstring(s) for s in ("a1e1cb2", "2019-09-24", "v2.0.4", "Linux", "5"))
    head += struct.pack(">ii", 1, 1)
    path.write_bytes(head + qstring("00:00:01.000") + struct.pack(">I", len(frame)) + frame)
    return path, frame


def test_a_ping_viewer_bin_is_refused_naming_what_it_is(tmp_path, capsys):
    path, frame = ping_viewer_log(tmp_path / "20230418-110334123.bin")
    assert "Ping Viewer sensor log" in ping_viewer_signature(path)
    with pytest.raises(LogImportError, match="not an ArduPilot dataflash log: a Ping Viewer sensor log"):
        convert_log(path)
    assert main(["convert", str(path), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "Ping Viewer" in err[0]
    assert not (tmp_path / "p.csv").exists()
    # a raw Ping-protocol capture (checksummed 'BR' frames) is named too; a broken checksum is not a Ping frame
    raw = tmp_path / "raw.bin"
    raw.write_bytes(frame * 3)
    assert "Ping-protocol stream" in ping_viewer_signature(raw)
    raw.write_bytes(frame[:-1] + bytes([frame[-1] ^ 1]))
    assert ping_viewer_signature(raw) is None


# ------------------------------------------------------------------------------------------- shared logs

@pytest.mark.skipif(not (ARDUSUB_LOGS / "small.BIN").exists() or not DIVE.exists(), reason="shared logs absent")
def test_shared_logs_channels():
    """small.BIN (EK3_SRC1_VELXY/POSXY = 3 GPS, GPS_TYPE 1 without a GPS message, VISO_TYPE 0): XKF1 unaided; the sea
    dive (no parameters, a DVL: VISO and XKFD records): u v w from the DVL measured, x y estimated; small.tlog (a
    Water Linked UGPS, GPS_TYPE 14, fix 3 in most GPS_RAW_INT): LOCAL_POSITION_NED estimated."""
    small = convert_log(ARDUSUB_LOGS / "small.BIN").metadata["channels"]
    assert {small[c]["kind"] for c in "uvwxy"} == {UNAIDED} and small["z"]["kind"] == "measured"
    sea = convert_log(DIVE).metadata["channels"]
    assert {sea[c]["kind"] for c in "uvw"} == {"measured"} and {sea[c]["kind"] for c in "xy"} == {"estimated"}
    assert "XKFD records" in sea["x"]["aiding"]
    tlog = convert_log(ARDUSUB_LOGS / "small.tlog").metadata["channels"]
    assert {tlog[c]["kind"] for c in "uvwxy"} == {"estimated"}
