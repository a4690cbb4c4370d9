"""``udrobot-ctrl sensitivity``: which coefficient matters for my controller?

Examples::

    udrobot-ctrl sensitivity --model cfd:morison --controller lqr --method local --out sens_local
    udrobot-ctrl sensitivity --model pendulum:chin --method sobol --samples 256 --workers 2 --out sens_sobol
    udrobot-ctrl sensitivity --method sobol --samples 1024 --scheduler tls://10.0.0.5:8786 --out s --resume
    udrobot-ctrl sensitivity --method morris --samples 20 --params surge.CD,heave.CD,heave.added_mass \\
        --range surge.CD=1.2:2.6

A dask scheduler runs any code its clients send: use ``tls://`` with certificates (README, "Distributed sensitivity
studies"), never a plain ``tcp://`` scheduler reachable by others (a warning says so).

Exit status: 0 when every run of the design was evaluated without an error; 1 when some runs failed (the tables are
written, the failed runs with their error, and the last line says how many); 2 when all failed, fewer runs than the
design were evaluated, or on bad input; 130 / 143 when stopped by Ctrl-C / SIGTERM (``--resume`` continues).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from udrobot_ctrl.cli.main import CLIError
from udrobot_ctrl.control.compare import CONTROL_DT, SIM_DT
from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator
from udrobot_ctrl.sensitivity.executor import SweepExecutor, scheduler_warning
from udrobot_ctrl.sensitivity.global_ import run_monte_carlo, run_morris, run_sobol
from udrobot_ctrl.sensitivity.local import local_sensitivity
from udrobot_ctrl.sensitivity.parameters import default_space, parse_range, read_study_file
from udrobot_ctrl.sensitivity.plots import sobol_bars, tornado
from udrobot_ctrl.sensitivity.results import DESIGN_FILE, STUDY_FILE, StudyLock, StudyLockedError
from udrobot_files.output import atomic_write, check_command, spec_files

METHODS = ("local", "sobol", "morris", "montecarlo")


def register(subparsers):
    p = subparsers.add_parser("sensitivity", help="local / Sobol / Morris sensitivity of closed-loop metrics "
                              "to the hydrodynamic coefficients", description=__doc__.replace("``", ""),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="cfd:morison", help="nominal (and design) model: SET:FORM or a model file")
    p.add_argument("--controller", default="lqr", choices=("lqr", "pid", "mpc", "lmpc", "nmpc"),
                   help="controller whose closed-loop metrics are studied (default lqr; mpc = lmpc)")
    p.add_argument("--method", default="local", choices=METHODS,
                   help="local: one-at-a-time derivatives; sobol: variance shares; morris: screening; "
                        "montecarlo: metric spread (default local)")
    p.add_argument("--samples", type=int, default=None,
                   help="sobol: base sample N (power of 2; N(d+2) runs, default 256); morris: trajectories "
                        "(r(d+1) runs, default 20); montecarlo: runs (default 500); local: ignored (1 + 6d runs)")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: all CPUs; 1 = serial)")
    p.add_argument("--scheduler", default=None,
                   help="dask scheduler address (tls://HOST:PORT; TLS settings from dask's config, see README) "
                        "instead of local processes")
    p.add_argument("--out", default=None, help="study directory (tables, plots); resumable")
    p.add_argument("--resume", action="store_true", help="continue the study in --out, computing missing runs only")
    p.add_argument("--params", default=None, help="comma-separated parameters to vary (default: all)")
    p.add_argument("--range", action="append", default=[], metavar="NAME=LOW:HIGH", help="override a range")
    p.add_argument("--ranges", default=None, metavar="FILE.toml",
                   help="study file: parameters = [...] and a [ranges] table NAME = [low, high]")
    p.add_argument("--margin", type=float, default=0.10, help="widening of the min..max spread of the sets (0.10)")
    p.add_argument("--no-rotational", action="store_true", help="leave the rotational scale factors out")
    p.add_argument("--redesign", action="store_true", help="redesign the controller on every perturbed model")
    p.add_argument("--dt", type=float, default=SIM_DT, help=f"RK4 step, s ({SIM_DT}, as compare)")
    p.add_argument("--control-dt", type=float, default=CONTROL_DT,
                   help=f"controller step, s ({CONTROL_DT}, as compare)")
    p.add_argument("--full-mission", action="store_true",
                   help="the full 46 s standard mission of compare instead of the quick 23 s one (compare --quick)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the sampling (default 0)")
    p.add_argument("--rank", action="store_true", help="sobol: indices of the metrics' ranks (robust to the few "
                   "runs that lose control)")
    p.add_argument("--plot", action="store_true", help="write tornado / index plots into --out")
    p.add_argument("--top", type=int, default=5, help="parameters listed per metric (5)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _samples(args) -> int:
    return DEFAULT_SAMPLES[args.method] if args.samples is None else args.samples


def build_space(args):
    """The parameter space of the CLI arguments (model, margin, subset, user ranges)."""
    space = default_space(args.model, margin=args.margin, rotational=not args.no_rotational)
    ranges, names = {}, None
    if args.ranges:
        doc = read_study_file(args.ranges)
        ranges.update(doc["ranges"])
        names = doc["parameters"]
    for text in args.range:
        k, v = parse_range(text)
        ranges[k] = v
    if ranges:
        space = space.with_ranges(ranges)
    if args.params:
        names = [n.strip() for n in args.params.split(",") if n.strip()]
    if names:
        space = space.subset(names)
    return space


def build_evaluator(args, space):
    """compare's controller and mission (standard, quick unless ``--full-mission``) on the perturbed vehicles."""
    mission = standard_mission(quick=not args.full_mission)
    return MissionEvaluator(space, controller=args.controller, mission=mission, redesign=args.redesign,
                            sim_dt=args.dt, control_dt=args.control_dt)


DEFAULT_SAMPLES = {"sobol": 256, "morris": 20, "montecarlo": 500}


def check_samples(args) -> None:
    """``--samples`` as the method reads it: refused when not a positive count (0 never means the default); a note
    when ``--method local`` ignores it (its runs are 1 + 6 d)."""
    if args.samples is None:
        return
    if args.samples < 1:
        raise ValueError(f"--samples must be a positive number of samples, got {args.samples} (leave it out for the "
                         f"method's default: sobol 256, morris 20, montecarlo 500)")
    if args.method == "local":
        print(f"udrobot-ctrl sensitivity: note: --samples {args.samples} is not used by --method local (it always runs "
              f"1 + 6 d closed-loop runs: the nominal point and 6 per parameter)", file=sys.stderr)


def run_outcome(res, requested: int) -> tuple:
    """(exit status, message or None) of a finished study: 0 when every requested run was evaluated without an
    error; 1 with a message naming how many runs failed (and the first error) otherwise, 2 when all failed.

    Parameters
    ----------
    res : LocalResult, GlobalResult or MonteCarloResult
        The study's result; its table of runs has one ``error`` entry per evaluated sample ("" when it ran).
    requested : int
        The runs the study's design asked for.
    """
    table = res.runs if hasattr(res, "runs") else res.table
    errors = [str(e) for e in np.asarray(table.get("error", []), dtype=object) if str(e) not in ("", "nan")]
    done = len(table.get("sample_id", ()))
    if done < requested:
        return 2, f"only {done} of the {requested} requested runs were evaluated"
    if not errors:
        return 0, None
    first = errors[0] if len(errors[0]) <= 200 else errors[0][:200] + "..."
    what = (f"{len(errors)} of the {requested} runs failed (first: {first}); the indices of metrics with failed runs "
            f"are NaN, the failed runs are in the table with their error")
    if len(errors) == requested:
        return 2, f"every run failed (first: {first}): no result"
    return 1, what


def run(args) -> int:
    """Validate the arguments, then run the study holding the lock of its ``--out`` folder throughout."""
    if args.resume and not args.out:
        raise ValueError("--resume needs --out (the study directory to continue)")
    check_samples(args)
    note = scheduler_warning(args.scheduler)
    if note:
        print(f"udrobot-ctrl sensitivity: warning: {note}", file=sys.stderr)
    inputs = spec_files(args.model, args.ranges)
    if args.out:
        # the study folder is locked by StudyLock below (the same lock primitive, OUT/.lock)
        check_command(inputs=inputs, force=True, claim=False,
                      folders={"--out": (args.out, ["space.json", STUDY_FILE, DESIGN_FILE, "results.csv"])})
    space = build_space(args)
    evaluator = build_evaluator(args, space)
    if not args.out:
        return _run(args, space, evaluator, inputs)
    try:
        with StudyLock(args.out):
            if not args.resume and (Path(args.out) / "study.json").exists():
                raise ValueError(f"{args.out} already holds a study; pass --resume or choose another --out")
            return _run(args, space, evaluator, inputs)
    except StudyLockedError as exc:
        raise CLIError(str(exc)) from None


def _run(args, space, evaluator, inputs) -> int:
    progress = not args.quiet
    print(f"sensitivity: {args.method} of {args.controller} on {space.vehicle.name} ({space.form} form), "
          f"{len(space)} parameters")
    t0 = time.perf_counter()
    with warnings.catch_warnings(), SweepExecutor(workers=args.workers, scheduler=args.scheduler) as ex:
        warnings.filterwarnings("ignore", message="Sobol study:")  # printed below as "warning: ..."
        print(f"executor: {ex.describe()}")
        slow = getattr(evaluator, "runtime_effects", ())
        if slow:
            print(f"model effects simulated at run time ({', '.join(slow)}): each sample flies alone in the numpy "
                  f"simulator (the batched kernels hold the nominal equations), about 1 s of CPU per mission")
        if args.method == "local":
            res = local_sensitivity(evaluator, space, executor=ex, out=args.out, resume=args.resume,
                                    progress=progress)
        elif args.method == "sobol":
            res = run_sobol(evaluator, space, _samples(args), executor=ex, out=args.out, resume=args.resume,
                            seed=args.seed, progress=progress, transform="rank" if args.rank else None)
        elif args.method == "montecarlo":
            res = run_monte_carlo(evaluator, space, _samples(args), executor=ex, out=args.out,
                                  resume=args.resume, seed=args.seed, progress=progress)
        else:
            res = run_morris(evaluator, space, _samples(args), executor=ex, out=args.out, resume=args.resume,
                             seed=args.seed, progress=progress)
    wall = time.perf_counter() - t0
    status, problem = run_outcome(res, res.n_runs)
    print(f"{res.n_runs} closed-loop runs in {wall:.1f} s")
    print(summary_text(res, args.method, args.top))
    for note in getattr(res, "warnings", []):
        print(f"warning: {note}", file=sys.stderr)
    if args.out:
        out = Path(args.out)
        atomic_write(out / "space.json", json.dumps(space.to_records(), indent=2), protect=inputs)
        if args.plot and args.method != "montecarlo":
            write_plots(res, args.method, out)
        print(f"tables in {out.resolve()}")
    if problem:
        sys.stdout.flush()
        print(f"udrobot-ctrl sensitivity: {'error' if status == 2 else 'warning'}: study not run as asked: {problem}"
              f" (exit status {status})", file=sys.stderr)
    return status


#: metrics of udrobot_ctrl.control.metrics (compare's) listed first and plotted
KEY_METRICS = ("iae", "iae_z", "iae_psi", "iae_u", "overshoot_z", "settling_z_s", "settling_psi_s", "final_error_u",
               "energy_J", "saturation_s", "max_pitch_deg", "max_speed", "lost_control", "unsettled")


def summary_text(res, method: str, top: int = 5) -> str:
    """Most influential parameters per metric, as text."""
    lines = ["  (indices say what drives the variance; the sd says whether that variance matters)"] \
        if method == "sobol" else []
    if method == "montecarlo":
        for m, s in res.summary.items():
            lines.append(f"  {m:<18} mean {s['mean']:.4g}  p5 {s['p5']:.4g}  p50 {s['p50']:.4g}  p95 {s['p95']:.4g}"
                         + (f"  [{s['failed']} failed]" if s["failed"] else ""))
        return "\n".join(lines)
    metrics = [m for m in KEY_METRICS if m in res.metrics] + [m for m in res.metrics if m not in KEY_METRICS]
    for m in metrics:
        names = res.ranking(m)[:top]
        if method == "local":
            eff = dict(zip(res.names, res.range_effect(m)))
            items = ", ".join(f"{n} {eff[n]:+.3g}" for n in names)
            lines.append(f"  {m:<18} nominal {res.base[m]:.4g}; swing over range: {items}")
        elif method == "sobol":
            st = dict(zip(res.names, res.indices[m]["ST"]))
            ci = dict(zip(res.names, res.indices[m]["ST_conf"]))
            items = ", ".join(f"{n} ST {st[n]:.2f}+-{ci[n]:.2f}" for n in names)
            y = np.asarray(res.table[m], float)
            spread = f"sd {np.nanstd(y):.3g} (p5..p95 {np.nanpercentile(y, 5):.3g}..{np.nanpercentile(y, 95):.3g})"
            lines.append(f"  {m:<18} {spread}: {items}"
                         + (f"  [{res.failed[m]} failed runs]" if res.failed.get(m) else ""))
        else:
            mu = dict(zip(res.names, res.indices[m]["mu_star"]))
            ci = dict(zip(res.names, res.indices[m]["mu_star_conf"]))
            items = ", ".join(f"{n} mu* {mu[n]:.3g}+-{ci[n]:.2g}" for n in names)
            lines.append(f"  {m:<18} {items}")
    return "\n".join(lines)


def write_plots(res, method: str, out: Path) -> list:
    import matplotlib.pyplot as plt

    paths = []
    for m in [k for k in KEY_METRICS if k in res.metrics]:
        path = out / f"{method}_{m}.png"
        fig = tornado(res, m, path=path) if method == "local" else sobol_bars(res, m, path=path)
        plt.close(fig)
        paths.append(path)
    return paths
