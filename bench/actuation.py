"""ArduSub's output side on real logs: the mixer against RCOU, and the actuation check per DOF.

1. Mixer check (the sea dive ``guided_above_terrain/00000029_filtered.BIN``, BlueROV2 Heavy, VECTORED_6DOF): the
   RATE log's ``ROut POut YOut`` (roll/pitch/yaw inputs incl. feed-forward) and ``AOut`` (0..1 throttle) are the
   controllers' outputs to the mixer; forward and lateral (GUIDED: from the position controller) are not logged,
   so they are fitted per sample by least squares. The log has no parameters, so MOT_i_DIRECTION is fitted too
   (each of the 2^4 sign sets of the horizontals, the verticals' signs from their correlation with the mix); PWM
   range 1100-1900 us (Sub's defaults) assumed. Printed per channel: RMS of ``motor_pwm(...) - RCOU`` (us) and
   NRMSE = RMS / standard deviation of the channel's RCOU.
2. Actuation check (:func:`udrobot_ctrl.autopilot.actuation.actuation_check`) on the dive (pwm mirrored with the
   fitted directions) and on the BlueROV2 Heavy tlogs of ``ardusub_log_tools`` (converted by ``udrobot-ctrl
   convert``, which mirrors reversed motors from the logged MOT_i_DIRECTION).

The shared data are read in place (never copied); converted runs go to a temporary folder.
Usage: ``python bench/actuation.py [--data ../shared/data] [--work DIR]``.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from pymavlink import DFReader
from scipy.optimize import least_squares

from udrobot_ctrl.autopilot.actuation import actuation_check
from udrobot_ctrl.autopilot.motors import MotorParameters, fit_directions, frame, motor_pwm, throttle_bidirectional
from udrobot_ctrl.io.mavlink import motor_command_pwm
from udrobot_ctrl.io.runlog import Run, read_run
from udrobot_ctrl.vehicle import load_model

ROOT = Path(__file__).resolve().parents[1]
DIVE = "guided_above_terrain/00000029_filtered.BIN"
TLOGS = ("ardusub_log_tools/2023-04-18 11-03-34.tlog", "ardusub_log_tools/small.tlog")


def read_bin(path: Path) -> dict:
    """RATE (time s, ROut, POut, YOut, AOut) and RCOU (time s, C1..C8) of a dataflash log."""
    log = DFReader.DFReader_binary(str(path))
    rate, rcou = [], []
    while True:
        m = log.recv_match(type=["RATE", "RCOU"])
        if m is None:
            break
        if m.get_type() == "RATE":
            rate.append((m.TimeUS * 1e-6, m.ROut, m.POut, m.YOut, m.AOut))
        else:
            rcou.append([m.TimeUS * 1e-6] + [getattr(m, f"C{i}") for i in range(1, 9)])
    return {"RATE": np.array(rate), "RCOU": np.array(rcou, float)}


def paired(log: dict, max_lag: float = 0.05):
    """RCOU rows with the RATE sample of the same loop (the latest RATE at most ``max_lag`` s before)."""
    rate, rcou = log["RATE"], log["RCOU"]
    j = np.searchsorted(rate[:, 0], rcou[:, 0], side="right") - 1
    ok = (j >= 0) & (rcou[:, 0] - rate[np.maximum(j, 0), 0] <= max_lag)
    return rate[j[ok]], rcou[ok]


def fit_forward_lateral(fr, known, pwm, params):
    """Per sample: forward, lateral (and the residual) that make ArduSub's PWM closest to the logged one."""
    n = known.shape[0]
    u = np.zeros((n, 6))
    u[:, :4] = known
    # linear start (no normalisation): pwm - 1500 = 400 d (mix of known) + 400 d (F f_fwd + L f_lat)
    base = motor_pwm(fr, u, params, integer=False)
    A = np.column_stack([fr.factors[:, 4], fr.factors[:, 5]]) * np.asarray(params.directions)[:, None] * 400.0
    sol = np.linalg.lstsq(A, (pwm - base).T, rcond=None)[0].T
    u[:, 4:] = sol
    for k in range(n):  # refine with the exact (normalising) mixer where the linear fit is off
        res = motor_pwm(fr, u[k], params, integer=False) - pwm[k]
        if np.max(np.abs(res)) > 2.0:
            def f(x, k=k):
                return motor_pwm(fr, np.r_[u[k, :4], x], params, integer=False) - pwm[k]
            u[k, 4:] = least_squares(f, u[k, 4:], bounds=([-1.5, -1.5], [1.5, 1.5])).x
    return u


def mixer_check(path: Path):
    """Fit directions and forward/lateral on the dive; print the per-channel residuals. Returns the directions."""
    log = read_bin(path)
    rate, rcou = paired(log)
    fr = frame("VECTORED_6DOF")
    pwm = rcou[:, 1:9]
    known = np.column_stack([rate[:, 1], rate[:, 2], rate[:, 3], throttle_bidirectional(rate[:, 4])])
    print(f"mixer check: {path.name}, {len(pwm)} RCOU samples paired with RATE (10 Hz); frame VECTORED_6DOF; "
          f"MOT_PWM_MIN/MAX 1100/1900 us assumed (no parameters in the log)")
    fit = fit_directions(fr, known, pwm)  # the converter's inference (udrobot_ctrl.convert.infer_motor_directions)
    dirs = list(fit.directions)
    print(f"  MOT_1..8_DIRECTION fitted over the 256 sign patterns: {fit.directions} (residual RMS {fit.rms:.4f} of "
          f"full scale; next pattern {fit.runner_up:.4f})")
    params = MotorParameters(directions=tuple(int(d) for d in dirs))
    u = fit_forward_lateral(fr, known, pwm, params)
    pred = motor_pwm(fr, u, params)  # ArduSub's integer PWM
    err = pred - pwm
    print(f"  fitted forward: median {np.median(u[:, 4]):+.3f}, range [{u[:, 4].min():+.3f}, {u[:, 4].max():+.3f}]; "
          f"lateral: median {np.median(u[:, 5]):+.3f}, range [{u[:, 5].min():+.3f}, {u[:, 5].max():+.3f}]")
    print(f"  {'motor':>5s} {'dir':>4s} {'RCOU std us':>11s} {'RMS us':>7s} {'NRMSE':>7s} {'max |err| us':>12s}")
    for i in range(8):
        rms = float(np.sqrt(np.mean(err[:, i] ** 2)))
        std = float(np.std(pwm[:, i]))
        print(f"  {i + 1:5d} {dirs[i]:+4d} {std:11.1f} {rms:7.2f} {rms / std:7.4f} {np.abs(err[:, i]).max():12.0f}")
    tot = float(np.sqrt(np.mean(err ** 2)))
    print(f"  all: RMS {tot:.2f} us, NRMSE {tot / float(np.std(pwm - pwm.mean(0))):.4f}; verticals (no fitted input): "
          f"RMS {float(np.sqrt(np.mean(err[:, 4:] ** 2))):.2f} us")
    return tuple(int(d) for d in dirs), log


def dive_run(data: Path, work: Path, dirs, log) -> Run:
    """The converted dive with pwm_1..8 from RCOU C1..C8 (motor-command PWM: mirrored with ``dirs``)."""
    out = work / "dive.csv"
    subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "convert", str(data / DIVE), "--out", str(out)],
                   check=True, capture_output=True)
    run = read_run(out)
    notes = run.metadata.get("notes", "")
    notes = notes if isinstance(notes, str) else "\n".join(notes)
    if "mirrored" in notes:
        print("  dive: the converter mirrored reversed motors from the log's MOT_i_DIRECTION; pwm used as it is")
        return run
    if run.inputs.shape[1] == 8:
        raw = run.inputs
        print(f"  dive: converter gave 8 raw pwm columns (the log has no MOT_i_DIRECTION); mirrored with the "
              f"fitted MOT_i_DIRECTION {dirs}")
    else:
        m = re.search(r"t = 0 is log time ([0-9.]+) s", notes)
        t0 = float(m.group(1)) if m else float(run.extra["t_source"][0])
        rcou = log["RCOU"]
        j = np.clip(np.searchsorted(rcou[:, 0], run.t + t0, side="right") - 1, 0, len(rcou) - 1)
        raw = rcou[j, 1:9]
        print(f"  dive: converter gave {run.inputs.shape[1]} pwm columns; pwm_1..8 rebuilt from RCOU C1..C8 (held), "
              f"mirrored with the fitted MOT_i_DIRECTION {dirs}")
    return Run(run.path, run.t, run.channels, "pwm", motor_command_pwm(raw, dirs), run.extra, run.metadata)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT / ".." / "shared" / "data"))
    ap.add_argument("--work", default=None, help="folder for converted runs (default: a temporary one)")
    args = ap.parse_args(argv)
    data = Path(args.data)
    if not (data / DIVE).exists():
        print(f"no shared data at {data}")
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        dirs, log = mixer_check(data / DIVE)
        heavy = load_model("bluerov2-heavy")
        run = dive_run(data, work, dirs, log)
        print(f"\nactuation check: {DIVE} (bluerov2-heavy, {run.duration:.0f} s)")
        check = actuation_check(run, heavy)
        print(check.table())
        for note in check.notes:
            print("  " + note)
        for rel in TLOGS:
            src = data / rel
            out = work / (src.stem.replace(" ", "_") + ".csv")
            subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "convert", str(src), "--mapping", "ardusub",
                            "--out", str(out)], check=True, capture_output=True)
            run = read_run(out)
            vehicle = load_model(run.metadata.get("vehicle", "bluerov2-heavy"))
            print(f"\nactuation check: {rel} ({vehicle.name}, {run.duration:.0f} s, pwm x{run.inputs.shape[1]})")
            check = actuation_check(run, vehicle)
            print(check.table())
            for note in check.notes:
                print("  " + note)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
