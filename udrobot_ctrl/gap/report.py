"""The diagnosis end to end and its ``udrobot-diagnosis/1`` report (docs/formats/diagnosis.md).

:func:`diagnose` prepares the runs, locates the gap with the nominal model, fits and selects effects on the
fit runs (:mod:`udrobot_ctrl.gap.attribute`) and scores every effect, and the combination of the significant
ones, on the holdout runs only (:mod:`udrobot_ctrl.gap.shrink`).
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from udrobot_ctrl.dynamics.effects import plant_effect, wall_parameters
from udrobot_ctrl.dynamics.plant import plant_parameters, require_nominal, rotation_zyx
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap import identifiability
from udrobot_ctrl.gap.attribute import (
    BIC_STRONG,
    HOLDOUT_CHI2,
    Attributor,
    build_stack,
    finalize,
    residual,
    select,
)
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.locate import locate
from udrobot_ctrl.gap.shrink import gap, simulate_windows
from udrobot_ctrl.io.files import atomic_write
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model

FORMAT = "udrobot-diagnosis/1"


def split_runs(runs, holdout):
    """Fit and holdout runs; without holdout runs, the last run is held out (one run: its last third).

    Returns (fit, holdout, note).
    """
    if holdout:
        return list(runs), list(holdout), "holdout runs given on the command line"
    if len(runs) >= 2:
        return list(runs[:-1]), [runs[-1]], f"no --holdout: the last run ({_name(runs[-1])}) is held out"
    r = runs[0]
    cut = r.t[0] + 2.0 / 3.0 * (r.t[-1] - r.t[0])
    a, b = r.t < cut, r.t >= cut

    def part(mask, tag):
        return Run(path=f"{_name(r)}[{tag}]", t=r.t[mask], channels={c: v[mask] for c, v in r.channels.items()},
                   input_kind=r.input_kind, inputs=r.inputs[mask], extra={}, metadata=r.metadata)
    return [part(a, "first two thirds")], [part(b, "last third")], \
        f"no --holdout and one run: the first two thirds fit, the last third ({cut - r.t[0]:.1f} s on) is held out"


def _name(run):
    """File name of a run; a split part keeps its tag (``a.csv[last 1/3]``, whose '/' is not a folder)."""
    if not run.path:
        return "run"
    base, bracket, tag = run.path.partition("[")
    return Path(base).name + bracket + tag


def _clean(v):
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else round(float(v), 6)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    return v


WALL_FRACTION = 0.05


def wall_distances(params, surfaces, eta, p, speed):
    """Distance (m, body origin to surface) below which the fitted wall effect matters, per surface.

    It matters where the extra added mass along the surface normal exceeds ``WALL_FRACTION`` (5 %) of the
    vehicle's mass along that normal (n^T M n, rigid body plus added mass), or where the suction force at
    ``speed`` exceeds 5 % of the nominal surge drag at that speed (D_L u + Q u|u|). With the template's
    exp(-h / lambda) decay, the first gives h = lambda ln(a_m / (0.05 n^T M n)), the second
    h = lambda ln(a_s U^2 / (0.05 drag(U))); 0 when the effect never reaches the fraction.

    Parameters
    ----------
    params : dict
        Fitted ``decay_length_m``, ``added_mass_at_contact_kg``, ``suction_N_s2_per_m2``.
    surfaces : dict
        label -> (distances (n,), unit normal (3,) NED) of the fit stack.
    eta : (n, 6) ndarray
        Poses of the fit stack (to express the normals in the body frame).
    p : PlantParameters
    speed : float
        Reference speed along the surface, m/s (the runs' 95th percentile horizontal speed).

    Returns
    -------
    dict label -> {"added_mass_m", "suction_m", "matters_below_m"}
    """
    lam = params.get("decay_length_m", 0.0)
    am, as_ = params.get("added_mass_at_contact_kg", 0.0), params.get("suction_N_s2_per_m2", 0.0)
    drag = float(p.D_L[0, 0] * speed + p.Q[0, 0] * speed ** 2)
    R = rotation_zyx(eta[:, 3], eta[:, 4], eta[:, 5])
    out = {}
    for label, (_dist, normal) in surfaces.items():
        nb = np.einsum("nji,j->ni", R, np.asarray(normal, float))
        m_n = float(np.mean(np.einsum("ni,ij,nj->n", nb, p.M[:3, :3], nb)))
        d_am = lam * math.log(am / (WALL_FRACTION * m_n)) if am > WALL_FRACTION * m_n > 0 else 0.0
        fs = as_ * speed ** 2
        d_s = lam * math.log(fs / (WALL_FRACTION * drag)) if fs > WALL_FRACTION * drag > 0 else 0.0
        out[label] = {"added_mass_m": d_am, "suction_m": d_s, "matters_below_m": max(d_am, d_s)}
    return out


def seabed_depth(runs) -> float | None:
    """Median NED depth of the seabed (z + altitude, m) over the runs that log both; else the sidecars'
    ``seabed_depth`` (their median); else None."""
    values = []
    for r in runs:
        z, alt = r.channels.get("z"), r.channels.get("altitude")
        if z is not None and alt is not None:
            s = np.asarray(z, float) + np.asarray(alt, float)
            values.append(s[np.isfinite(s)])
    values = np.concatenate(values) if values else np.zeros(0)
    if values.size:
        return float(np.median(values))
    meta = [float(r.metadata["seabed_depth"]) for r in runs if (r.metadata or {}).get("seabed_depth") is not None]
    return float(np.median(meta)) if meta else None


def run_walls(runs) -> list:
    """The distinct walls of the runs' sidecars (``walls``: point and normal, NED), in order of appearance, of the
    runs that log x and y (the diagnosis places walls only where the position is known)."""
    out = []
    for r in runs:
        if not all(c in r.channels and np.isfinite(r.channels[c]).any() for c in ("x", "y")):
            continue
        for w in (r.metadata or {}).get("walls", []) or []:
            wall = {"point": [float(v) for v in w["point"]], "normal": [float(v) for v in w["normal"]]}
            if wall not in out:
                out.append(wall)
    return out


def corrected_model(model, report, runs=()):
    """The model plus the report's significant effects: what ``diagnose --out-model`` writes.

    Parameters
    ----------
    model : str, Path or Vehicle
        The nominal model that was diagnosed.
    report : dict
        A ``udrobot-diagnosis/1`` report.
    runs : sequence of Run
        The diagnosed runs (a significant ``wall_effect`` takes the seabed depth from their z + altitude, or their
        sidecars' ``seabed_depth``, and the walls of their sidecars).

    Returns
    -------
    vehicle : Vehicle
        With ``effects`` (each checked as a model file's entry would be) and their provenance.
    not_placed : dict
        Effect name -> reason, for significant effects the plant cannot carry: a static thrust map (deadband,
        asymmetry, inflow loss) fitted on runs that log a commanded wrench (``tau_*``) acts on the six wrench
        components, not on the model's thrusters. Each is also recorded in the provenance.

    Raises
    ------
    ValueError
        If a significant effect cannot be placed in the plant (a wall effect without a seabed or a wall).
    """
    vehicle = load_model(model)
    added, not_placed = [], {}
    wrench_runs = any(getattr(r, "input_kind", None) == "tau" for r in runs)
    for i, e in enumerate(x for x in report["effects"] if x["significant"]):
        params = dict(e["params"])
        if wrench_runs and e["name"] in ("thruster_deadband", "thruster_asymmetry", "thrust_inflow_loss"):
            not_placed[e["name"]] = ("fitted on runs that log a commanded wrench (tau_*): it acts on the six wrench "
                                     "components, which the plant's thrusters do not expose; fit it on thrust or "
                                     "pwm runs to place it")
            continue
        if e["name"] == "wall_effect":  # the planes the diagnosis saw: the seabed and the sidecar walls
            depth, walls = seabed_depth(runs), run_walls(runs)
            if depth is None and not walls:
                raise ValueError("wall_effect is significant but the runs give neither an altitude or seabed_depth "
                                 "nor walls, so the planes the corrected plant needs are unknown; add a "
                                 "seabed_depth_m (or a wall) to the effect by hand")
            if depth is not None:
                params["seabed_depth_m"] = depth
            params.update(wall_parameters(walls))
        added.append(plant_effect({"name": e["name"], "params": params}, f"report effects[{i}] ({e['name']})"))
    prov = dict(vehicle.provenance)
    for e in added:
        prov[f"effects.{e.name}"] = (f"estimated: udrobot-ctrl diagnose, fitted on {', '.join(report['fit_runs'])}, "
                                     f"scored on {', '.join(report['holdout_runs'])} (shrink "
                                     f"{next(x['shrink'] for x in report['effects'] if x['name'] == e.name):.2f})")
    for name, why in not_placed.items():
        prov[f"effects.{name}"] = f"not placed: significant in the diagnosis but {why}"
    names = "+".join(e.name for e in added)
    return vehicle.with_changes(effects=tuple(vehicle.effects) + tuple(added), provenance=prov,
                                name=f"{vehicle.name}+{names}" if added else vehicle.name), not_placed


def diagnose(model, runs, holdout=None, window_s=8.0, effects=None, log=None, model_label=None):
    """Run the whole diagnosis; returns (report dict, context dict for plots).

    Parameters
    ----------
    model : str, Path or Vehicle
        Nominal model.
    runs : list of Run
        Fit runs (positional runs of the CLI).
    holdout : list of Run, optional
        Runs used only to score.
    window_s : float
        Multiple-shooting window, s.
    effects : list of str, optional
        Catalogue subset to test (default: all).
    """
    t0 = time.perf_counter()
    say = log or (lambda s: None)
    vehicle = load_model(model)
    p = plant_parameters(vehicle)
    require_nominal(p, "the diagnoser (it fits effects on top of the plant; a model's parameter effects are "
                       "folded in, its thrust, lag and force effects are not), so diagnose the model without them")
    M_A = np.asarray(p.M_A, float)
    fit_runs, ho_runs, split_note = split_runs(runs, holdout)
    cat = fx.catalogue()
    names = list(effects or fx.EFFECT_NAMES)
    for n in names:
        if n not in cat:
            raise ValueError(f"unknown effect {n!r}; the catalogue is {', '.join(fx.EFFECT_NAMES)}")
    fit_p = [prepare(r, p, _name(r)) for r in fit_runs]
    ho_p = [prepare(r, p, _name(r)) for r in ho_runs]
    notes = [split_note] + [n for pr in fit_p + ho_p for n in pr.notes]
    say(f"prepared {len(fit_p)} fit and {len(ho_p)} holdout runs ({time.perf_counter() - t0:.1f} s)")

    # -- where: nominal multiple-shooting errors on every run (the nominal model is fitted to nothing)
    all_p = fit_p + ho_p
    nominal_sims = [simulate_windows(pr, p, (), window_s) for pr in all_p]
    g_all = gap(all_p, nominal_sims)
    location, detail = locate(all_p, nominal_sims, g_all["scale"], [residual(pr, p) for pr in all_p])

    # -- which: equation-error fits on the fit runs, holdout confirmation
    st, r, dofs = build_stack(fit_p, p, M_A)
    st_h, r_h, dofs_h = build_stack(ho_p, p, M_A)
    ident = identifiability.assess(st, r, dofs & dofs_h, fit_p, cat, names)  # what the observed channels can tell
    cat = ident.restrict(cat)
    att = Attributor(st, r, dofs, cat)
    att_h = Attributor(st_h, r_h, dofs & dofs_h, cat)
    att.dofs = dofs & dofs_h
    sel = select(att, att_h, names, log=say, exclude=ident.names)
    att_h.n_eff = max(10.0, att_h.N / max(sel["tau_int"], 1.0))
    say(f"fitted {len(names)} candidate effects; {len(sel['selected'])} pass the fit-run tests"
        + (f" ({', '.join(sel['selected'])}), to be confirmed on the holdout" if sel["selected"] else "")
        + f" ({time.perf_counter() - t0:.1f} s)")

    # -- how far: simulate the holdout runs with each effect alone and with the selected ones together
    ho_sims0 = nominal_sims[len(fit_p):]
    g_before = gap(ho_p, ho_sims0)
    scored = g_before["scored"]

    def hooks_for(fit, only=None):
        out = []
        for n in (only or fit.names):
            out.append(cat[n].hooks(fit.params[n], p, ho_p[0].B, ho_p[0].inflow, st.f_ref, M_A))
        return out

    shrink = {}
    for n in names:
        g = gap(ho_p, [simulate_windows(pr, p, hooks_for(sel["singles"][n]), window_s) for pr in ho_p], scored)
        shrink[n] = (1 - g["value"] / g_before["value"]) if g_before["value"] > 0 else 0.0
    def combo_gap(members):
        if not members:
            return g_before, ho_sims0
        sims = [simulate_windows(pr, p, hooks_for(sel["final"], members), window_s) for pr in ho_p]
        return gap(ho_p, sims, scored), sims

    # backward check on the holdout simulation: an effect whose removal changes the holdout gap by less than
    # 2% of the gap before does not explain the gap (a fit to structure the template does not describe)
    members = list(sel["selected"])
    g_after, after_sims = combo_gap(members)
    pruned, contribution = {}, {}
    for n in list(reversed(members)):
        if len(members) == 1 and shrink[n] > 0.02:
            break
        rest = [m for m in members if m != n]
        g_rest, sims_rest = combo_gap(rest)
        contrib = (g_rest["value"] - g_after["value"]) / g_before["value"] if g_before["value"] > 0 else 0.0
        contribution[n] = contrib
        if contrib < 0.02:
            pruned[n] = contrib
            members, g_after, after_sims = rest, g_rest, sims_rest
    if pruned:  # refit what remains (its parameters were shared with the dropped effects) and re-score
        sel.update(finalize(att, [m for m in sel["selected"] if m in members], names))
        g_after, after_sims = combo_gap(members)
    say(f"scored on holdout ({time.perf_counter() - t0:.1f} s)")

    sigma = sel["noise_sigma"]
    speed95 = float(np.nanpercentile(np.hypot(st.nu[:, 0], st.nu[:, 1]), 95))
    entries = []
    order = sorted(sel["selected"], key=lambda n: -shrink[n]) + sorted(
        [n for n in names if n not in sel["selected"]], key=lambda n: (n not in pruned, -shrink[n]))
    steps = {s["effect"]: s for s in sel["steps"]}
    for n in order:
        significant = n in sel["selected"]
        fit = sel["final"] if n in sel["final"].names else sel["singles"][n]
        ev = {"delta_bic": sel["delta_bic"][n]}
        if n in contribution:  # rise of the holdout gap (fraction of gap_before) when removed from the combination
            ev["holdout_gap_contribution"] = contribution[n]
        if n in pruned:
            ev["note"] = "passed the fit-run tests but does not reduce the holdout gap (< 2% of it); not significant"
        if n in steps:
            ev["selection_delta_bic"] = steps[n]["delta_bic"]
            ev["holdout_likelihood_ratio"] = steps[n]["holdout_lr"]
        entry = {"name": n, "significant": significant, "params": fit.params[n] if significant else {},
                 "shrink": shrink[n], "evidence": ev, "meaning": cat[n].meaning}
        if not significant:
            entry["fitted_params_if_added"] = sel["singles"][n].params[n]
        entry.update(ident.entry(n))
        if significant:
            alts = sel["indistinguishable"].get(n, [])
            if alts:
                entry["indistinguishable_from"] = [{"name": a, "manoeuvre": fx.discriminating_manoeuvre(n, a)}
                                                   for a in alts]
            if n == "wall_effect":
                per = wall_distances(fit.params[n], st.surfaces, st.eta, p, speed95)
                entry["matters_below_m"] = max([v["matters_below_m"] for v in per.values()], default=0.0)
                entry["matters_below"] = {
                    "criterion": f"extra added mass along the normal > {100 * WALL_FRACTION:g}% of the vehicle's "
                                 f"mass along it, or suction at {speed95:.2f} m/s (95th percentile horizontal "
                                 f"speed) > {100 * WALL_FRACTION:g}% of the nominal surge drag at that speed",
                    "distance": "from the body origin to the surface, m",
                    "per_surface": per}
        entries.append(entry)
    unexplained = (g_after["value"] / g_before["value"]) if g_before["value"] > 0 else float("nan")
    verdict = (f"significant: {len(sel['selected'])} of {len(names)} effects tested ({', '.join(sel['selected'])})"
               if sel["selected"] else
               f"no catalogue effect explains the gap significantly ({len(names)} effects tested)")
    if not scored:
        const = ", ".join(g_before.get("undefined", {})) or "none"
        verdict = (f"gap undefined: no measured channel varies above its noise (constant channels: {const}), so "
                   f"there is nothing to score; fly a manoeuvre that excites the channels")
    if sel["selected"] and unexplained > 0.5:
        verdict += f"; {100 * unexplained:.0f}% of the gap remains unexplained"
    elif not sel["selected"] and g_before["value"] > 0:
        verdict += f" (gap {g_before['value']:.3f} stays unexplained)"
    report = {
        "format": FORMAT,
        "model": model_label or (str(model) if not hasattr(model, "name") else model.name),
        "fit_runs": [pr.name for pr in fit_p],
        "holdout_runs": [pr.name for pr in ho_p],
        "gap_before": {k: g_before[k] for k in ("metric", "value", "per_channel", "undefined")} | {"scored": scored},
        "location": location,
        "effects": entries,
        "unidentifiable": ident.report(),
        "sensors": identifiability.sensors(fit_p + ho_p),
        "gap_after": {k: g_after[k] for k in ("metric", "value", "per_channel", "undefined")} | {"scored": scored},
        "unexplained": unexplained,
        "verdict": verdict,
        "location_detail": detail,
        "noise": {"tau_int_samples": sel["tau_int"], "n_eff": sel["n_eff"], "n_samples": att.N,
                  "sigma_residual_per_dof": dict(zip(fx.DOF, sigma))},
        "method": {
            "gap": f"NRMSE of multiple-shooting replays ({window_s:g} s windows from the measured state, logged "
                   f"commands held), RMS over the scored channels; channel scale = std of the measurement",
            "fit": "equation error on residual generalised forces from Savitzky-Golay velocities, "
                   "per-DOF noise variances estimated from the data",
            "significance": f"forward selection: BIC (N_eff = N / tau_int) drop > {BIC_STRONG:g} on the fit runs "
                            f"and a holdout equation-error likelihood ratio > {HOLDOUT_CHI2:g}",
            "split": split_note,
        },
        "selection_steps": sel["steps"],
        "notes": notes,
        "elapsed_s": time.perf_counter() - t0,
    }
    ctx = {"preps": all_p, "n_fit": len(fit_p), "nominal_sims": nominal_sims, "after_sims": after_sims,
           "residuals": [residual(pr, p) for pr in all_p], "location": location}
    return _clean(report), ctx


def _num(value, spec: str, undefined: str = "undefined") -> str:
    """``value`` formatted with ``spec``, or ``undefined`` for None / nan (JSON null)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return undefined
    return format(value, spec)


def summary(report) -> str:
    """Human-readable summary of a report (undefined numbers, e.g. the gap of constant channels, say so)."""
    gb, ga = report["gap_before"], report["gap_after"]
    why = gb.get("undefined") or {}
    per = [f"{c} {_num(v, '.2f')}" for c, v in gb["per_channel"].items() if c in gb["scored"]]
    per += [f"{c} undefined: channel constant" for c in why]
    lines = [f"model {report['model']}: fit {', '.join(report['fit_runs'])}; "
             f"holdout {', '.join(report['holdout_runs'])}",
             f"gap before {_num(gb['value'], '.3f', 'undefined (no channel to score)')} (NRMSE; "
             + ", ".join(per) + ")"]
    for loc in report["location"]:
        lines.append(f"  where: {loc['channel']} holds {100 * loc['share']:.0f}% -- {loc['condition']}; windows "
                     f"{loc['windows'][:3]} in {loc['run']}")
    lines.append("effects (ranked):")
    for e in report["effects"]:
        tag = "SIGNIFICANT" if e["significant"] else "-"
        extra = ""
        if e.get("indistinguishable_from"):
            extra = "; indistinguishable from " + ", ".join(a["name"] for a in e["indistinguishable_from"])
        if e.get("matters_below_m") is not None:
            extra += f"; matters below {e['matters_below_m']:.2f} m"
        lines.append(f"  {e['name']:<26s} {tag:<11s} shrink {_num(e['shrink'], '+.2f')}  "
                     f"dBIC {_num(e['evidence']['delta_bic'], '.0f')}{extra}")
        if e["significant"]:
            lines.append("      params " + ", ".join(f"{k}={_num(v, '.4g')}" for k, v in e["params"].items()))
    for u in report.get("unidentifiable", []):
        lines.append(f"  unidentifiable with these sensors: {u['name']} ({u['reason']})")
    lines.append(f"gap after {_num(ga['value'], '.3f')}; unexplained {_num(report['unexplained'], '.2f')}")
    lines.append(report["verdict"])
    return "\n".join(lines)


def write_report(report, path, protect=()) -> None:
    """Write the JSON report atomically (never over a file in ``protect``, see :mod:`udrobot_ctrl.io.files`)."""
    atomic_write(path, json.dumps(report, indent=2) + "\n", protect=protect)
