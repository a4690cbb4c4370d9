"""``udrobot-ctrl model export|show``: write a plant as ``udrobot-model/1`` JSON, or summarise it."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from udrobot_ctrl.constants import DOF_NAMES
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.thrusters import actuated_dofs
from udrobot_ctrl.vehicle import ALL_MODEL_NAMES, load_model, write_model_file
from udrobot_files.output import check_command, spec_files


def register(subparsers):
    """Add ``model`` with sub-commands ``export`` and ``show``."""
    parser = subparsers.add_parser(
        "model", help="export or show a plant model (udrobot-model/1)",
        description="Export a model (a shipped name SET:FORM, a coefficient-set TOML as FILE.toml:FORM, or a "
                    "udrobot-model/1 JSON file) as udrobot-model/1 JSON, or print its masses, restoring forces, "
                    "added mass, damping, thrusters and which degrees of freedom the thrusters actuate. "
                    "The format is defined in docs/formats/model.md.",
        epilog="example: udrobot-ctrl model show --model pendulum:chin")
    sub = parser.add_subparsers(dest="model_command", required=True, metavar="{export,show}")
    exp = sub.add_parser(
        "export", help="write the model as udrobot-model/1 JSON (with provenance)",
        description="Write the model as udrobot-model/1 JSON: every coefficient in SI units with its provenance "
                    "(measured, cfd, estimated, assumed, derived). Other tools (and diagnose, simulate, compare) "
                    "read it back wherever a model name is accepted.",
        epilog="example: udrobot-ctrl model export --model pendulum:chin --out pendulum_chin.json")
    exp.add_argument("--model", required=True, help=f"model name ({', '.join(ALL_MODEL_NAMES)}) or model file")
    exp.add_argument("--out", required=True, help="output JSON file")
    exp.add_argument("--force", action="store_true", help="replace an existing output file")
    exp.set_defaults(func=run_export)
    show = sub.add_parser(
        "show", help="print a summary of the model",
        description="Print the model's mass, weight and buoyancy, centres of gravity and buoyancy, the diagonal "
                    "of M_total, M_A, linear (D_L) and quadratic (Q) damping per DOF, the thrusters, the actuated "
                    "and passive DOFs, the model's effects (name and parameters) and the provenance of every "
                    "number.",
        epilog="example: udrobot-ctrl model show --model demo_out/identification/pendulum_identified.toml:chin")
    show.add_argument("--model", required=True, help=f"model name ({', '.join(ALL_MODEL_NAMES)}) or model file")
    show.set_defaults(func=run_show)
    parser.set_defaults(func=run)


def run(args) -> int:
    """Dispatch (argparse sets ``func`` of the chosen sub-command, this is only a fallback)."""
    return run_show(args) if getattr(args, "model_command", None) == "show" else run_export(args)


def run_export(args) -> int:
    """Write ``args.model`` to ``args.out`` atomically; refuses to overwrite without ``--force``."""
    out = Path(args.out)
    inputs = spec_files(args.model)
    check_command({"--out": out}, inputs, force=getattr(args, "force", False))
    vehicle = load_model(args.model)
    write_model_file(vehicle, out, protect=inputs)
    print(f"wrote {out} ({vehicle.name}, udrobot-model/1)")
    return 0


def summary(vehicle) -> str:
    """Human-readable summary: masses, restoring, diagonal hydrodynamics (with the effects that change parameters
    folded in), thrusters, actuated DOFs, the ``effects`` list with its parameters, provenance."""
    p = plant_parameters(vehicle)
    lines = [f"model {vehicle.name}", f"  mass {vehicle.mass:.3f} kg, weight {vehicle.weight:.2f} N, "
             f"buoyancy {vehicle.buoyancy:.2f} N (net {vehicle.buoyancy - vehicle.weight:+.2f} N up)",
             f"  r_g {np.round(vehicle.r_g, 4).tolist()} m, r_b {np.round(vehicle.r_b, 4).tolist()} m"]
    fmt = "  {:<3}" + " {:>11}" * 4
    lines.append(fmt.format("DOF", "M_total", "M_A", "D_L", "Q"))
    for i, name in enumerate(DOF_NAMES):
        lines.append(fmt.format(name, f"{p.M[i, i]:.4g}", f"{vehicle.added_mass[i, i]:.4g}",
                                f"{p.D_L[i, i]:.4g}", f"{p.Q[i, i]:.4g}"))
    for t in vehicle.thrusters:
        lines.append(f"  thruster {t.name}: position {np.round(t.position, 4).tolist()} m, "
                     f"direction {np.round(t.direction, 4).tolist()}, "
                     f"+{t.max_forward_N:g} / -{t.max_reverse_N:g} N")
    rep = actuated_dofs(p.T)
    coupled = getattr(rep, "coupled", ())
    lines.append(f"  actuated DOFs: {', '.join(rep.actuated) or 'none'} (thruster matrix rank {rep.rank}); "
                 + (f"coupled only: {', '.join(coupled)}; " if coupled else "")
                 + f"passive: {', '.join(rep.passive) or 'none'}")
    if vehicle.effects:
        lines.append(f"  effects ({len(vehicle.effects)}, in the plant besides the coefficients above):")
        for e in vehicle.effects:
            params = ", ".join(f"{k} {v:g}" for k, v in e.params.items())
            lines.append(f"    {e.name} ({e.kind.enters}): {params or 'no parameters'}")
    else:
        lines.append("  effects: none")
    lines.append("  provenance:")
    for key, val in sorted(vehicle.provenance.items()):
        lines.append(f"    {key}: {val}")
    return "\n".join(lines)


def run_show(args) -> int:
    """Print :func:`summary` of ``args.model``."""
    print(summary(load_model(args.model)))
    return 0
