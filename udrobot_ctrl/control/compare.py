"""``udrobot-ctrl compare``: design on model A, fly on plant B, for every pair of the five models.

For every pair (design model A, plant B) the standard mission (:func:`udrobot_ctrl.control.missions.standard_mission`:
depth step 0.5 -> 1.5 m, heading 0 -> 90 deg, surge transit at 0.5 m/s and stop; ``--quick`` compresses it
to 23 s) is flown on B by each controller designed on A (``lqr``, ``pid``, ``lmpc``, ``nmpc``; see
:func:`udrobot_ctrl.control.missions.make_controller`), and scored by
:func:`udrobot_ctrl.control.metrics.mission_metrics`:
``iae`` (weighted total, s), ``overshoot`` (% of the depth step), ``settling_s`` (depth step, 2 % band; null
when it does not settle before the next manoeuvre), ``energy_J`` (estimated T-200 electrical energy),
``saturation_s`` (time with a thruster at a limit). A controller whose design fails or whose flight diverges keeps
its rows with null metrics and a recorded reason.

Estimation: for each plant B one data set is made by flying B with the LQR designed on B; the EKF
(:func:`udrobot_ctrl.control.ekf.ekf_on_trajectory`) built on model A filters B's simulated sensors (pressure
depth, IMU, DVL); reported: RMSE of z (m), psi (rad), u (m/s) and the mean NIS.

:func:`compare` returns a :class:`Comparison` (the rows, the EKF rows, the mission, the wall time):
``.to_json()`` is the ``--json`` document, ``.full_json()`` ``compare_full.json`` and ``.summary()`` the printed
tables. Each controller is designed once per design model and flown on every plant; the designs (and the EKF per
filter model) run in a ``concurrent.futures`` process pool (``--workers``), with a progress bar on a terminal.
Outputs: the ``--json`` file
holds exactly ``{"models", "results": [{design, plant, controller, iae, overshoot, settling_s, energy_J,
saturation_s}], "ekf": [{filter_model, plant, rmse: {z, psi, u}, nis_mean}]}``; ``--out DIR`` gets
``compare.csv``, ``compare_ekf.csv``, ``compare.txt`` (readable tables, with skip/failure reasons),
``compare_full.json`` (every metric) and plots (IAE matrices, mission trajectories, EKF RMSE matrix).
"""
from __future__ import annotations

import inspect
import json
import os
import textwrap
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from tqdm.auto import tqdm

from udrobot_ctrl.control.ekf import ekf_on_trajectory
from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import CONTROLLER_KINDS, make_controller, run_mission, standard_mission
from udrobot_ctrl.control.mpc import LinearMPC
from udrobot_ctrl.dynamics.sim import as_parameters
from udrobot_ctrl.vehicle import MODEL_NAMES
from udrobot_files.output import atomic_write, save_figure

#: How a design fails for a reason of the model, not of the code: reported in the row, the matrix goes on.
DESIGN_ERRORS = (ValueError, np.linalg.LinAlgError)
#: How the EKF comparison fails for a reason of the model (diverged data, broken covariance).
ESTIMATION_ERRORS = (FloatingPointError, np.linalg.LinAlgError)

RESULT_KEYS = ("design", "plant", "controller", "iae", "overshoot", "settling_s", "energy_J", "saturation_s")
DETAIL_KEYS = ("iae_z", "iae_psi", "iae_u", "overshoot_psi", "settling_psi_s", "overshoot_u", "settling_u_s",
               "max_roll_deg", "max_pitch_deg", "max_sway_mps")
EKF_STATES = ("z", "psi", "u")
EKF_UNITS = {"z": "m", "psi": "rad", "u": "m/s"}
EKF_LABELS = {"z": "depth z", "psi": "heading psi", "u": "surge speed u"}
SIM_DT = 0.01  # s, RK4 step
CONTROL_DT = 0.05  # s, controller period
EKF_DT = 0.05  # s, filter period


def _null_row(design, plant, kind, status):
    row = {k: None for k in RESULT_KEYS}
    row.update(design=design, plant=plant, controller=kind, status=status)
    return row


def _fly(ctrl, kind, design, plant, mission):
    """One flight of an already designed controller; returns (row with every metric, SimResult or None)."""

    t0 = time.perf_counter()
    reset = getattr(ctrl, "reset", None)
    if callable(reset):
        reset()  # the same design flies on every plant: forget integrators, warm starts and plans
    try:
        res = run_mission(ctrl, plant, mission, dt=SIM_DT, control_dt=CONTROL_DT)
    except FloatingPointError as exc:  # the plant diverged (controller failures are caught by SafeController)
        return _null_row(design, plant, kind, f"diverged: {exc}"), None
    p = as_parameters(plant)
    m = mission_metrics(res, mission, p.f_min, p.f_max)
    row = {"design": design, "plant": plant, "controller": kind}
    for k in RESULT_KEYS[3:] + DETAIL_KEYS:
        row[k] = m[k]
    fb = getattr(res.controller, "fallbacks", 0)
    row["status"] = "ok" if not fb else f"ok, {fb} controller fallbacks ({res.controller.last_error})"
    row["wall_s"] = time.perf_counter() - t0
    return row, res


_EKF_DATA: dict = {}


def _ekf_data(plant, mission):
    """Plant B flown by the LQR designed on B: (t, x, u), cached per process."""
    key = (plant, mission.name)
    if key not in _EKF_DATA:

        res = run_mission(make_controller("lqr", plant, mission, control_dt=CONTROL_DT), plant, mission,
                          dt=SIM_DT, control_dt=CONTROL_DT)
        _EKF_DATA[key] = (res.t, res.x, res.u)
    return _EKF_DATA[key]


def _estimate(design, plant, mission):

    try:
        t, x, u = _ekf_data(plant, mission)
        out = ekf_on_trajectory(design, t, x, u, dt=EKF_DT, seed=0)
        rmse = {s: float(out["rmse"][s]) for s in EKF_STATES}
        return {"filter_model": design, "plant": plant, "rmse": rmse, "nis_mean": float(out["nis_mean"]),
                "nis_per_dof": float(out.get("nis_per_dof", float("nan"))), "status": "ok"}
    except ESTIMATION_ERRORS as exc:  # the trajectory diverged or the filter's covariance broke down
        return {"filter_model": design, "plant": plant, "rmse": {s: None for s in EKF_STATES}, "nis_mean": None,
                "status": f"failed: {type(exc).__name__}: {exc}"}


def _decimate(res, every=5):
    """Plot-sized copy of a trajectory: (t, z, psi, u) every ``every`` samples."""
    return {"t": res.t[::every], "z": res.x[::every, 2], "psi": res.x[::every, 5], "u": res.x[::every, 6]}


def run_design(kind, design, plants, quick, keep_trajectory):
    """Design ``kind`` once on model ``design`` and fly it on every plant; worker function of the pool.

    Returns (rows, trajectories); the trajectory of the matched pair (design == plant) is kept when asked.
    """

    mission = standard_mission(quick)
    try:
        ctrl = make_controller(kind, design, mission, control_dt=CONTROL_DT)
    except FloatingPointError as exc:
        return [_null_row(design, b, kind, f"design diverged: {exc}") for b in plants], {}
    except DESIGN_ERRORS as exc:  # e.g. not stabilisable, Riccati failure: one failed design must not stop the matrix
        return [_null_row(design, b, kind, f"design failed: {type(exc).__name__}: {exc}") for b in plants], {}
    rows, trajs = [], {}
    for plant in plants:
        row, res = _fly(ctrl, kind, design, plant, mission)
        rows.append(row)
        if keep_trajectory and res is not None and plant == design:
            trajs[(kind, design, plant)] = _decimate(res)
    return rows, trajs


def run_filter(design, plants, quick):
    """The EKF built on ``design`` on the data of every plant; worker function of the pool."""
    mission = standard_mission(quick)
    return [_estimate(design, b, mission) for b in plants]


def compile_kernels(model=MODEL_NAMES[0], controllers=CONTROLLER_KINDS, ekf: bool = True) -> int:
    """Fly each of ``controllers`` designed on ``model`` on that one plant (quick mission), and the EKF on its data,
    so that every compiled kernel a :func:`compare` job uses (numba, casadi) is in the on-disk caches; the results
    are discarded.

    A :func:`compare` pool starts its workers at once, and on a machine that has not compiled them yet every worker
    compiles the same kernels at the same time. Run beside other work (the demo runs it in a
    :class:`udrobot_ctrl.parallel.Background` job during identification), this compiles them once, on an otherwise
    idle core; once compiled it costs one design flown per controller.

    Returns
    -------
    int
        The jobs flown (controllers, plus one for the EKF).
    """
    for kind in controllers:
        run_design(kind, model, [model], True, False)
    if ekf:
        run_filter(model, [model], True)
    return len(controllers) + int(ekf)


# CPU seconds of one job (a design flown on the five plants, quick mission; the EKF on five data sets), measured
# once on the development machine; only their order matters: the longest jobs start first
_JOB_COST = {"nmpc": 2.5, "lmpc": 1.7, "lqr": 0.35, "pid": 0.27, "ekf": 0.4}


@dataclass(frozen=True)
class Comparison:
    """What :func:`compare` found: every (design A, plant B, controller) flight and every (filter A, plant B) EKF run.

    Parameters
    ----------
    models : tuple of str
        The model names (or files), each a design model and a plant, in the order given.
    results : list of dict
        One row per flight, ordered by design, plant, controller: ``design``, ``plant``, ``controller``, the
        metrics of :data:`RESULT_KEYS` and :data:`DETAIL_KEYS` (:func:`~udrobot_ctrl.control.metrics.mission_metrics`:
        IAE s, overshoot %, settling s, energy J, saturation s, angles deg, speeds m/s; None when the run failed),
        ``status`` (``ok`` or why the design or flight failed) and ``wall_s`` (s) of a flight that ran.
    ekf : list of dict
        One row per (``filter_model``, ``plant``): ``rmse`` of z (m), psi (rad), u (m/s), ``nis_mean`` (-),
        ``nis_per_dof`` (-) and ``status``; None values when the filter failed.
    skipped : dict
        Name -> reason of what was not run (empty: every controller and the EKF are part of the package).
    mission_name : str
        The mission flown (:func:`~udrobot_ctrl.control.missions.standard_mission`).
    mission_t_final : float
        Its duration, s.
    wall_s : float
        Wall time of the whole comparison, s.
    trajectories : dict or None
        (controller, design, plant) -> decimated ``t``, ``z``, ``psi``, ``u`` of the matched pairs (design ==
        plant), when :func:`compare` was asked to keep them.
    """

    models: tuple[str, ...]
    results: list[dict]
    ekf: list[dict]
    skipped: dict[str, str]
    mission_name: str
    mission_t_final: float
    wall_s: float
    trajectories: dict | None = None

    def to_json(self) -> dict:
        """The ``--json`` document: exactly ``models``, ``results`` and ``ekf`` with the contract keys (NaN -> null).

        Returns
        -------
        dict
            ``{"models", "results": [{design, plant, controller, iae, overshoot, settling_s, energy_J,
            saturation_s}], "ekf": [{filter_model, plant, rmse: {z, psi, u}, nis_mean}]}`` (units as in
            :class:`Comparison`).
        """
        return _finite({"models": list(self.models),
                        "results": [{k: r.get(k) for k in RESULT_KEYS} for r in self.results],
                        "ekf": [{"filter_model": e["filter_model"], "plant": e["plant"], "rmse": dict(e["rmse"]),
                                 "nis_mean": e["nis_mean"]} for e in self.ekf]})

    def full_json(self) -> dict:
        """``compare_full.json``: every row with every metric, the skipped runs, the mission and the wall time.

        Returns
        -------
        dict
            ``{"models", "results", "ekf", "skipped", "mission": {name, t_final (s)}, "wall_s" (s)}`` (NaN -> null;
            the trajectories are left out).
        """
        mission = {"name": self.mission_name, "t_final": self.mission_t_final}
        return _finite({"models": list(self.models), "results": self.results, "ekf": self.ekf,
                        "skipped": self.skipped, "mission": mission, "wall_s": self.wall_s})

    def summary(self) -> str:
        """The printed report: the controller and EKF tables (:func:`text_table`), :data:`TABLE_LEGEND` and a
        ``skipped NAME: reason`` line per skipped run.

        Returns
        -------
        str
            The text, lines joined by newlines, no final newline.
        """
        return "\n".join([text_table(self.results, self.ekf), TABLE_LEGEND,
                          *(f"skipped {name}: {why}" for name, why in self.skipped.items())])


def _progress(total, desc):
    """A tqdm bar on stderr, silent when stderr is not a terminal."""

    return tqdm(total=total, desc=desc, unit="job", disable=None, leave=False)


def compare(models=MODEL_NAMES, controllers=CONTROLLER_KINDS, quick: bool = False, workers: int | None = None,
            keep_trajectories: bool = False, ekf: bool = True, t_final: float | None = None,
            progress: bool = True) -> Comparison:
    """Run the (design A, plant B, controller) matrix and the EKF matrix.

    Each controller is designed once per design model and flown on every plant (a design does not depend on
    the plant); the jobs (one per controller and design model, one per EKF model) run in a process pool,
    longest first.

    Parameters
    ----------
    models : sequence of str
        Model names (or files) used both as design models and as plants.
    controllers : sequence of str
        Subset of ``lqr``, ``pid``, ``lmpc``, ``nmpc``.
    quick : bool
        Short (23 s) mission instead of the full 46 s one.
    workers : int or None
        Processes of the pool (1 = run in this process; None = one per core).
    keep_trajectories : bool
        Keep decimated trajectories of the matched pairs (design == plant) for plots.
    ekf : bool
        Also run the EKF matrix.
    t_final : float, optional
        Backwards-compatible switch: a value below the full mission's 46 s selects ``quick``.
    progress : bool
        Show a progress bar on stderr (only when it is a terminal).

    Returns
    -------
    Comparison
        The rows (ordered by design, plant, controller), the EKF rows, the mission, the wall time and the
        trajectories when asked.
    """
    models = list(models)
    controllers = list(controllers)
    bad = [c for c in controllers if c not in CONTROLLER_KINDS]
    if bad:
        raise ValueError(f"unknown controllers {bad}; expected a subset of {', '.join(CONTROLLER_KINDS)}")
    if not models:
        raise ValueError("no models given")
    if t_final is not None:
        quick = t_final < standard_mission(False).t_final

    n_thr = {str(m): as_parameters(m).T.shape[1] for m in models}  # fail early, naming the model
    if len(set(n_thr.values())) > 1:
        raise ValueError("models with different thruster counts cannot be paired (a controller designed on one "
                         "commands the other's thrusters): " + ", ".join(f"{m} {k}" for m, k in n_thr.items()))
    skipped = {}  # every controller and the EKF are part of the package: nothing is skipped for being missing
    with_ekf = ekf
    t0 = time.perf_counter()
    jobs = [("ctrl", (kind, a, models, quick, keep_trajectories)) for a in models for kind in controllers]
    if with_ekf:
        jobs += [("ekf", (a, models, quick)) for a in models]
    jobs.sort(key=lambda j: -_JOB_COST.get(j[1][0] if j[0] == "ctrl" else "ekf", 1.0))
    if workers is None:
        workers = os.cpu_count() or 1
    workers = max(1, min(workers, len(jobs)))
    bar = _progress(len(jobs), "compare") if progress else None
    outs = []
    if workers <= 1:
        for tag, a in jobs:
            outs.append((tag, run_design(*a) if tag == "ctrl" else run_filter(*a)))
            if bar is not None:
                bar.update()
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
            futures = {pool.submit(run_design if tag == "ctrl" else run_filter, *a): tag for tag, a in jobs}
            for fut in as_completed(futures):
                outs.append((futures[fut], fut.result()))
                if bar is not None:
                    bar.update()
    if bar is not None:
        bar.close()
    rows, ekf_rows, trajs = [], [], {}
    for tag, out in outs:
        if tag == "ctrl":
            rows.extend(out[0])
            trajs.update(out[1])
        else:
            ekf_rows.extend(out)
    rows.sort(key=lambda r: (models.index(r["design"]), models.index(r["plant"]), controllers.index(r["controller"])))
    ekf_rows.sort(key=lambda e: (models.index(e["filter_model"]), models.index(e["plant"])))
    mission = standard_mission(quick)
    return Comparison(models=tuple(models), results=rows, ekf=ekf_rows, skipped=skipped, mission_name=mission.name,
                      mission_t_final=mission.t_final, wall_s=time.perf_counter() - t0,
                      trajectories=trajs if keep_trajectories else None)


def _finite(v):
    """JSON-safe value: non-finite floats become None (null); dicts/lists recursively."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    return v


def _preview_s() -> float:
    """How far ahead the MPCs see the mission's reference: their default horizon times the control period, s."""
    return inspect.signature(LinearMPC.__init__).parameters["horizon"].default * CONTROL_DT


#: Why the MPCs move before each reference step (printed under every table and in the demo's index).
MPC_PREVIEW = (f"lmpc and nmpc see the mission's reference {_preview_s():g} s ahead (their horizon): they start "
               f"each manoeuvre before its reference step, where the LQR and PID only react to the current error; "
               f"part of their lower IAE is this preview, which a real mission has only when its next set point "
               f"is known in advance")

TABLE_LEGEND = """\
legend (controller table): ctrl = controller (lqr: gain-scheduled LQR, pid: decoupled PID, lmpc: linear MPC,
  nmpc: nonlinear MPC); design A = model the controller was designed on; plant B = model it flew on;
  IAE s = sum over depth, heading and surge of the integral of |error| dt divided by the channel's largest
  step (1 m, 90 deg, 0.5 m/s), s;
  OS % = overshoot of the depth step, % of the step; Ts s = settling time of the depth step (2 % band), s,
  '-' = did not settle before the next manoeuvre; E kJ = estimated thruster electrical energy, kJ;
  sat s = time with a thruster at its limit, s; pitch = largest |pitch| angle, deg; '-' in any other
  column = no value (the run failed: see status).
legend (EKF table): EKF model A = model inside the filter; plant B = model that made the data; z m, psi rad,
  u m/s = RMS estimation error of depth, heading and surge speed; NIS = mean normalised innovation squared
  (about the number of measured components when the filter is consistent).
preview: """ + "\n  ".join(textwrap.wrap(MPC_PREVIEW + ".", 108))


def _f(v, fmt):
    """``v`` formatted with ``fmt``; a missing or non-finite value is ``-``, right-aligned to the same width."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        width = fmt.split(".")[0]
        return format("-", f">{width}") if width.isdigit() else "-"
    return format(v, fmt)


#: Width of the status column; a longer reason wraps at word boundaries onto indented continuation lines.
STATUS_WIDTH = 60


def _with_status(prefix: str, status: str) -> list:
    """``prefix`` + ``status``, the status wrapped (never cut) at :data:`STATUS_WIDTH` under its column."""
    parts = textwrap.wrap(status or "", STATUS_WIDTH, break_long_words=False, break_on_hyphens=False) or [""]
    return [prefix + parts[0]] + [" " * len(prefix) + part for part in parts[1:]]


def text_table(results, ekf_rows=()) -> str:
    """Readable fixed-width tables of the controller rows (and the EKF rows); see :data:`TABLE_LEGEND`.

    The status (``ok`` or the reason a design or flight failed) is printed in full: a reason longer than
    :data:`STATUS_WIDTH` characters continues on indented lines below its row, wrapped between words.
    """
    names = [r[k] for r in results for k in ("design", "plant")] + [e[k] for e in ekf_rows for k in
                                                                      ("filter_model", "plant")]
    w = max([19, *map(len, names)])
    hdr = (f"{'ctrl':<5} {'design A':<{w}} {'plant B':<{w}} {'IAE s':>7} {'OS %':>6} {'Ts s':>6} {'E kJ':>6} "
           f"{'sat s':>6} {'pitch':>6}  status")
    lines = [hdr, "-" * len(hdr)]
    for r in results:
        e = r.get("energy_J")
        lines += _with_status(f"{r['controller']:<5} {r['design']:<{w}} {r['plant']:<{w}} {_f(r.get('iae'), '7.3f')} "
                              f"{_f(r.get('overshoot'), '6.1f')} {_f(r.get('settling_s'), '6.2f')} "
                              f"{_f(None if e is None else e / 1000, '6.2f')} {_f(r.get('saturation_s'), '6.2f')} "
                              f"{_f(r.get('max_pitch_deg'), '6.1f')}  ", r.get("status", ""))
    if ekf_rows:
        h2 = f"\n{'EKF model A':<{w}} {'plant B':<{w}} {'z m':>8} {'psi rad':>8} {'u m/s':>8} {'NIS':>7}  status"
        lines += [h2, "-" * len(h2)]
        for e in ekf_rows:
            rm = e["rmse"]
            lines += _with_status(f"{e['filter_model']:<{w}} {e['plant']:<{w}} {_f(rm['z'], '8.4f')} "
                                  f"{_f(rm['psi'], '8.4f')} {_f(rm['u'], '8.4f')} {_f(e['nis_mean'], '7.2f')}  ",
                                  e.get("status", ""))
    return "\n".join(lines)


def _write_atomic(path: Path, text: str, protect=()):
    atomic_write(path, text, protect=protect)


def _csv_value(v):
    return "" if v is None else str(v).replace(",", ";")


OUTPUT_FILES = ("compare.csv", "compare_ekf.csv", "compare.txt", "compare_full.json", "compare_ekf_rmse.png",
                "compare_missions.png")


def output_names(controllers) -> list:
    """File names :func:`write_outputs` may write for these controller kinds (checked before the runs)."""
    return [*OUTPUT_FILES, *(f"compare_iae_{k}.png" for k in controllers)]


def write_outputs(result: Comparison, out: Path, protect=()) -> list:
    """CSV, text table, full JSON and plots in ``out``; returns the written paths (never over a ``protect`` file).

    Parameters
    ----------
    result : Comparison
        What :func:`compare` returned.
    out : Path
        The folder (created if missing).
    protect : sequence of Path
        Files never written over (the inputs).

    Returns
    -------
    list of Path
        The files written.
    """

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows, models = result.results, list(result.models)
    keys = ["controller", "design", "plant", *RESULT_KEYS[3:], *DETAIL_KEYS, "status"]
    files = [out / "compare.csv", out / "compare_ekf.csv", out / "compare.txt", out / "compare_full.json"]
    _write_atomic(files[0], "\n".join([",".join(keys)] + [",".join(_csv_value(r.get(k)) for k in keys)
                                                          for r in rows]) + "\n", protect)
    ek = ["filter_model", "plant", "rmse_z", "rmse_psi", "rmse_u", "nis_mean", "status"]
    _write_atomic(files[1], "\n".join([",".join(ek)] + [",".join(_csv_value(v) for v in (
        e["filter_model"], e["plant"], e["rmse"]["z"], e["rmse"]["psi"], e["rmse"]["u"], e["nis_mean"],
        e.get("status"))) for e in result.ekf]) + "\n", protect)
    skipped = "".join(f"\nskipped {k}: {v}" for k, v in result.skipped.items())
    _write_atomic(files[2], text_table(rows, result.ekf) + "\n\n" + TABLE_LEGEND + skipped + "\n", protect)
    _write_atomic(files[3], json.dumps(result.full_json(), indent=1, default=float), protect)
    n = len(models)
    short = [m.replace(":", ":\n") for m in models]
    for kind in sorted({r["controller"] for r in rows}):
        mat = np.full((n, n), np.nan)
        for r in rows:
            if r["controller"] == kind and r.get("iae") is not None:
                mat[models.index(r["design"]), models.index(r["plant"])] = r["iae"]
        fig = Figure(figsize=(6.5, 5.2))
        ax = fig.subplots()
        im = ax.imshow(mat, cmap="viridis")
        ax.set_xticks(range(n), short, fontsize=7)
        ax.set_yticks(range(n), short, fontsize=7)
        ax.set_xlabel("plant B")
        ax.set_ylabel("design model A")
        for i in range(n):
            for j in range(n):
                ax.text(j, i, "-" if np.isnan(mat[i, j]) else f"{mat[i, j]:.2f}", ha="center", va="center",
                        color="w", fontsize=8)
        fig.colorbar(im, label="IAE, weighted total (s)")
        ax.set_title(f"{kind.upper()}: IAE, designed on A, flown on B")
        fig.tight_layout()
        path = out / f"compare_iae_{kind}.png"
        save_figure(fig, path, protect=protect, dpi=110)
        files.append(path)
    if result.ekf:
        fig = Figure(figsize=(15, 4.6))
        axes = fig.subplots(1, 3)
        for ax, s in zip(axes, EKF_STATES):
            mat = np.full((n, n), np.nan)
            for e in result.ekf:
                if e["rmse"][s] is not None:
                    mat[models.index(e["filter_model"]), models.index(e["plant"])] = e["rmse"][s]
            im = ax.imshow(mat, cmap="magma")
            ax.set_xticks(range(n), short, fontsize=6)
            ax.set_yticks(range(n), short, fontsize=6)
            ax.set_title(f"EKF RMSE of {EKF_LABELS[s]}")
            ax.set_xlabel("plant B")
            ax.set_ylabel("filter model A")
            fig.colorbar(im, ax=ax, label=f"RMSE {s} ({EKF_UNITS[s]})")
        fig.tight_layout()
        path = out / "compare_ekf_rmse.png"
        save_figure(fig, path, protect=protect, dpi=110)
        files.append(path)
    trajs = result.trajectories or {}
    if trajs:
        kinds = sorted({k for k, _, _ in trajs})
        fig = Figure(figsize=(4.5 * len(kinds), 8))
        axes = fig.subplots(3, len(kinds), squeeze=False, sharex=True)
        mission = standard_mission(result.mission_name.endswith("quick"))
        for j, kind in enumerate(kinds):
            for (k, a, _b), tr in sorted(trajs.items()):
                if k != kind:
                    continue
                axes[0, j].plot(tr["t"], tr["z"], lw=1, label=a)
                axes[1, j].plot(tr["t"], np.degrees(tr["psi"]), lw=1)
                axes[2, j].plot(tr["t"], tr["u"], lw=1)
            tt = np.linspace(0, mission.t_final, 500)
            ref = mission.reference_array(tt)
            for i, (c, scale) in enumerate((("z", 1.0), ("psi", 180 / np.pi), ("u", 1.0))):
                axes[i, j].plot(tt, ref[c] * scale, "k--", lw=0.8, label="reference" if i == 0 else None)
                axes[i, j].grid(True, alpha=0.3)
            axes[0, j].set_title(f"{kind.upper()} (design = plant)")
            axes[0, j].invert_yaxis()
            axes[2, j].set_xlabel("t (s)")
        axes[0, 0].set_ylabel("depth z (m)")
        axes[1, 0].set_ylabel("heading (deg)")
        axes[2, 0].set_ylabel("surge u (m/s)")
        axes[0, 0].legend(fontsize=7, title="design = plant", title_fontsize=7)
        fig.tight_layout()
        path = out / "compare_missions.png"
        save_figure(fig, path, protect=protect, dpi=110)
        files.append(path)
    return files
