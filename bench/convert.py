"""Field-log conversion speed: a ~30-minute QGC-style ArduSub tlog converted with the shipped ``ardusub`` mapping.

The tlog is built with pymavlink's own encoder at the stream rates of the shared 2023 BlueOS/QGC log
(research): ATTITUDE and AHRS2 20 Hz, VFR_HUD 10 Hz, SYSTEM_TIME 3 Hz, GLOBAL_POSITION_INT 3 Hz,
DISTANCE_SENSOR 3 Hz of which 2 in 3 frames have a bad CRC, SYS_STATUS 3 Hz, SCALED_PRESSURE,
SCALED_PRESSURE2, RAW_IMU, SERVO_OUTPUT_RAW and RC_CHANNELS 2 Hz, NAMED_VALUE_FLOAT 16 Hz, HEARTBEAT 1 Hz;
plus AHRS 20 Hz and SCALED_IMU2 2 Hz: ~113 frames/s against ~165 in the real log. It carries the parameters
of a BlueROV2 Heavy and a truncated last frame.

Usage: ``python bench/convert.py [--minutes 30] [--json]``. Prints build and convert times, MB/s and frames/s;
nothing is asserted (2 shared cores here; figures depend on load). Target: < 10 s for 30 min.
"""
from __future__ import annotations

import argparse
import json
import struct
import tempfile
import time
from pathlib import Path

import numpy as np

from udrobot_ctrl.io import convert_log

T0 = 1_681_840_000.0


def build_tlog(path: Path, minutes: float) -> int:
    """Write the synthetic tlog; return its number of frames."""
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    ping = mav2.MAVLink(None, srcSystem=1, srcComponent=194)
    duration = 60.0 * minutes
    ev = []

    def every(rate, fn, phase=0.0):
        for t in np.arange(phase, duration, 1.0 / rate):
            ev.append((t, fn(t)))

    def depth(t):
        return 5.0 + 4.0 * np.sin(t / 120.0)

    params = {"FRAME_CONFIG": 2.0, "BARO2_GND_PRESS": 101325.0, "BARO_SPEC_GRAV": 1.0,
              **{f"SERVO{k}_FUNCTION": 32.0 + k for k in range(1, 9)}}
    for k, (name, v) in enumerate(params.items()):
        ev.append((0.001 * k, mav.param_value_encode(name.encode(), v, 9, len(params), k).pack(mav)))
    every(1.0, lambda t: mav.heartbeat_encode(12, 3, 81, 19, 4).pack(mav))
    every(20.0, lambda t: mav.attitude_encode(int(t * 1e3), 0.05 * np.sin(t), 0.02, 0.001 * t, 0.01, 0.0, 0.001)
          .pack(mav), 0.01)
    every(20.0, lambda t: mav.ahrs2_encode(0.05 * np.sin(t), 0.02, 0.001 * t, 0.0, 0, 0).pack(mav), 0.013)
    every(20.0, lambda t: mav.ahrs_encode(0, 0, 0, 0, 0, 0.0, 0.0).pack(mav), 0.014)
    every(3.0, lambda t: mav.system_time_encode(0, int(t * 1e3)).pack(mav), 0.015)
    every(2.0, lambda t: mav.scaled_imu2_encode(int(t * 1e3), 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav), 0.016)
    every(10.0, lambda t: mav.vfr_hud_encode(0.0, 0.0, 0, 0, 0.0, 0.0).pack(mav), 0.02)
    every(3.0, lambda t: mav.global_position_int_encode(int(t * 1e3), 0, 0, 0, int(-1e3 * depth(t)), 0, 0, 0, 0)
          .pack(mav), 0.03)
    every(3.0, lambda t: mav.sys_status_encode(0, 0, 0, 500, 15800, 100, 80, 0, 0, 0, 0, 0, 0).pack(mav), 0.04)
    every(2.0, lambda t: mav.scaled_pressure2_encode(int(t * 1e3), (101325.0 + 9810.0 * depth(t)) / 100, 0.0, 900)
          .pack(mav), 0.05)
    every(2.0, lambda t: mav.scaled_pressure_encode(int(t * 1e3), 996.0, 0.0, 4100).pack(mav), 0.06)
    every(2.0, lambda t: mav.raw_imu_encode(int(t * 1e6), 5, -3, -1000, 0, 0, 0, 0, 0, 0).pack(mav), 0.07)
    every(2.0, lambda t: mav.servo_output_raw_encode(int(t * 1e6), 0, *[1500 + int(50 * np.sin(t))] * 8,
                                                     0, 0, 0, 1100, 1100, 0, 0, 1500).pack(mav), 0.08)
    every(2.0, lambda t: mav.rc_channels_encode(int(t * 1e3), 16, *[1500] * 18, 255).pack(mav), 0.09)
    every(16.0, lambda t: mav.named_value_float_encode(int(t * 1e3), b"PilotGain", 0.5).pack(mav), 0.011)

    def distance(t):
        frame = bytearray(ping.distance_sensor_encode(int(t * 1e3), 20, 5000, 3000, 2, 1, 25, 0).pack(ping))
        if int(t * 3) % 3:
            frame[-1] ^= 0x33  # bad CRC, as BlueOS writes most of them
        return bytes(frame)

    every(3.0, distance, 0.012)
    ev.sort(key=lambda e: e[0])
    with open(path, "wb") as fh:
        for t, frame in ev:
            fh.write(struct.pack(">Q", int(round((T0 + t) * 1e6))) + frame)
    with open(path, "r+b") as fh:  # vehicle switched off mid-frame
        fh.truncate(path.stat().st_size - 7)
    return len(ev)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "dive.tlog"
        t0 = time.perf_counter()
        frames = build_tlog(path, args.minutes)
        build_s = time.perf_counter() - t0
        mb = path.stat().st_size / 1e6
        t0 = time.perf_counter()
        run = convert_log(path, "ardusub")
        convert_s = time.perf_counter() - t0
    z = run.channels["z"]
    print(f"tlog: {args.minutes:g} min, {frames} frames, {mb:.1f} MB (built in {build_s:.1f} s)")
    print(f"convert: {convert_s:.2f} s = {mb / convert_s:.1f} MB/s, {frames / convert_s / 1e3:.0f} k frames/s; "
          f"{run.n} rows, vehicle {run.metadata['vehicle']}, {run.inputs.shape[1]} inputs, "
          f"depth {np.nanmin(z):.2f}..{np.nanmax(z):.2f} m")
    print([ln for ln in run.metadata["notes"].splitlines() if ln.startswith("damage: bad CRC")][0])
    if args.json:
        print(json.dumps({"minutes": args.minutes, "frames": frames, "mb": round(mb, 2),
                          "convert_s": round(convert_s, 3), "mb_per_s": round(mb / convert_s, 2)}))


if __name__ == "__main__":
    main()
