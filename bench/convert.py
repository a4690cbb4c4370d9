"""Field-log conversion speed: a ~30-minute QGC-style ArduSub tlog converted with the shipped ``ardusub`` mapping.

The tlog is built with pymavlink's own encoder at the stream rates of the shared 2023 BlueOS/QGC log
(research): ATTITUDE and AHRS2 20 Hz, VFR_HUD 10 Hz, SYSTEM_TIME 3 Hz, GLOBAL_POSITION_INT 3 Hz,
DISTANCE_SENSOR 3 Hz of which 2 in 3 frames have a bad CRC, SYS_STATUS 3 Hz, SCALED_PRESSURE,
SCALED_PRESSURE2, RAW_IMU, SERVO_OUTPUT_RAW and RC_CHANNELS 2 Hz, NAMED_VALUE_FLOAT 16 Hz, HEARTBEAT 1 Hz;
plus AHRS 20 Hz and SCALED_IMU2 2 Hz: ~113 frames/s against ~165 in the real log. It carries the parameters
of a BlueROV2 Heavy and a truncated last frame.

Usage: ``python bench/convert.py [--minutes 30] [--json]``. Prints build and convert times, MB/s and frames/s;
nothing is asserted (2 shared cores here; figures depend on load). Target: < 10 s for 30 min.

Damaged copies (issue 40): ``python bench/convert.py --corrupt 1000 [--trials 5] [--seed 0] [--logs DIR]`` converts
each log of ``DIR`` (default ``../shared/data/ardusub_log_tools``, read only: copies go to a temporary folder)
clean, then ``--trials`` copies with ``--corrupt`` random bytes each replaced by a random value, each conversion
``udrobot-ctrl convert`` in its own process; it prints each conversion's exit status, CPU time (wall time drifts
with the load of a shared machine) and memory (the growth
of the peak resident memory during the conversion, imports excluded), the process's peak resident memory
(``ru_maxrss``, the interpreter and its imports included: about 130 MiB of any conversion) and their ratios to the
clean conversion's. Target: every damaged copy within
2x the clean time and memory, or exit 2 with the reason.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from udrobot_ctrl.convert import convert_log

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


SHARED_LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "ardusub_log_tools"
LOG_SUFFIXES = (".tlog", ".bin")


def corrupt_copy(src: Path, dst: Path, n: int, rng) -> None:
    """Copy ``src`` to ``dst`` with ``n`` random bytes (distinct offsets) replaced by different random values."""
    data = bytearray(src.read_bytes())
    where = rng.choice(len(data), size=min(n, len(data)), replace=False)
    for i in where:
        data[i] = (data[i] + int(rng.integers(1, 256))) % 256
    dst.write_bytes(bytes(data))


def convert_measured(log: Path, out: Path) -> dict:
    """``udrobot-ctrl convert LOG --out OUT --force`` in a child process (:func:`child`): exit status, the
    conversion's time (s, imports excluded) and memory (MiB: the growth of the peak resident memory during the
    conversion), the child's peak resident memory (MiB, ``ru_maxrss``: interpreter and imports included), the last
    stderr line."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(log), str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "UDROBOT_JOBS": "1"})
    out_text, err = (b.decode(errors="replace") for b in proc.communicate())
    rss = 0.0
    try:
        import resource

        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0  # the largest child so far
    except ImportError:
        pass
    lines = err.strip().splitlines()
    report = json.loads(out_text.strip().splitlines()[-1]) if out_text.strip() else {}
    return {"status": proc.returncode, "wall_s": report.get("convert_s", float("nan")),
            "cpu_s": report.get("cpu_s", float("nan")),
            "heap_mib": report.get("heap_mib", float("nan")), "rss_mib": report.get("rss_mib", rss),
            "message": lines[-1][:160] if lines else "", "traceback": "Traceback" in err}


def _rss_now_mib() -> float:
    """This process's resident memory now (Linux /proc; nan elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return float("nan")


def child(log: str, out: str) -> int:
    """One conversion, measured from inside: prints ``{"convert_s", "cpu_s", "heap_mib", "rss_mib"}`` as its last
    line (wall and CPU time: on a shared machine compare CPU times), where
    ``heap_mib`` is the growth of the peak resident memory during the conversion (imports done before)."""
    import resource

    from udrobot_ctrl.cli import convert as _convert  # noqa: F401 - imports outside the measurement
    from udrobot_ctrl.cli.main import main as cli_main
    from udrobot_ctrl.convert import convert_log  # noqa: F401
    from udrobot_ctrl.io.mapping import load_mapping  # noqa: F401

    before = _rss_now_mib()
    t0, c0 = time.perf_counter(), time.process_time()
    status = cli_main(["convert", log, "--mapping", "ardusub", "--out", out, "--force"])
    took, cpu = time.perf_counter() - t0, time.process_time() - c0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(json.dumps({"convert_s": took, "cpu_s": cpu, "heap_mib": max(rss - before, 0.0), "rss_mib": rss}))
    return status


def corrupt_bench(logs: Path, n: int, trials: int, seed: int) -> list:
    """Clean and damaged conversions of every log in ``logs``; one result dict per conversion."""
    import numpy as np

    rng = np.random.default_rng(seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for src in sorted(p for p in logs.iterdir() if p.suffix.lower() in LOG_SUFFIXES):
            clean = tmp / src.name
            shutil.copy(src, clean)
            base = convert_measured(clean, tmp / "clean.csv")
            print(f"{src.name}: clean: exit {base['status']}, {base['cpu_s']:.2f} s CPU ({base['wall_s']:.2f} s "
                  f"wall), conversion memory {base['heap_mib']:.1f} MiB, RSS {base['rss_mib']:.0f} MiB", flush=True)
            rows.append({"log": src.name, "trial": "clean", **base})
            for k in range(trials):
                bad = tmp / f"bad{src.suffix}"
                corrupt_copy(src, bad, n, rng)
                r = convert_measured(bad, tmp / "bad.csv")
                r.update(log=src.name, trial=k, time_ratio=r["cpu_s"] / base["cpu_s"],
                         heap_ratio=r["heap_mib"] / base["heap_mib"], rss_ratio=r["rss_mib"] / base["rss_mib"])
                within = max(r["time_ratio"], r["heap_ratio"], r["rss_ratio"]) <= 2
                r["ok"] = (r["status"] == 2 or (r["status"] == 0 and within)) and not r["traceback"]
                print(f"  {n} flips #{k}: exit {r['status']}, {r['cpu_s']:.2f} s CPU ({r['time_ratio']:.2f}x), memory "
                      f"{r['heap_mib']:.1f} MiB ({r['heap_ratio']:.2f}x), RSS {r['rss_mib']:.0f} MiB "
                      f"({r['rss_ratio']:.2f}x){'' if r['ok'] else '  <-- OVER'}"
                      + (f"; {r['message']}" if r["status"] else ""), flush=True)
                rows.append(r)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--corrupt", type=int, default=0, metavar="N",
                    help="convert copies of the shared logs with N random bytes replaced (see the module doc)")
    ap.add_argument("--trials", type=int, default=5, help="damaged copies per log (--corrupt)")
    ap.add_argument("--seed", type=int, default=0, help="random seed of the damage (--corrupt)")
    ap.add_argument("--logs", type=Path, default=SHARED_LOGS, help="folder of the logs (--corrupt)")
    ap.add_argument("--child", nargs=2, metavar=("LOG", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        sys.exit(child(*args.child))
    if args.corrupt:
        rows = corrupt_bench(args.logs, args.corrupt, args.trials, args.seed)
        bad = [r for r in rows if r["trial"] != "clean" and not r["ok"]]
        damaged = [r for r in rows if r["trial"] != "clean"]
        worst_t = max((r["time_ratio"] for r in damaged), default=float("nan"))
        worst_h = max((r["heap_ratio"] for r in damaged), default=float("nan"))
        worst_m = max((r["rss_ratio"] for r in damaged), default=float("nan"))
        print(f"{len(damaged)} damaged conversions: worst CPU time {worst_t:.2f}x, memory {worst_h:.2f}x, RSS "
              f"{worst_m:.2f}x of the clean one; {len(bad)} over 2x without exit 2 (or with a traceback)")
        if args.json:
            print(json.dumps({"corrupt": args.corrupt, "trials": args.trials, "seed": args.seed,
                              "worst_time_ratio": round(worst_t, 3), "worst_heap_ratio": round(worst_h, 3),
                              "worst_rss_ratio": round(worst_m, 3), "over": len(bad)}))
        return
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
