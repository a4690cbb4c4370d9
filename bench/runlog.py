"""Reading a large ``udrobot-run/1`` CSV: peak memory over file size, and rows/s.

    python bench/runlog.py [--mb 200] [--keep PATH]

Writes a synthetic run (6 thrusts, the 12 state channels and voltage, full-precision floats: ~420 bytes per
row) of about ``--mb`` MB, then reads it with :func:`udrobot_ctrl.io.runlog.read_run` in a fresh process and
prints the peak resident memory above that process's baseline (after imports), as a multiple of the file size.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from udrobot_ctrl.io.runlog import STATE_CHANNELS, write_run

CHILD = r"""
import json, sys, time
from udrobot_ctrl.io.runlog import read_run

def status_kib(key):
    with open("/proc/self/status") as fh:
        return next(int(l.split()[1]) for l in fh if l.startswith(key + ":"))

base = status_kib("VmRSS")
t0 = time.perf_counter()
run = read_run(sys.argv[1])
wall = time.perf_counter() - t0
peak = status_kib("VmHWM")  # peak RSS of this process image (ru_maxrss would include the parent's, across exec)
print(json.dumps({"rows": run.n, "wall_s": wall, "base_kib": base, "peak_kib": peak,
                  "array_bytes": run.t.nbytes + run.inputs.nbytes + sum(v.nbytes for v in run.channels.values())}))
"""


def make_run(path: Path, rows: int, seed: int = 0) -> Path:
    """A synthetic 10 Hz..100 Hz run of ``rows`` rows with full-precision random channels."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.005, 0.015, rows))
    channels = {c: rng.normal(size=rows) for c in STATE_CHANNELS}
    channels["voltage"] = 15.0 + rng.normal(scale=0.1, size=rows)
    inputs = rng.uniform(-30, 30, size=(rows, 6))
    return write_run(path, t, channels, "thrust", inputs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=200.0, help="approximate file size, MB (default 200)")
    ap.add_argument("--keep", help="write the generated file here (default: a temporary folder)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.keep) if args.keep else Path(tmp) / "big_run.csv"
        rows = int(args.mb * 1e6 / 420)
        t0 = time.perf_counter()
        make_run(path, rows)
        size = path.stat().st_size
        print(f"wrote {path}: {rows} rows, {size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s "
              f"({rows / (time.perf_counter() - t0):,.0f} rows/s)")
        out = subprocess.run([sys.executable, "-c", CHILD, str(path)], check=True, capture_output=True, text=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
    extra = (r["peak_kib"] - r["base_kib"]) * 1024
    print(f"read_run: {r['rows']} rows in {r['wall_s']:.1f} s = {r['rows'] / r['wall_s']:,.0f} rows/s, "
          f"{size / 1e6 / r['wall_s']:.1f} MB/s")
    print(f"peak RSS above baseline {extra / 1e6:.0f} MB = {extra / size:.2f} x the file size "
          f"(the returned float64 arrays alone: {r['array_bytes'] / 1e6:.0f} MB = {r['array_bytes'] / size:.2f} x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
