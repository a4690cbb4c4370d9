"""``udrobot-ctrl compare``: design on model A, fly on plant B, for every pair of the five models.

For each controller (``lqr``, ``pid``, ``lmpc``) and each design model A, the controller is designed on A
and the standard depth-and-heading mission (:class:`udrobot_ctrl.sensitivity.mission.DepthHeadingMission`:
1 m depth and 90 deg heading steps while cruising at 0.5 m/s) is flown on all five plants B at once with
the batched plant. Metrics (see :func:`udrobot_ctrl.sensitivity.mission.mission_metrics`):

* ``iae`` — integral of |depth error| (m s) + integral of |heading error| (rad s);
* ``overshoot`` — depth overshoot, % of the step; ``settling_s`` — depth settling time (2 % band);
* ``energy_J`` — ideal actuator-disk energy of the thrusts (estimated lower bound of the electrical energy);
* ``saturation_s`` — time with at least one thruster at its limit.

Not in this build yet (reported as ``skipped`` in the JSON): the casadi nonlinear MPC (``nmpc``) and the
EKF comparison; ``lmpc`` here is the condensed linear MPC solved by FISTA, not yet the OSQP formulation.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from udrobot_ctrl.vehicle import MODEL_NAMES, load_model

CONTROLLERS = ("lqr", "pid", "lmpc")
NOT_AVAILABLE = {"nmpc": "nonlinear MPC (casadi) is not implemented in this build",
                 "ekf": "EKF comparison is not implemented in this build"}


def _controller(kind, design_vehicle, bp, mission):
    from udrobot_ctrl.plant import plant_parameters
    from udrobot_ctrl.sensitivity.mission import (
        BatchLQR,
        BatchMPC,
        BatchPID,
        MPCSettings,
        lqr_gain,
        mpc_matrices,
        pid_gains,
        trim_thrust,
    )

    if kind == "lqr":
        K, trim = lqr_gain(design_vehicle, mission=mission)
        return BatchLQR(K, trim, mission), mission.dt
    if kind == "pid":
        trim = trim_thrust(plant_parameters(design_vehicle), mission.operating_point())
        return BatchPID(pid_gains(design_vehicle), trim, bp.T, mission), mission.dt
    if kind == "lmpc":
        settings = MPCSettings()
        qp = mpc_matrices(design_vehicle, mission, settings)
        return BatchMPC(qp, mission, bp.f_min, bp.f_max, settings), settings.Ts
    raise ValueError(f"controller must be one of {', '.join(CONTROLLERS)}, got {kind!r}")


def compare(models=MODEL_NAMES, controllers=CONTROLLERS, t_final: float = 20.0, keep_trajectories: bool = False):
    """Run every (design A, plant B, controller) combination.

    Returns
    -------
    dict
        ``{"models": [...], "results": [{"design", "plant", "controller", "iae", "overshoot", "settling_s",
        "energy_J", "saturation_s", ...}], "skipped": {...}}``, and ``"trajectories"`` when asked
        (``{(controller, design): SimResult}``).
    """
    from udrobot_ctrl.sensitivity.batch import batch_plant, simulate_batch
    from udrobot_ctrl.sensitivity.mission import DepthHeadingMission, mission_metrics

    models = list(models)
    mission = DepthHeadingMission(t_final=t_final)
    plants = [load_model(m) for m in models]
    bp = batch_plant(plants)
    rows, trajs = [], {}
    for kind in controllers:
        for design in models:
            ctrl, control_dt = _controller(kind, load_model(design), bp, mission)
            res = simulate_batch(bp, mission.x0(), mission.t_final, ctrl, dt=mission.dt, control_dt=control_dt)
            m = mission_metrics(res, mission, bp.f_min, bp.f_max)
            if keep_trajectories:
                trajs[(kind, design)] = res
            for j, plant in enumerate(models):
                rows.append({
                    "design": design, "plant": plant, "controller": kind,
                    "iae": float(m["iae_depth"][j] + m["iae_heading"][j]),
                    "overshoot": float(m["overshoot_depth"][j]),
                    "settling_s": float(m["settling_depth"][j]),
                    "energy_J": float(m["energy"][j]),
                    "saturation_s": float(m["saturation"][j] * mission.t_final),
                    "iae_depth": float(m["iae_depth"][j]), "iae_heading": float(m["iae_heading"][j]),
                    "speed_error": float(m["speed_error"][j]), "max_pitch_deg": float(m["max_pitch"][j]),
                    "lost_control": bool(m["lost_control"][j]),
                })
    out = {"models": models, "results": rows, "ekf": [], "skipped": dict(NOT_AVAILABLE)}
    if keep_trajectories:
        out["trajectories"] = trajs
    return out


TEXT_KEYS = ("iae", "overshoot", "settling_s", "energy_J", "saturation_s", "speed_error", "max_pitch_deg")


def text_table(results) -> str:
    """Readable fixed-width table of the result rows."""
    hdr = f"{'ctrl':<5} {'design':<19} {'plant':<19} {'IAE':>7} {'OS %':>6} {'Ts (s)':>7} {'E (J)':>7} " \
          f"{'sat (s)':>7} {'u err':>7} {'pitch':>6}"
    lines = [hdr, "-" * len(hdr)]
    for r in results:
        lines.append(f"{r['controller']:<5} {r['design']:<19} {r['plant']:<19} {r['iae']:7.3f} "
                     f"{r['overshoot']:6.1f} {r['settling_s']:7.2f} {r['energy_J']:7.1f} {r['saturation_s']:7.2f} "
                     f"{r['speed_error']:7.3f} {r['max_pitch_deg']:6.1f}" + ("  LOST" if r["lost_control"] else ""))
    return "\n".join(lines)


def write_outputs(result, out: Path) -> list:
    """CSV, text table and per-controller plots (design = plant trajectories and the IAE matrix)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    rows = result["results"]
    keys = ["controller", "design", "plant", *TEXT_KEYS, "lost_control"]
    csv = [",".join(keys)] + [",".join(str(r[k]) for k in keys) for r in rows]
    files = [out / "compare.csv", out / "compare.txt"]
    files[0].write_text("\n".join(csv) + "\n")
    files[1].write_text(text_table(rows) + "\n")
    models = result["models"]
    for kind in sorted({r["controller"] for r in rows}):
        mat = np.full((len(models), len(models)), np.nan)
        for r in rows:
            if r["controller"] == kind:
                mat[models.index(r["design"]), models.index(r["plant"])] = r["iae"]
        fig, ax = plt.subplots(figsize=(6.5, 5))
        im = ax.imshow(mat, cmap="viridis")
        ax.set_xticks(range(len(models)), models, rotation=40, ha="right")
        ax.set_yticks(range(len(models)), models)
        ax.set_xlabel("plant B")
        ax.set_ylabel("design model A")
        for i in range(len(models)):
            for j in range(len(models)):
                ax.text(j, i, f"{mat[i, j]:.2f}", ha="center", va="center", color="w", fontsize=8)
        fig.colorbar(im, label="IAE (depth m s + heading rad s)")
        ax.set_title(f"{kind.upper()}: IAE, design on A, fly on B")
        fig.tight_layout()
        path = out / f"compare_iae_{kind}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        files.append(path)
    trajs = result.get("trajectories") or {}
    for kind in sorted({k for k, _ in trajs}):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for design in models:
            res = trajs.get((kind, design))
            if res is None:
                continue
            j = models.index(design)
            axes[0].plot(res.t, res.x[:, j, 2], label=design)
            axes[1].plot(res.t, np.degrees(res.x[:, j, 5]), label=design)
        axes[0].set_ylabel("depth z (m)")
        axes[1].set_ylabel("heading psi (deg)")
        for ax in axes:
            ax.set_xlabel("t (s)")
            ax.grid(True)
        axes[0].legend(fontsize=8, title="design = plant")
        fig.suptitle(f"{kind.upper()}: 1 m depth and 90 deg heading steps at 0.5 m/s")
        fig.tight_layout()
        path = out / f"mission_{kind}.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        files.append(path)
    return files


def register(subparsers):
    p = subparsers.add_parser("compare", help="design on model A, fly on plant B: every pair of the five models")
    p.add_argument("--out", help="folder for CSV, text table and plots")
    p.add_argument("--json", help="write the JSON report here")
    p.add_argument("--controllers", default=",".join(CONTROLLERS), help="comma-separated: lqr,pid,lmpc")
    p.add_argument("--models", default=",".join(MODEL_NAMES), help="comma-separated model names or files")
    p.add_argument("--quick", action="store_true", help="short mission (10 s) for smoke tests")
    p.set_defaults(func=run)


def run(args) -> int:
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    for c in controllers:
        if c in NOT_AVAILABLE:
            raise ValueError(f"--controllers {c}: {NOT_AVAILABLE[c]}")
        if c not in CONTROLLERS:
            raise ValueError(f"--controllers: unknown controller {c!r} (expected {', '.join(CONTROLLERS)})")
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    result = compare(models, controllers, t_final=10.0 if args.quick else 20.0, keep_trajectories=bool(args.out))
    print(text_table(result["results"]))
    for name, why in result["skipped"].items():
        print(f"skipped {name}: {why}")
    if args.out:
        files = write_outputs(result, Path(args.out))
        print(f"wrote {len(files)} files to {args.out}")
    if args.json:
        doc = {k: v for k, v in result.items() if k != "trajectories"}
        path = Path(args.json)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(doc, indent=2))
        tmp.replace(path)
        print(f"wrote {path}")
    return 0
