"""``udrobot-ctrl demo``: the main job, end to end.

1. identification: SYNTHETIC free-decay and pendulum launches and CFD tables, generated from the coefficients
   of Cely et al. 2019 following its protocol (the paper's raw data are not public), are identified back, and
   Table 7's added-mass coefficients are reproduced from its omega_n;
2. models: the five coefficient sets become Fossen plants, exported as udrobot-model/1 files;
3. plant: open-loop top speed and step responses of every model;
4. controllers: LQR, PID, linear and nonlinear MPC and the EKF across the 5 x 5 design/plant matrix;
5. plots and tables in ``--out``, indexed by ``--out/README.md`` (what each file is, what to open first).

Every step that fails is reported and the demo goes on with the next one; the exit status
is non-zero if any step failed.
"""
from __future__ import annotations

import argparse
import json
import time
import traceback
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from identification import cfd, free_decay, synthetic
from identification.identify import RigOptions, coefficient_set_values, identify_files
from identification.plots import plot_report
from identification.sets import write_coefficient_set
from udrobot_ctrl.control.compare import (
    MPC_PREVIEW,
    compare,
    compile_kernels,
    write_outputs,
)
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.parallel import Background
from udrobot_ctrl.vehicle import MODEL_NAMES, coefficient_set, full_size_vehicle, load_model, write_model_file
from udrobot_files.output import OutputError, atomic_write, check_command, open_atomic, save_figure

SYNTHETIC_NOTE = ("the identification data are SYNTHETIC: launch logs and CFD tables generated from the "
                  "coefficients of Cely et al. 2019 (its raw data are not public) with simulated sensor noise; "
                  "the intervals show how well the method recovers known values, not the real vehicle's "
                  "uncertainty")


# units of the identified coefficients (launches: of the scaled test model; CFD: full size)
COEFF_UNITS = {"Cm": "[-]", "CD": "[-]", "KL": "[N s/m]", "KQ": "[N s^2/m^2]"}
SUMMARY_FILE = "demo_summary.json"  # written last: its presence marks a folder holding an earlier demo
INDEX_FILE = "README.md"  # the index of what the demo wrote (write_index)


def register(subparsers):
    p = subparsers.add_parser(
        "demo", help="identify, build the five models, run the controllers, write plots",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="The whole chain on the UDrobot of Cely et al. 2019 (Sensors 19, 3631): about 20 s on two\n"
                    "cores, about 1 min the first time on a machine (its kernels are compiled once):\n"
                    "  1. identification of SYNTHETIC launch logs and CFD tables generated from the paper's\n"
                    "     coefficients (its raw data are not public): checks the method, not the vehicle;\n"
                    "  2. the five shipped models (cfd, free_decay, pendulum coefficient sets) as udrobot-model/1;\n"
                    "  3. open-loop top speed per model;\n"
                    "  4. LQR, PID, linear and nonlinear MPC designed on each model and flown on every other\n"
                    "     (5 x 5), and the EKF likewise;\n"
                    "  5. plots, tables and an index OUT/README.md saying what to open first.",
        epilog="example: udrobot-ctrl demo --out demo_out   (then open demo_out/README.md)")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--full", action="store_true", help="full-length missions (46 s instead of 23 s; slower)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes for the controller matrix (default: one per core)")
    p.add_argument("--force", action="store_true", help="replace the outputs of an earlier demo in --out")
    p.set_defaults(func=run)


def _banner(text):
    print("\n" + "=" * len(text) + "\n" + text + "\n" + "=" * len(text), flush=True)


def step_identification(out: Path) -> dict:
    """Identify synthetic raw test data generated with the paper's coefficients and protocol.

    The paper's raw launch logs and CFD force tables are not public, so the demo writes launch files
    that follow its protocol (6 launches x 4 amplitudes per axis, the 30 % spring model on K = 63.6
    N/m with a 2.45 counts/mm encoder; the 22 % pendulum model on an assumed 0.30 m arm) with the
    paper's coefficients as truth, runs the same batch identification as ``udrobot-ctrl identify``
    on them, and compares. Table 7's added-mass coefficients are also recomputed from its omega_n.
    """
    base = out / "identification"
    raw = base / "raw"
    summary: dict = {"data": SYNTHETIC_NOTE}
    print(f"NOTE: {SYNTHETIC_NOTE}\n")
    wn = np.array([7.1142, 7.8268, 6.8188])  # Cely 2019 Table 7
    cm = free_decay.mass_coefficient(free_decay.added_mass_from_frequency(wn, 63.6, 0.97), 1000.0, 344_868e-9)
    print("Table 7 check: C_m = (K / omega_n^2 - m) / (rho V) from its omega_n, K = 63.6 N/m, m = 0.97 kg")
    for axis, c, ref in zip(("surge", "sway", "heave"), cm, (0.8172, 0.1945, 1.1564)):
        print(f"  {axis:6s} C_m {c:.4f}  (Table 7: {ref:.4f}, {100 * (c / ref - 1):+.1f} %)")
    summary["table7_Cm"] = cm.tolist()

    udrobot = full_size_vehicle()  # its projected areas are the default areas for C_D
    spring_truth = synthetic.paper_spring_truth()
    pend_truth = synthetic.paper_pendulum_truth()
    jobs = {
        "spring": (synthetic.write_protocol(raw / "spring", synthetic.protocol("spring", spring_truth, seed=1),
                                            "spring"),
                   RigOptions(mechanical_damping=0.5, reference_mass=9.20, vehicle=udrobot), spring_truth,
                   ("Cm", "CD", "KQ")),
        "pendulum": (synthetic.write_protocol(raw / "pendulum", synthetic.protocol("pendulum", pend_truth, seed=1),
                                              "pendulum"),
                     RigOptions(length=0.30, reference_mass=9.20, vehicle=udrobot), pend_truth, ("Cm", "KL", "KQ")),
    }
    table5 = {"surge": (1.0503, 43.2322), "sway": (0.5706, 28.7941), "heave": (0.1306, 58.5848)}
    cfd_paths = []
    for axis, (kl, kq) in table5.items():
        u, f = cfd.synthetic_table(kl, kq, noise=0.005, rng=np.random.default_rng(5))
        path = raw / "cfd" / f"cfd_{axis}.csv"
        path.parent.mkdir(parents=True, exist_ok=True)
        with open_atomic(path, "wb") as fh:
            np.savetxt(fh, np.column_stack([u, f]), delimiter=",", header="speed,force", comments="", fmt="%.6g")
        cfd_paths.append(path)
    jobs["cfd"] = (cfd_paths, RigOptions(vehicle=udrobot), None, ("KL", "KQ", "CD"))
    for kind, (paths, opts, truth, keys) in jobs.items():
        print(f"identifying {len(paths)} synthetic {kind} files ...", flush=True)
        t0 = time.perf_counter()
        rep = identify_files(kind, paths, opts, keep_fits=True)
        wall = time.perf_counter() - t0
        launches = rep.pop("_launches")
        plot_report(rep, launches, base / "plots", kind, title_note=" (SYNTHETIC data from the paper's coefficients)")
        atomic_write(base / f"{kind}_report.json", json.dumps(rep, indent=1, default=float))
        print(f"\n{kind}: {rep['n_ok']} of {rep['n_launches']} files identified, {rep['n_used']} used, "
              f"{wall:.2f} s ({'full-size CFD tables' if kind == 'cfd' else 'scaled test model'}; "
              "intervals from the synthetic noise)")
        print(f"  {'axis':6s} " + " ".join(f"{k + ' ' + COEFF_UNITS[k] + ' (95% CI)':>30s}" for k in keys)
              + "   truth (generated with)")
        for axis in rep["axes"]:
            agg = rep["by_axis"][axis]["aggregate"]
            cells = []
            for k in keys:
                a = agg.get(k) or {}
                ci = a.get("ci95") or [float("nan")] * 2
                cells.append(f"{a.get('value', float('nan')):9.4g} [{ci[0]:8.4g},{ci[1]:8.4g}]")
            tr = ""
            if truth is not None:
                tr = ", ".join(f"{k} {getattr(truth[axis], k):.4g}" for k in keys)
            else:
                tr = f"K_L {table5[axis][0]}, K_Q {table5[axis][1]} (Table 5)"
            print(f"  {axis:6s} " + " ".join(f"{c:>30s}" for c in cells) + f"   {tr}")
        if kind == "cfd":
            print("  note: Table 5 lists K_D below K_Q on every axis; a least-squares Morison fit of the same table "
                  "cannot give that when K_L > 0\n  (K_D = K_Q + K_L sum|u|^3 / sum u^4), so Table 5's C_D is not "
                  "reproducible from its own K_L, K_Q (tests/identification/test_cfd.py)")
        name = {"spring": "free_decay_identified", "pendulum": "pendulum_identified", "cfd": "cfd_identified"}[kind]
        borrowed = coefficient_set("pendulum") if kind == "cfd" else None
        per_axis, prov, desc = coefficient_set_values(rep, name, base=borrowed)
        write_coefficient_set(base / f"{name}.toml", name, per_axis, prov, desc)
        summary[kind] = {"n_files": rep["n_launches"], "n_used": rep["n_used"], "wall_s": wall,
                         "aggregate": {a: {k: (rep["by_axis"][a]["aggregate"].get(k) or {}).get("value")
                                           for k in keys} for a in rep["axes"]}}
    shipped, mine = load_model("pendulum:chin"), load_model(f"{base / 'pendulum_identified.toml'}:chin")
    print("\nidentified pendulum set vs shipped pendulum:chin (full size, reference displaced mass 9.20 kg "
          "as the paper):")
    for i, axis in enumerate(("surge", "sway", "heave")):
        print(f"  {axis:6s} M_A {mine.added_mass[i, i]:7.3f} kg (shipped {shipped.added_mass[i, i]:7.3f})   "
              f"K_L {mine.linear_damping[i, i]:6.3f} ({shipped.linear_damping[i, i]:6.3f})   "
              f"K_Q {mine.quadratic_damping[i, i]:7.3f} ({shipped.quadratic_damping[i, i]:7.3f})")
    print(f"raw files, reports, sets and plots in {base}")
    return summary


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


#: |pitch| beyond which an open-loop run is marked as diverged (deg); the same threshold as the console note.
PITCH_DIVERGED_DEG = 30.0


def divergence_index(pitch_deg) -> int | None:
    """Index of the first sample with ``|pitch| > PITCH_DIVERGED_DEG`` (deg), or None when it never diverges."""
    over = np.flatnonzero(np.abs(np.asarray(pitch_deg, float)) > PITCH_DIVERGED_DEG)
    return int(over[0]) if over.size else None


def step_open_loop(out: Path) -> dict:
    """Full forward thrust on both horizontal thrusters: top speed per model, with a plot."""

    fig = Figure(figsize=(7, 6))
    ax, ax_pitch = fig.subplots(2, 1, sharex=True)
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
        if max_pitch > PITCH_DIVERGED_DEG:
            note = (f"  <- pitch diverges ({max_pitch:.0f} deg): Munk moment (Z_wdot - X_udot) u w exceeds the "
                    f"restoring moment above {u_munk:.2f} m/s (pitch is passive in this layout)")
        print(f"{name:<20} top surge speed {u[-1]:.3f} m/s (F = K_L u + K_Q u^2 predicts {u_pred:.3f}){note}")
        (line,) = ax.plot(r.t, u, label=name)
        pitch = np.degrees(r.x[:, 4])
        ax_pitch.plot(r.t, np.clip(pitch, -PITCH_DIVERGED_DEG * 3, PITCH_DIVERGED_DEG * 3), color=line.get_color())
        k = divergence_index(pitch)
        if k is not None:
            result[name]["pitch_diverges_at_s"] = float(r.t[k])
            for a, y in ((ax, u[k]), (ax_pitch, np.sign(pitch[k]) * PITCH_DIVERGED_DEG)):
                a.plot(r.t[k], y, "X", ms=10, mec="k", color=line.get_color(), zorder=4,
                       label=f"{name}: pitch diverges" if a is ax else None)
            ax.annotate(f"{name}: |pitch| > {PITCH_DIVERGED_DEG:g} deg at {r.t[k]:.1f} s (Munk moment);\n"
                        f"its speed after this is not a top speed", (r.t[k], u[k]), xytext=(0.3, 0.5),
                        textcoords="axes fraction", fontsize=7, arrowprops={"arrowstyle": "->", "lw": 0.6},
                        bbox={"boxstyle": "round", "fc": "w", "ec": "0.6", "lw": 0.5})
    ax.set_ylabel("u (m/s)")
    ax.set_title("Full forward thrust (2 x 36.4 N): surge speed per coefficient set")
    ax.grid(True)
    ax.legend(fontsize=7)
    ax_pitch.axhline(PITCH_DIVERGED_DEG, color="0.5", lw=0.6, ls="--")
    ax_pitch.axhline(-PITCH_DIVERGED_DEG, color="0.5", lw=0.6, ls="--")
    ax_pitch.set_ylabel(f"pitch (deg, clipped at +-{3 * PITCH_DIVERGED_DEG:g})")
    ax_pitch.set_xlabel("t (s)")
    ax_pitch.set_title(f"pitch (passive in this layout); X: first |pitch| > {PITCH_DIVERGED_DEG:g} deg", fontsize=9)
    ax_pitch.grid(True)
    fig.tight_layout()
    save_figure(fig, out / "open_loop_surge.png", dpi=120)
    return result


def step_controllers(out: Path, full: bool = False, workers: int | None = None) -> dict:
    """LQR, PID, linear and nonlinear MPC designed on each model A and flown on every plant B (5 x 5), and the EKF
    with model A on data from plant B (``udrobot-ctrl compare``)."""
    print(f"{len(MODEL_NAMES)} x {len(MODEL_NAMES)} design/plant pairs, 4 controllers and the EKF "
          f"({'full 46 s' if full else 'quick 23 s'} mission) ...", flush=True)
    result = compare(quick=not full, keep_trajectories=True, workers=workers)
    write_outputs(result, out / "compare")
    atomic_write(out / "compare" / "compare.json", json.dumps(result.to_json(), indent=2))
    print(result.summary())
    return {"rows": len(result.results), "ekf_rows": len(result.ekf), "wall_s": result.wall_s}


# (file or glob relative to --out, what it is); the first entries are what to open first
INDEX = (
    ("compare/compare_missions.png", "start here: each controller flying the mission on the model it was designed "
                                     f"on (dashed: the reference). Why the MPCs move first: {MPC_PREVIEW}"),
    ("compare/compare_iae_*.png", "tracking error (IAE) of each controller designed on model A and flown on plant "
                                  "B: how much a wrong model costs"),
    ("compare/compare.txt", "the controller and EKF tables with their legend"),
    ("open_loop_surge.png", "full forward thrust: top surge speed and pitch per coefficient set; an X marks where "
                            "a model's pitch diverges (its later speed is not a top speed)"),
    ("identification/plots/*_fits.png", "identification of the SYNTHETIC launches: measurement and fitted decay"),
    ("identification/plots/*_vs_reynolds.png", "identified coefficients (95 % intervals) vs Reynolds number"),
    ("identification/plots/cfd_regressions.png", "CFD force tables (SYNTHETIC) and the Chin / Morison regressions"),
    ("compare/compare_ekf_rmse.png", "EKF built on model A filtering plant B's simulated sensors: RMSE"),
    ("identification/*_report.json", "full identification reports (every launch, intervals, outliers, tests)"),
    ("identification/*_identified.toml", "the identified coefficient sets, usable as --model FILE.toml:chin"),
    ("identification/raw/", "the SYNTHETIC raw files (launch CSVs, CFD tables): sample input for "
                            "udrobot-ctrl identify"),
    ("models/*.json", "the five models as udrobot-model/1 (docs/formats/model.md)"),
    ("compare/compare.csv", "every controller metric, one row per (controller, design, plant)"),
    ("compare/compare_ekf.csv", "the EKF metrics, one row per (filter model, plant): RMSE of z, psi, u and the mean "
                                "NIS"),
    ("compare/compare.json", "the compare report (models, results, ekf)"),
    ("compare/compare_full.json", "everything compare computed: every metric of every row, the mission, the run "
                                  "time"),
    ("demo_summary.json", "the numbers printed on screen"),
)
#: Description of a written file no :data:`INDEX` entry matches (listed all the same: the index omits nothing).
OTHER = "also written by the demo (not described above)"


def write_index(out: Path, failed=()) -> Path:
    """``out/README.md``: every file the demo wrote, what it is, what to open first; returns its path.

    Files matched by :data:`INDEX` are listed in its order with its description; a folder entry (``raw/``) covers
    everything under it; any other file in ``out`` is listed last (:data:`OTHER`), so the index names every file
    in the folder but itself.
    """
    lines = ["# udrobot-ctrl demo output", "",
             f"Written by `udrobot-ctrl demo` on {time.strftime('%Y-%m-%d %H:%M')}.", "",
             f"**Note:** {SYNTHETIC_NOTE}.", ""]
    if failed:
        lines += [f"**Failed steps:** {', '.join(failed)} (see the console output); their files are missing.", ""]
    lines += ["| file | what it is |", "|---|---|"]
    listed, folders = {out / INDEX_FILE}, []
    for pattern, what in INDEX:
        if pattern.endswith("/"):
            paths = [out / pattern] if (out / pattern).is_dir() else []
            folders += paths
        else:
            paths = [p for p in sorted(out.glob(pattern)) if p not in listed]
        if paths:
            listed.update(paths)
            rels = [p.relative_to(out).as_posix() + ("/" if p.is_dir() else "") for p in paths]
            lines.append(f"| {', '.join(f'[{r}]({r})' for r in rels)} | {what} |")
    others = [p for p in sorted(out.rglob("*")) if (p.is_file() or p.is_symlink()) and p not in listed
              and not any(f in p.parents for f in folders)]
    if others:
        rels = [p.relative_to(out).as_posix() for p in others]
        lines.append(f"| {', '.join(f'[{r}]({r})' for r in rels)} | {OTHER} |")
    path = out / INDEX_FILE
    atomic_write(path, "\n".join(lines) + "\n")  # replaces a planted link by a file, never writes through it
    return path


STEPS = [("identification", step_identification), ("models", step_models), ("open_loop", step_open_loop),
         ("controllers", step_controllers)]


def check_demo_folder(out: Path, force: bool) -> None:
    """The demo writes dozens of files under ``out``: without ``force`` it refuses a folder that holds anything.

    Raises
    ------
    OutputError
        ``out`` is not a writable folder, or (without ``force``) it exists and is not empty, naming a few of its
        entries; with ``force``, a device, pipe or socket where the demo writes its index or summary.
    """
    check_command(force=force, folders={"--out": (out, [SUMMARY_FILE, INDEX_FILE])})
    if not force and out.is_dir():
        entries = sorted(p.name for p in out.iterdir())
        if entries:
            raise OutputError(f"--out {out}: exists and is not empty ({len(entries)} entries: "
                              f"{', '.join(entries[:5])}{', ...' if len(entries) > 5 else ''}); the demo would "
                              f"replace files there: pass --force to replace the outputs of an earlier demo, or "
                              f"choose a new folder")


def _kernels_compiled(job: Background) -> None:
    """Wait for the kernels compiled beside the earlier steps (:func:`compile_kernels`); if that failed, say so and
    go on: the controllers step compiles what it needs itself (and reports its own failures)."""
    try:
        job.result()
    except Exception as exc:  # noqa: BLE001 - only a warm-up: the step itself raises what matters
        print(f"note: compiling the controllers' kernels ahead failed ({type(exc).__name__}: {exc}); "
              "the controllers step compiles them itself", flush=True)


def run(args) -> int:
    out = Path(args.out)
    check_demo_folder(out, getattr(args, "force", False))
    (out / "models").mkdir(parents=True, exist_ok=True)
    summary, failed = {}, []
    t_start = time.perf_counter()
    workers = getattr(args, "workers", None)
    # the controllers' kernels compiled once beside identification, not by every pool worker at once (first run)
    kernels = Background(compile_kernels) if workers != 1 else None
    for i, (name, fn) in enumerate(STEPS, 1):
        _banner(f"demo step {i}/{len(STEPS)}: {name}")
        t0 = time.perf_counter()
        try:
            if name == "controllers":
                if kernels is not None:
                    _kernels_compiled(kernels)
                summary[name] = fn(out, full=args.full, workers=workers)
            else:
                summary[name] = fn(out)
        except Exception as exc:  # noqa: BLE001 - the demo prints the traceback, lists the step as failed, goes on
            traceback.print_exc()
            summary[name] = {"error": f"{type(exc).__name__}: {exc}"}
            failed.append(name)
        print(f"[{name}: {time.perf_counter() - t0:.1f} s]", flush=True)
    atomic_write(out / SUMMARY_FILE, json.dumps(summary, indent=2, default=float))
    index = write_index(out, failed)
    _banner(f"demo finished in {time.perf_counter() - t_start:.0f} s"
            + (f" with failed steps: {', '.join(failed)}" if failed else ""))
    print(f"outputs in {out.resolve()}; the index {index} lists them. Open first:")
    for rel in ("compare/compare_missions.png", "compare/compare_iae_lqr.png", "compare/compare.txt"):
        if (out / rel).exists():
            print(f"  {out / rel}")
    print(f"NOTE: {SYNTHETIC_NOTE}.")
    return 1 if failed else 0
