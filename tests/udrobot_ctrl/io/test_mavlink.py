"""MAVLink .tlog built with pymavlink's encoder and a dataflash .bin (cross-checked with pymavlink's DFReader)."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from udrobot_ctrl.convert import convert_log, load_any
from udrobot_ctrl.io import LogImportError
from udrobot_ctrl.io.mavlink import Damage, LogFacts, firmware_text, iter_dataflash, iter_tlog

T0 = 1_700_000_000.0
# these synthetic logs name no frame and their outputs do not tell one (outputs held at 1400 / 1600 us beside moving
# ones, or a single moving output): the converter refuses to guess, so the tests give the 4-thruster vehicle
VEHICLE = "udrobot"


def roll(t):
    return 0.4 * np.exp(-0.3 * t) * np.cos(2 * np.pi * 0.8 * t)


def write_tlog(path, duration=3.0, servo_dt=0.1, pressure=False):
    """ATTITUDE 50 Hz, SERVO_OUTPUT_RAW 10 Hz, VFR_HUD (alt = -depth) or SCALED_PRESSURE2, tlog framing."""
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    events = []
    for t in np.arange(0.0, duration, 0.02):
        events.append((t, mav.attitude_encode(int(t * 1000), roll(t), 0.05, 1.0 + 0.1 * t, -0.1, 0.0, 0.1)))
        depth = 1.0 + 0.2 * t
        if pressure:
            p_hpa = (101325.0 + 1000.0 * 9.81 * depth) / 100.0  # surface pressure + rho g depth
            events.append((t + 0.001, mav.scaled_pressure2_encode(int(t * 1000), p_hpa, 0.0, 2000)))
        else:
            events.append((t + 0.001, mav.vfr_hud_encode(0.0, 0.0, 0, 0, -depth, 0.0)))
    for k, t in enumerate(np.arange(0.005, duration, servo_dt)):
        t = t + (0.003 if k else 0.0)  # keep later commands off the 50 Hz output grid (no ties at 1 us resolution)
        events.append((t, mav.servo_output_raw_encode(int(t * 1e6), 0, 1500 + k, 1400, 1600, 1500 - k,
                                                                 1500, 1500, 1500, 1500)))
    events.sort(key=lambda e: e[0])
    with open(path, "wb") as fh:
        for t, msg in events:
            fh.write(struct.pack(">Q", int(round((T0 + t) * 1e6))) + msg.pack(mav))
    return path


def test_tlog_round_trip_with_vfr_hud_depth(tmp_path):
    path = write_tlog(tmp_path / "dive.tlog")
    run = convert_log(path, "ardusub", vehicle=VEHICLE)
    t_abs = T0 + 0.005 + run.t  # overlap starts at the first SERVO_OUTPUT_RAW (+5 ms)
    t = t_abs - T0
    np.testing.assert_allclose(run.channels["phi"], roll(t), atol=0.4 * (2 * np.pi * 0.8) ** 2 * 0.02**2 / 8 + 1e-6)
    np.testing.assert_allclose(run.channels["psi"], 1.0 + 0.1 * t, atol=1e-6)
    np.testing.assert_allclose(run.channels["z"], 1.0 + 0.2 * (t - 0.001), atol=1e-5)  # float32 alt
    np.testing.assert_allclose(run.channels["r"], 0.1, atol=1e-7)
    k = np.maximum(np.floor((t - 0.008) / 0.1), 0).astype(int)  # command k issued at 0.008 + 0.1 k (k >= 1)
    np.testing.assert_array_equal(run.inputs[:, 0], 1500 + k)
    np.testing.assert_array_equal(run.inputs[:, 3], 1500 - k)
    notes = run.metadata["notes"]
    assert "z <- VFR_HUD[alt]" in notes and "tlog receive time" in notes
    assert "ATTITUDE: autopilot time (aligned by median offset) - tlog receive time delay median 0.0 ms" in notes
    assert load_any(path, vehicle=VEHICLE).n == run.n


def test_tlog_external_pressure_sensor_gives_depth(tmp_path):
    path = write_tlog(tmp_path / "p.tlog", pressure=True)
    run = convert_log(path, "ardusub", vehicle=VEHICLE)
    t = run.t + 0.005
    # the log starts at 1.0 m (1111 hPa, above any weather): not the surface, so the standard atmosphere
    # (101325 Pa, the value encoded) is the reference and the depth is the true one
    np.testing.assert_allclose(run.channels["z"], 1.0 + 0.2 * (t - 0.001), atol=2e-4)
    notes = run.metadata["notes"]
    assert "SCALED_PRESSURE2[press_abs] (pressure_to_depth" in notes
    assert "starts under water; standard atmosphere 1013.25 hPa assumed" in notes


def test_tlog_damage_is_skipped_counted_and_named_by_offset(tmp_path):
    path = write_tlog(tmp_path / "a.tlog", duration=0.5)
    data = path.read_bytes()
    frames = list(iter_tlog(path))
    assert len(frames) == 25 * 2 + 5
    # truncated in the middle of the last frame: everything before it is read, the tail is counted
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(data[:-5])
    last_offset = frames[-1][1]
    damage = Damage()
    assert len(list(iter_tlog(cut, damage))) == len(frames) - 1
    assert damage.kinds["truncated tail"].offsets == [last_offset]
    run = convert_log(cut, "ardusub", vehicle=VEHICLE)
    assert f"damage: truncated tail: 1 ({len(data) - 5 - last_offset} bytes), first byte offsets {last_offset}" \
        in run.metadata["notes"]
    # a flipped payload byte: that frame alone is skipped as a bad CRC of its type
    index, offset, _, msg = frames[10]
    bad = bytearray(data)
    bad[offset + 8 + 12] ^= 0xFF
    (tmp_path / "crc.tlog").write_bytes(bytes(bad))
    damage = Damage()
    kept = list(iter_tlog(tmp_path / "crc.tlog", damage))
    assert len(kept) == len(frames) - 1 and offset not in [f[1] for f in kept]
    kind = f"bad CRC {msg.get_type()} ({msg.get_msgId()})"
    assert damage.kinds[kind].count == 1 and damage.kinds[kind].offsets == [offset]
    # garbage where a start byte should be: skipped up to the next frame
    bad = bytearray(data)
    bad[frames[3][1] + 8] = 0x00
    (tmp_path / "start.tlog").write_bytes(bytes(bad))
    damage = Damage()
    kept = list(iter_tlog(tmp_path / "start.tlog", damage))
    assert [f[1] for f in kept] == [f[1] for f in frames if f[1] != frames[3][1]]
    garbage = damage.kinds["garbage (no frame start)"]
    assert garbage.offsets == [frames[3][1]] and garbage.nbytes == frames[4][1] - frames[3][1]
    # nothing usable: refused with the file named
    (tmp_path / "junk.tlog").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(LogImportError, match=r"junk.tlog: nothing usable decodes.*byte offset 0"):
        convert_log(tmp_path / "junk.tlog", "ardusub")


# ------------------------------------------------------------------------------------------- dataflash

FMT_STRUCT = struct.Struct("<BBB4s16s64s")


def _fmt(mtype, name, fmt, columns):
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    length = 3 + struct.calcsize("<" + "".join(FORMAT_TO_STRUCT[c][0] for c in fmt))
    record = b"\xa3\x95" + FMT_STRUCT.pack(128, mtype, length, name.encode(), fmt.encode(), columns.encode())
    return record, length


def write_bin(path, duration=3.0):
    """A minimal ArduSub-style dataflash log: FMT, ATT (cdeg as float deg here), RCOU, BARO instances 0/1."""
    out = [_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")[0]]
    att, _ = _fmt(129, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw")
    rcou, _ = _fmt(130, "RCOU", "QHHHH", "TimeUS,C1,C2,C3,C4")
    baro, _ = _fmt(131, "BARO", "QBf", "TimeUS,I,Alt")
    out += [att, rcou, baro]
    events = []
    for t in np.arange(0.0, duration, 0.01):
        us = int(round((10.0 + t) * 1e6))
        events.append((us, b"\xa3\x95\x81" + struct.pack("<Qfff", us, np.degrees(roll(t)), 2.0, 90.0)))
        events.append((us + 1, b"\xa3\x95\x83" + struct.pack("<QBf", us + 1, 0, 5.0)))  # enclosure baro
        events.append((us + 2, b"\xa3\x95\x83" + struct.pack("<QBf", us + 2, 1, -(0.5 + 0.1 * t))))
    for k, t in enumerate(np.arange(0.0, duration, 0.05)):
        us = int(round((10.0 + t) * 1e6)) + 3
        events.append((us, b"\xa3\x95\x82" + struct.pack("<QHHHH", us, 1500 + k, 1500, 1500, 1500)))
    events.sort(key=lambda e: e[0])
    path.write_bytes(b"".join(out) + b"".join(e[1] for e in events))
    return path


def test_dataflash_round_trip_and_agrees_with_pymavlink(tmp_path):
    from pymavlink.DFReader import DFReader_binary

    path = write_bin(tmp_path / "00000001.BIN".lower())
    ours = [(name, values) for _, _, name, values in iter_dataflash(path)]
    ref = DFReader_binary(str(path))
    theirs = []
    while (m := ref.recv_msg()) is not None:
        if m.get_type() != "FMT":
            theirs.append((m.get_type(), {c: getattr(m, c) for c in m.get_fieldnames()}))
    assert [n for n, _ in ours] == [n for n, _ in theirs]
    assert all(a == pytest.approx(b) for (_, a), (_, b) in zip(ours, theirs))

    run = convert_log(path, "ardusub", require_inputs=True, vehicle=VEHICLE)
    t = run.t  # first ATT at boot 10.0 s is the earliest; BARO[1] starts 2 µs later
    np.testing.assert_allclose(run.channels["phi"], roll(t), atol=1e-3)
    np.testing.assert_allclose(run.channels["psi"], np.pi / 2, atol=1e-6)
    np.testing.assert_allclose(run.channels["z"], 0.5 + 0.1 * t, atol=1e-5)  # BARO instance 1, Alt = -depth
    assert "z <- BARO[1][Alt]" in run.metadata["notes"]
    assert run.inputs[0, 0] == 1500 and run.inputs[-1, 0] == 1500 + int((t[-1] + 1e-9) // 0.05)


def test_dataflash_truncated_or_corrupt(tmp_path):
    path = write_bin(tmp_path / "a.bin", duration=0.2)
    data = path.read_bytes()
    records = [(i, o, n) for i, o, n, _ in iter_dataflash(path)]
    (tmp_path / "cut.bin").write_bytes(data[:-7])
    run = convert_log(tmp_path / "cut.bin", "ardusub", vehicle=VEHICLE)
    _, last_offset, last_name = records[-1]
    assert f"damage: truncated tail ({last_name}): 1 ({len(data) - 7 - last_offset} bytes), first byte offsets " \
        f"{last_offset}" in run.metadata["notes"]
    index, offset, _ = records[7]
    bad = bytearray(data)
    bad[offset] ^= 0xFF  # broken record header: that record is lost, the reader resynchronises on the next
    (tmp_path / "bad.bin").write_bytes(bytes(bad))
    damage = Damage()
    kept = [o for _, o, _, _ in iter_dataflash(tmp_path / "bad.bin", damage)]
    assert kept == [o for _, o, _ in records if o != offset]
    assert damage.kinds["garbage (no record header)"].offsets == [offset]
    assert damage.kinds["garbage (no record header)"].nbytes == records[8][1] - offset
    (tmp_path / "zero.bin").write_bytes(b"\0" * 100)
    with pytest.raises(LogImportError, match=r"zero.bin: nothing usable decodes"):
        convert_log(tmp_path / "zero.bin", "ardusub")


def test_dataflash_fmt_with_unknown_format_char_is_damage_not_a_crash(tmp_path, capsys):
    """A FMT record whose format has a character pymavlink does not know is counted as 'bad FMT' damage (pymavlink
    would print and raise a bare Exception); the other records are read."""
    path = write_bin(tmp_path / "a.bin", duration=0.2)
    good = [(o, n) for _, o, n, _ in iter_dataflash(path)]
    bad_fmt = b"\xa3\x95" + FMT_STRUCT.pack(128, 140, 12, b"BAD", b"QX", b"TimeUS,V")
    data = path.read_bytes()
    (tmp_path / "b.bin").write_bytes(bad_fmt + data)
    damage = Damage()
    kept = [(o - len(bad_fmt), n) for _, o, n, _ in iter_dataflash(tmp_path / "b.bin", damage)]
    assert kept == good
    assert damage.kinds["bad FMT"].offsets == [0]
    assert "Unsupported format char" not in capsys.readouterr().out


def test_firmware_text_is_the_last_version_banner():
    """The sidecar's ``firmware``: the log's own ``ArduSub V...`` banner (the real logs send
    'ArduSub V4.1.0 (89639005)' and 'ArduSub V4.1.1 BETA5 (66c674c1)'), None when absent."""
    facts = LogFacts(texts=["ArduSub V4.1.0 (89639005)", "Frame: VECTORED", "ArduSub V4.1.1 BETA5 (66c674c1)"])
    assert firmware_text(facts) == "ArduSub V4.1.1 BETA5 (66c674c1)"
    assert firmware_text(LogFacts(texts=["Frame: VECTORED_6DOF"])) is None
