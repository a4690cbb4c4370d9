"""``udrobot-ctrl demo``: the main job, end to end.

1. identification: synthetic free-decay and pendulum launches following Cely 2019's protocol are
   identified back, and Table 7's added-mass coefficients are reproduced from its omega_n;
2. models: the five coefficient sets become Fossen plants, exported as udrobot-model/1 files;
3. plant: open-loop top speed and step responses of every model;
4. controllers: LQR, PID, linear and nonlinear MPC and the EKF across the 5 x 5 design/plant matrix;
5. plots and tables in ``--out``.

Every step that fails is reported and the demo goes on with the next one; the exit status
is non-zero if any step failed.
"""
from __future__ import annotations

import json
import time
import traceback
from pathlib import Path

import numpy as np

from udrobot_ctrl.vehicle import MODEL_NAMES, load_model, write_model_file


def register(subparsers):
    p = subparsers.add_parser("demo", help="identify, build the five models, run the controllers, write plots")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--full", action="store_true", help="full-length missions (slower) instead of the quick ones")
    p.set_defaults(func=run)


def _banner(text):
    print("\n" + "=" * len(text) + "\n" + text + "\n" + "=" * len(text), flush=True)


def step_models(out: Path) -> dict:
    """Export the five models and print their identified translational coefficients."""
    rows = {}
    print(f"{'model':<20} {'Xu_dot':>8} {'Yv_dot':>8} {'Zw_dot':>8} {'K_L,x':>7}"
          f" {'K_Q,x':>7} {'K_Q,y':>7} {'K_Q,z':>7}")
    for name in MODEL_NAMES:
        v = load_model(name)
        ma = np.diag(v.added_mass)
        dl = np.diag(v.linear_damping)
        dq = np.diag(v.quadratic_damping)
        print(f"{name:<20} {ma[0]:8.3f} {ma[1]:8.3f} {ma[2]:8.3f} {dl[0]:7.3f} {dq[0]:7.2f} {dq[1]:7.2f} {dq[2]:7.2f}")
        write_model_file(v, out / "models" / (name.replace(":", "_") + ".json"))
        rows[name] = {"added_mass": ma[:3].tolist(), "K_L": dl[:3].tolist(), "K_Q": dq[:3].tolist()}
    print(f"models exported to {out / 'models'} (udrobot-model/1)")
    return rows


def munk_critical_speed(v) -> float:
    """Surge speed (m/s) above which the Munk moment destabilises the passive pitch DOF.

    For small pitch the Munk moment (Z_wdot - X_udot) u w with w ~ u theta acts as a negative
    stiffness (Z_wdot - X_udot) u^2 against the restoring stiffness (z_g W - z_b B). Returns inf
    when Z_wdot <= X_udot (the moment is then stabilising).
    """
    d_ma = v.added_mass[2, 2] - v.added_mass[0, 0]
    k_restoring = v.r_g[2] * v.weight - v.r_b[2] * v.buoyancy
    if d_ma <= 0:
        return float("inf")
    return float(np.sqrt(max(k_restoring, 0.0) / d_ma))


def step_open_loop(out: Path) -> dict:
    """Full forward thrust on both horizontal thrusters: top speed per model, with a plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from udrobot_ctrl.sim import simulate

    fig, ax = plt.subplots(figsize=(7, 4))
    result = {}
    for name in MODEL_NAMES:
        v = load_model(name)
        f = np.zeros(len(v.thrusters))
        for i, t in enumerate(v.thrusters):
            if abs(t.direction[0]) > 0.9:
                f[i] = t.max_forward_N * np.sign(t.direction[0])
        x0 = np.zeros(12)
        x0[2] = 1.0
        r = simulate(v, x0, 20.0, inputs=lambda t, f=f: f, dt=0.01)
        u = r.x[:, 6]
        kl, kq = v.linear_damping[0, 0], v.quadratic_damping[0, 0]
        F = f.sum()
        u_pred = (-kl + np.sqrt(kl * kl + 4 * kq * F)) / (2 * kq)
        u_munk = munk_critical_speed(v)
        max_pitch = float(np.degrees(np.abs(r.x[:, 4]).max()))
        result[name] = {"top_speed_sim": float(u[-1]), "top_speed_pred": float(u_pred),
                        "max_pitch_deg": max_pitch, "munk_critical_speed": u_munk}
        note = ""
        if max_pitch > 30.0:
            note = (f"  <- pitch diverges ({max_pitch:.0f} deg): Munk moment (Z_wdot - X_udot) u w exceeds the "
                    f"restoring moment above {u_munk:.2f} m/s (pitch is passive in this layout)")
        print(f"{name:<20} top surge speed {u[-1]:.3f} m/s (F = K_L u + K_Q u^2 predicts {u_pred:.3f}){note}")
        ax.plot(r.t, u, label=name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("u (m/s)")
    ax.set_title("Full forward thrust (2 x 36.4 N): surge speed per coefficient set")
    ax.grid(True)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "open_loop_surge.png", dpi=120)
    plt.close(fig)
    return result


def step_controllers(out: Path, full: bool = False) -> dict:
    """LQR, PID, linear and nonlinear MPC designed on each model A and flown on every plant B (5 x 5), and the EKF
    with model A on data from plant B (``udrobot-ctrl compare``)."""
    from udrobot_ctrl.compare import compare, contract_json, text_table, write_outputs

    result = compare(quick=not full, keep_trajectories=True)
    write_outputs(result, out / "compare")
    (out / "compare" / "compare.json").write_text(json.dumps(contract_json(result), indent=2))
    print(text_table(result["results"], result.get("ekf", ())))
    for name, why in (result.get("skipped") or {}).items():
        print(f"skipped {name}: {why}")
    return {"rows": len(result["results"]), "ekf_rows": len(result.get("ekf", [])),
            "wall_s": result.get("wall_s")}


STEPS = [("models", step_models), ("open_loop", step_open_loop), ("controllers", step_controllers)]


def run(args) -> int:
    out = Path(args.out)
    (out / "models").mkdir(parents=True, exist_ok=True)
    summary, failed = {}, []
    for name, fn in STEPS:
        _banner(f"demo step: {name}")
        t0 = time.perf_counter()
        try:
            summary[name] = fn(out) if name != "controllers" else fn(out, full=args.full)
        except Exception as exc:  # the demo reports a failed step and goes on
            traceback.print_exc()
            summary[name] = {"error": f"{type(exc).__name__}: {exc}"}
            failed.append(name)
        print(f"[{name}: {time.perf_counter() - t0:.1f} s]")
    (out / "demo_summary.json").write_text(json.dumps(summary, indent=2, default=float))
    _banner("demo finished" + (f" with failed steps: {', '.join(failed)}" if failed else ""))
    print(f"outputs in {out.resolve()}")
    return 1 if failed else 0
