"""Batch identification: many launch files (or CFD tables) -> per-launch results, statistics, aggregate.

This is what ``udrobot-ctrl identify`` runs; it is also the API for scripts::

    from identification.identify import RigOptions, identify_files
    from udrobot_ctrl.vehicle import full_size_vehicle
    report = identify_files("spring", paths, RigOptions(stiffness=63.6, vehicle=full_size_vehicle()))

(``vehicle``: the full-size vehicle the scale-model results are referred to; this package never reads it
itself, so that it depends on nothing of ``udrobot_ctrl``, which consumes its coefficient sets.)

Steps (spring and pendulum):

1. each file is read, validated and fitted on its own; a bad file becomes ``ok: false`` with the
   reason and never stops the others; so does a physically impossible fit (negative added mass, damping
   or drag 3.29 standard errors below 0, :func:`identification.decay.physical_check`): its values are kept
   with ``impossible`` reasons, never counted as ok nor aggregated;
2. launches are labelled with their axis (``--axis`` or a ``surge|sway|heave|x|y|z`` token in the
   file name) and amplitude group (an ``L1``..``L4`` token, else the nearest protocol amplitude);
3. outliers: Tukey's far-out fences per axis on group-centred key coefficients; rejected launches
   keep their results and carry the reason (``used: false``, ``rejected``);
4. Wilcoxon rank-sum tests between groups (Tables 6, 8, 9);
5. aggregate per axis over the used launches (:func:`identification.statistics.aggregate`);
6. full-scale values by :mod:`identification.similitude`.

Rig defaults are the paper's scale models (Table 2 spring model, Table 3 pendulum model, K = 63.6
N/m) and are reported as such in ``rig``; the pendulum arm length is not in the paper and must be
given. Projected areas default to the full-size areas of ``RigOptions.vehicle`` (``udrobot-ctrl identify``:
``models/udrobot.toml``) times scale^2.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from identification import cfd, decay, free_decay, pendulum, similitude, statistics
from identification.decay import LaunchError
from identification.fossen import AXES, CoefficientSet
from identification.similitude import FullSizeVehicle

KINDS = ("spring", "pendulum", "cfd")
_AXIS_TOKENS = {"surge": "surge", "x": "surge", "sway": "sway", "y": "sway", "heave": "heave", "z": "heave"}
# key coefficients: outlier rule and pairwise tests
KEYS = {"spring": ("Cm", "CD"), "pendulum": ("Cm", "KL", "KQ"), "cfd": ()}
AGGREGATED = {"spring": ("Cm", "added_mass_kg", "CD", "KQ", "KL"),
              "pendulum": ("Cm", "added_mass_kg", "KL", "KQ", "CD"),
              "cfd": ("KL", "KQ", "KD", "CD")}
PAPER_RIG = {
    "spring": {"mass": (0.97, "Cely 2019 Table 2"), "volume": (344_868e-9, "Cely 2019 Table 2"),
               "stiffness": (63.6, "Cely 2019 sec. 3.2"), "scale": (0.30, "Cely 2019 Table 2")},
    "pendulum": {"mass": (0.146, "Cely 2019 Table 3"), "volume": (107_597e-9, "Cely 2019 Table 3"),
                 "scale": (0.22, "Cely 2019 Table 3")},
    "cfd": {"scale": (1.0, "full-size CFD model (Cely 2019 sec. 3.4)")},
}


@dataclass
class RigOptions:
    """Rig and scaling options (SI). ``None`` means the paper's value for the test (see ``PAPER_RIG``).

    Attributes
    ----------
    mass : float
        Tested model mass, kg.
    volume : float
        Tested model displaced volume, m^3.
    stiffness : float
        Spring constant, N/m (spring test).
    area : float or dict
        Projected area for C_D, m^2; one number or ``{axis: area}``.
    length : float
        Pendulum arm, pivot to model centre, m.
    gravity, rho : float
        m/s^2 and kg/m^3.
    scale : float
        Model/full-size length ratio.
    mechanical_damping : float or None
        Spring rig's own linear damping, N s/m, subtracted from the fitted linear damping to give the
        fluid K_L (and, for the graphical method, from zeta before C_D). None: unknown, taken as 0 for
        the fits, and the spring's K_L (rig + fluid) is then not written into a coefficient set.
    pivot_inertia : float
        Pendulum arm + pivot inertia about the pivot, kg m^2.
    reference_mass : str or float
        Full-size displaced mass for the added mass: ``vehicle``, ``geometric`` or kg.
    vehicle : FullSizeVehicle or None
        The full-size vehicle (projected areas, displaced volume), needed when ``area`` is None or
        ``reference_mass`` is ``vehicle``; ``udrobot-ctrl identify`` passes UDrobot's
        (:func:`udrobot_ctrl.vehicle.full_size_vehicle`).
    KL_law : str
        ``reynolds`` or ``froude`` scaling of K_L.
    axis : str or None
        Axis for every file (else read from the file names).
    provenance : dict
        Where each resolved rig value came from (filled by :func:`resolve_rig`).
    """

    mass: float | None = None
    volume: float | None = None
    stiffness: float | None = None
    area: float | dict | None = None
    length: float | None = None
    gravity: float = 9.81
    rho: float = 1000.0
    scale: float | None = None
    mechanical_damping: float | None = None
    pivot_inertia: float = 0.0
    reference_mass: str | float = "vehicle"
    KL_law: str = "reynolds"
    axis: str | None = None
    vehicle: FullSizeVehicle | None = None
    provenance: dict = field(default_factory=dict)


def axis_from_name(path) -> str | None:
    """Axis named by a ``surge|sway|heave|x|y|z`` token of the file name (None if absent or ambiguous)."""
    tokens = re.split(r"[^a-z0-9]+", Path(path).stem.lower())
    found = {_AXIS_TOKENS[t] for t in tokens if t in _AXIS_TOKENS}
    return found.pop() if len(found) == 1 else None


def group_from_name(path) -> str | None:
    """Amplitude group named by an ``L1``.. token of the file name."""
    m = re.search(r"(?:^|[^a-z0-9])l([1-9])(?:[^a-z0-9]|$)", Path(path).stem.lower())
    return f"L{m.group(1)}" if m else None


def resolve_rig(kind: str, opts: RigOptions) -> RigOptions:
    """Fill unset rig values with the paper's, recording where every value came from."""
    if kind not in KINDS:
        raise ValueError(f"unknown identification kind {kind!r} (expected {', '.join(KINDS)})")
    o = replace(opts, area=dict(opts.area) if isinstance(opts.area, dict) else opts.area, provenance={})
    prov = {}
    for name, (value, source) in PAPER_RIG[kind].items():
        if getattr(o, name) is None:
            setattr(o, name, value)
            prov[name] = f"default: {source}"
        else:
            prov[name] = "given"
    if kind == "pendulum" and o.length is None:
        raise ValueError("pendulum: --length (m, pivot to the model's centre) is required; the paper does not "
                         "state it")
    if o.area is None:
        if o.vehicle is None:
            raise ValueError("no projected area: give --area (m^2, one number or surge=..,sway=..,heave=..) or "
                             "the full-size vehicle whose areas are scaled (RigOptions.vehicle)")
        full = o.vehicle.projected_area
        o.area = {a: float(full[a]) * o.scale ** 2 for a in AXES}
        prov["area"] = (f"default: full-size projected areas of {o.vehicle.source} x scale^2 "
                        f"({o.vehicle.area_provenance})")
    else:
        prov["area"] = "given"
    for name in ("mass", "volume", "stiffness", "length", "gravity", "rho", "scale"):
        v = getattr(o, name)
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"rig option {name} must be a positive number in SI units, got {v!r}")
    o.provenance = prov
    return o


def area_for(opts: RigOptions, axis: str | None) -> float:
    """Projected area (m^2) for ``axis``."""
    if isinstance(opts.area, dict):
        if axis not in opts.area:
            raise ValueError(f"no projected area for axis {axis!r}: give --area as a number or "
                             f"surge=..,sway=..,heave=..")
        return float(opts.area[axis])
    return float(opts.area)


def _clean(d: dict) -> dict:
    return {k: v for k, v in d.items() if not k.startswith("_")}


def _one(kind, path, opts: RigOptions, fit: str, keep_fit: bool) -> dict:
    axis = opts.axis or axis_from_name(path)
    entry = {"file": str(path), "axis": axis, "ok": False, "error": None}
    try:
        if kind == "spring":
            launch = free_decay.read_spring_launch(path)
            rig = free_decay.SpringRig(opts.mass, opts.volume, opts.stiffness, area_for(opts, axis), opts.rho,
                                       opts.mechanical_damping or 0.0)
            res = free_decay.identify_launch(launch, rig, method=fit, keep_fit=keep_fit)
        elif kind == "pendulum":
            launch = pendulum.read_pendulum_launch(path)
            rig = pendulum.PendulumRig(opts.mass, opts.volume, opts.length, area_for(opts, axis), opts.rho,
                                       opts.gravity, opts.pivot_inertia)
            res = pendulum.identify_launch(launch, rig, method=fit, keep_fit=keep_fit)
        else:
            table = cfd.read_force_table(path)
            area = area_for(opts, axis) if (opts.area is not None and (axis or not isinstance(opts.area, dict))) \
                else None
            res = cfd.identify_table(table, area, opts.rho)
            if keep_fit:
                res["_table"] = table
    except LaunchError as exc:
        entry["error"] = str(exc)
        return entry
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        entry["error"] = f"{path}: {exc}"
        return entry
    entry.update(res)
    check = decay.physical_check(res)  # pendulum/spring results carry it already; CFD fits are checked here
    entry["impossible"], entry["doubtful"] = list(check.impossible), list(check.doubtful)
    if check.impossible:  # values kept for the record, never counted as ok nor aggregated
        entry["error"] = f"{path}: physically impossible: " + "; ".join(check.impossible)
        return entry
    entry["ok"] = True
    return entry


def identify_files(kind: str, paths, opts: RigOptions | None = None, fit: str = "output-error",
                   keep_fits: bool = False) -> dict:
    """Identify every file and build the report (layout of the ``--json`` output).

    Parameters
    ----------
    kind : {'spring', 'pendulum', 'cfd'}
        The test: spring free decay (Cely 2019 eqs. 6-9), pendulum free decay (eqs. 10-16) or CFD force-speed
        tables (Table 5).
    paths : sequence of path-like
        Launch CSVs (``t,y``/``t,counts``; ``t,theta``) or CFD tables (``speed,force``).
    opts : RigOptions
        Rig, area and scaling options.
    fit : {'output-error', 'graphical'}
        Launch fit method (ignored for CFD).
    keep_fits : bool
        Keep each launch's fitted curve in the report (for the plots).

    Returns
    -------
    dict
        ``method``, ``rig``, ``launches``, ``groups``, ``pairwise``, ``aggregate``, ``full_scale``.
        With a single axis ``aggregate`` and ``full_scale`` map coefficient -> {value, ci95}; with
        several they map axis -> coefficient -> {value, ci95}. ``by_axis`` always has the per-axis form.
    """
    if fit not in ("output-error", "graphical"):
        raise ValueError(f"--fit must be output-error or graphical, got {fit!r}")
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("no input files")
    opts = resolve_rig(kind, opts or RigOptions())
    launches = [_one(kind, p, opts, fit, keep_fits) for p in paths]
    levels = statistics.LEVELS.get(kind)
    ok = [e for e in launches if e["ok"]]
    for e in launches:
        e["used"] = e["ok"]
        e["rejected"] = None
        if kind != "cfd":
            amp = e.get("amplitude")
            e["group"] = group_from_name(e["file"]) or (statistics.amplitude_groups([amp], levels)[0]
                                                        if amp else None)
    axes = sorted({e["axis"] or "unspecified" for e in ok}, key=lambda a: (AXES + ("unspecified",)).index(a))
    by_axis = {}
    for axis in axes:
        rows = [e for e in ok if (e["axis"] or "unspecified") == axis]
        if kind != "cfd":
            members = {e["file"]: e for e in rows}
            groups = {e["file"]: e["group"] for e in rows}
            for f, reason in statistics.outlier_reasons(members, KEYS[kind], groups=groups).items():
                members[f]["used"] = False
                members[f]["rejected"] = reason
        used = [e for e in rows if e["used"]]
        by_axis[axis] = _axis_summary(kind, axis, rows, used, opts)
    report = {
        "format": "udrobot-identification/1",
        "method": _method_name(kind, fit),
        "rig": {f.name: getattr(opts, f.name) for f in fields(opts) if f.name not in ("provenance", "vehicle")}
        | {"provenance": opts.provenance},
        "launches": [_clean(e) for e in launches],
        "n_launches": len(launches), "n_ok": len(ok), "n_used": sum(e["used"] for e in launches),
        "axes": axes,
        "by_axis": by_axis,
    }
    if len(axes) == 1:
        report["aggregate"] = by_axis[axes[0]]["aggregate"]
        report["full_scale"] = by_axis[axes[0]]["full_scale"]
        report["pairwise"] = by_axis[axes[0]]["pairwise"]
    else:
        report["aggregate"] = {a: by_axis[a]["aggregate"] for a in axes}
        report["full_scale"] = {a: by_axis[a]["full_scale"] for a in axes}
        report["pairwise"] = {a: by_axis[a]["pairwise"] for a in axes}
    if keep_fits:
        report["_launches"] = launches
    return report


def _method_name(kind, fit):
    return {"spring": f"spring free decay (Cely 2019 eqs. 6-9), {fit} fit",
            "pendulum": f"pendulum free decay (Cely 2019 eqs. 10-16, dimensionally consistent), {fit} fit, "
                        "Chin and Morison forms",
            "cfd": "CFD force-speed regression (Cely 2019 Table 5): Chin F = K_L u + K_Q |u| u and "
                   "Morison F = 1/2 rho C_D A |u| u"}[kind]


def _axis_summary(kind, axis, rows, used, opts) -> dict:
    agg = {}
    if kind == "cfd":
        if used:
            speed = np.concatenate([e["_table"].speed if "_table" in e else _reload(e) for e in used])
            force = np.concatenate([e["_table"].force if "_table" in e else _reload(e, "force") for e in used])
            area = None
            try:
                area = area_for(opts, axis)
            except ValueError:
                pass
            pooled = cfd.identify_table(cfd.ForceTable("pooled", speed, force), area, opts.rho)
            for k in AGGREGATED["cfd"]:
                if k in pooled:
                    agg[k] = {"value": pooled[k], "ci95": pooled.get(k + "_ci95"), "n": len(used)}
            agg["r2_chin"] = pooled["r2"]
            agg["r2_morison"] = pooled["morison"]["r2"]
    else:
        for k in AGGREGATED[kind]:
            src = used
            vals = [s.get(k) for s in src]
            if not any(v is not None for v in vals):
                continue
            se = [s.get(k + "_se") for s in src]
            vals = [np.nan if v is None else v for v in vals]
            if all(s is not None for s in se):
                agg[k] = statistics.aggregate(vals, [np.nan if s is None else s for s in se])
            else:
                agg[k] = statistics.aggregate(vals)
        if kind == "pendulum":
            if "CD" in agg:
                agg["CD"]["form"] = "morison (theta'' = -a1 sin theta - a2 |theta'| theta')"
            mor = {}
            for k in ("Cm", "CD"):
                vals = [e["morison"].get(k) for e in used if "morison" in e]
                se = [e["morison"].get(k + "_se") for e in used if "morison" in e]
                if vals:
                    mor[k] = statistics.aggregate(vals, se)
            agg["morison"] = mor
        if used:
            agg["Re"] = {"min": float(min(e["Re"] for e in used)), "max": float(max(e["Re"] for e in used))}
    pairwise = {}
    if kind != "cfd":
        groups = [e["group"] for e in used]
        for k in KEYS[kind] + (("CD",) if kind == "pendulum" else ()):
            pairwise[k] = statistics.pairwise_tests([e.get(k, np.nan) for e in used], groups)
    full = {}
    if agg:
        ref, ref_desc = similitude.reference_displaced_mass(opts.reference_mass, opts.volume or 0.0, opts.scale,
                                                            opts.rho, opts.vehicle) if kind != "cfd" else (None, None)
        base = {k: v for k, v in agg.items() if isinstance(v, dict) and "value" in v}
        if kind == "cfd":
            base.pop("KD", None)
        full = similitude.full_scale(base, opts.scale, ref if ref is not None else 0.0, opts.KL_law)
        if kind == "cfd":
            full.pop("added_mass_kg", None)
        else:
            full["reference_mass"] = {"value": ref, "law": ref_desc}
    n_rej = sum(1 for e in rows if not e["used"])
    return {"aggregate": agg, "full_scale": full, "pairwise": pairwise, "n_ok": len(rows), "n_used": len(used),
            "n_rejected": n_rej}


def _reload(entry, col="speed"):
    t = cfd.read_force_table(entry["file"])
    return t.speed if col == "speed" else t.force


# ----------------------------------------------------------------------------- coefficient set
def coefficient_set_values(report: dict, name: str, base: CoefficientSet | None = None) -> tuple[dict, dict, str]:
    """Full-scale per-axis arrays and provenance for :func:`identification.sets.write_coefficient_set`.

    Axes or quantities the report lacks are taken from the coefficient set ``base`` (tagged ``assumed``;
    ``udrobot-ctrl identify --base`` loads it with :func:`udrobot_ctrl.vehicle.coefficient_set`); without
    ``base`` a missing added mass is an error (every set needs one).

    Parameters
    ----------
    report : dict
        The report of :func:`identify_files`.
    name : str
        The coefficient set's name.
    base : CoefficientSet, optional
        The set that supplies what the report lacks.

    Returns
    -------
    per_axis : dict
        Quantity (``added_mass``, ``KL``, ``KQ``, ``CD``) -> (3,) full-scale values for surge, sway, heave
        (kg, N s/m, N s^2/m^2, dimensionless), or None for a quantity not identified on any axis.
    provenance : dict
        ``AXIS.QUANTITY`` -> how the value was obtained (``measured``/``cfd``/``assumed`` with the method).
    description : str
        The set's description line.
    """
    by_axis = report["by_axis"]
    values = {"added_mass": [None] * 3, "KL": [None] * 3, "KQ": [None] * 3, "CD": [None] * 3}
    prov: dict = {}
    method = report["method"].split(",")[0]
    quantities = [("added_mass", "added_mass_kg"), ("KL", "KL"), ("KQ", "KQ"), ("CD", "CD")]
    if report["method"].startswith("spring") and report["rig"].get("mechanical_damping") is None:
        quantities.remove(("KL", "KL"))  # rig and fluid linear damping not separated
    for i, axis in enumerate(AXES):
        fs = by_axis.get(axis, {}).get("full_scale", {})
        for key, src in quantities:
            if src in fs and fs[src].get("value") is not None:
                value = float(fs[src]["value"])
                note = ""
                if value < 0:
                    ci = fs[src].get("ci95") or [value, value]
                    if ci[1] < 0:
                        raise ValueError(f"{axis} {key} = {value:.4g} (95 % CI {ci[0]:.4g}..{ci[1]:.4g}) is negative "
                                         "beyond its uncertainty: check the rig options (e.g. --mechanical-damping)")
                    note = f" (estimate {value:.3g}, 95 % CI up to {ci[1]:.3g}: zero within uncertainty, written as 0)"
                    value = 0.0
                values[key][i] = value
                tag = "cfd" if report["method"].startswith("CFD") else "measured"
                law = fs[src]["law"]
                if key == "added_mass" and "reference_mass" in fs:
                    law += f"; reference displaced mass {fs['reference_mass']['law'].split(' (')[0]}"
                prov[f"{axis}.{key}"] = f"{tag}: {method}; scaled: {law}{note}"
    missing = []
    for key, vals in values.items():
        for i, v in enumerate(vals):
            if v is not None:
                continue
            bv = _base_value(base, key, i) if base is not None else None
            if bv is not None:
                vals[i] = bv
                prov[f"{AXES[i]}.{key}"] = f"assumed: not identified here; from set {base.name!r}"
            elif key == "added_mass" or any(x is not None for x in vals):
                missing.append(f"{AXES[i]}.{key}")
    if missing:
        raise ValueError(f"cannot write a complete coefficient set: {', '.join(missing)} not identified "
                         f"(add the launches for that axis, or --base cfd|free_decay|pendulum to borrow them)")
    per_axis = {k: (np.array(v) if all(x is not None for x in v) else None) for k, v in values.items()}
    return per_axis, prov, f"identified by udrobot-ctrl identify: {report['method']}"


def _base_value(cs, key, i):
    if key == "added_mass":
        return float(cs.added_mass["default"][i])
    arr = getattr(cs, key)
    return None if arr is None else float(arr[i])


def format_table(report: dict) -> str:
    """Per-launch table and aggregate as text.

    Parameters
    ----------
    report : dict
        The report of :func:`identify_files`.

    Returns
    -------
    str
        The printed table.
    """
    kind = "cfd" if report["method"].startswith("CFD") else ("pendulum" if "pendulum" in report["method"]
                                                              else "spring")
    cols = {"spring": ("amplitude", "Re", "Cm", "CD", "KL"), "pendulum": ("amplitude_deg", "Re", "Cm", "KL", "KQ"),
            "cfd": ("KL", "KQ", "KD", "CD", "r2")}[kind]
    lines = [report["method"], ""]
    head = f"{'file':32s} {'axis':6s} {'grp':4s} " + " ".join(f"{c:>11s}" for c in cols) + "  status"
    lines.append(head)
    for e in report["launches"]:
        name = Path(e["file"]).name[-32:]
        if not e["ok"] and e.get("impossible"):
            vals = " ".join(f"{_fmt(e.get(c)):>11s}" for c in cols)
            lines.append(f"{name:32s} {str(e['axis'] or '-'):6s} {'-':4s} {vals}  REJECTED "
                         + "; ".join(e["impossible"]))
            continue
        if not e["ok"]:
            lines.append(f"{name:32s} {str(e['axis'] or '-'):6s} {'-':4s} " + " ".join(f"{'-':>11s}" for _ in cols)
                         + f"  ERROR {e['error']}")
            continue
        vals = " ".join(f"{_fmt(e.get(c)):>11s}" for c in cols)
        status = "ok" if e["used"] else f"rejected ({e['rejected']})"
        lines.append(f"{name:32s} {str(e['axis'] or '-'):6s} {str(e.get('group') or '-'):4s} {vals}  {status}")
    lines.append("")
    for axis in report["axes"]:
        s = report["by_axis"][axis]
        lines.append(f"{axis}: {s['n_used']} of {s['n_ok']} launches used ({s['n_rejected']} rejected)")
        for k, v in s["aggregate"].items():
            if isinstance(v, dict) and "value" in v and v["value"] is not None:
                ci = v.get("ci95")
                ci_s = f"  95% CI [{_fmt(ci[0])}, {_fmt(ci[1])}]" if ci else ""
                lines.append(f"  {k:14s} {_fmt(v['value']):>11s}{ci_s}")
        for k, v in s["full_scale"].items():
            if k != "reference_mass" and v.get("value") is not None:
                lines.append(f"  full size {k:9s} {_fmt(v['value']):>11s}   ({v['law']})")
        if "reference_mass" in s["full_scale"]:
            ref = s["full_scale"]["reference_mass"]
            lines.append(f"  full-size added mass uses a reference displaced mass of {ref['value']:.4g} kg "
                         f"({ref['law'].split(' (')[0]})")
    return "\n".join(lines)


def _fmt(v):
    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan"
    return f"{v:.5g}" if isinstance(v, (int, float)) else str(v)
