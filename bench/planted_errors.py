"""Real data with a known answer: plant a known error in the nominal model and diagnose a real log with it.

The real vehicle is what it is; what the diagnosis says of it with the unplanted nominal model is the reference.
With an error planted in the nominal model (the net buoyancy 15 N too heavy; the heave quadratic drag x3), the
same log must come back with that error on top of the reference: the buoyancy correction 15 N larger (the model
made heavier, the correction adds buoyancy), the heave drag scale corrected to ``(1 + s_ref) / 3 - 1``.

Prints, per plant: what was named, the named effects' parameters, and for the planted parameter the change against
the reference with the expected change; ``--json`` ends with one JSON line of those figures.

Usage: ``PYTHONPATH=. python bench/planted_errors.py [--log LOG | --run RUN.csv] [--model bluerov2-heavy]
[--plants buoyancy,heave_drag] --dir DIR [--json]``. The default log is the shared sea dive
(``../shared/data/guided_above_terrain/00000029_filtered.BIN``). Each diagnosis of that dive takes one to two
CPU-minutes.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from udrobot_ctrl.cli.main import main  # noqa: E402

SEA_DIVE = ROOT.parent / "shared" / "data" / "guided_above_terrain" / "00000029_filtered.BIN"
BUOYANCY_PLANT_N = -15.0  # N: the nominal buoyancy lowered by 15 N (the model 15 N too heavy)
HEAVE_DRAG_FACTOR = 3.0   # the nominal heave quadratic drag multiplied by 3


@dataclass(frozen=True)
class Plant:
    """A known error put into the nominal model file.

    Attributes
    ----------
    name : str
        Its label.
    effect : str
        The catalogue effect that stands for it.
    param : str
        That effect's parameter that measures it.
    """

    name: str
    effect: str
    param: str

    def apply(self, model: dict) -> dict:
        """The model (``udrobot-model/1`` dict) with the error planted."""
        out = json.loads(json.dumps(model))
        if self.name == "buoyancy":
            out["buoyancy"] = model["buoyancy"] + BUOYANCY_PLANT_N
        elif self.name == "heave_drag":
            out["quadratic_damping"][2][2] = model["quadratic_damping"][2][2] * HEAVE_DRAG_FACTOR
        out["name"] = f"{model['name']}+planted-{self.name}"
        return out

    def expected(self, reference: float) -> float:
        """The parameter the diagnosis should return with the error planted, given its value on the reference."""
        if self.name == "buoyancy":
            return reference - BUOYANCY_PLANT_N
        return (1.0 + reference) / HEAVE_DRAG_FACTOR - 1.0


PLANTS = {"buoyancy": Plant("buoyancy", "buoyancy_offset", "dB_N"),
          "heave_drag": Plant("heave_drag", "quadratic_damping_error", "scale_Zw|w|")}


def _quiet(argv: list) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(argv)


def diagnose(model: Path, run: Path, out: Path) -> dict:
    """The report of ``diagnose --model MODEL RUN`` (JSON dict)."""
    status = _quiet(["diagnose", "--model", str(model), "--json", str(out), "--quiet", "--force", str(run)])
    if status != 0:
        raise SystemExit(f"diagnose exited {status} on {model.name}")
    return json.loads(out.read_text())


def effect_value(report: dict, plant: Plant) -> tuple:
    """(value of the planted parameter or 0 when the effect was not fitted, whether its effect was named)."""
    e = next((e for e in report["effects"] if e["name"] == plant.effect), None)
    if e is None:
        return 0.0, False
    params = e.get("params") or e.get("fitted_params_if_added") or {}
    return float(params.get(plant.param, 0.0)), bool(e.get("significant"))


def named(report: dict) -> str:
    """The named effects with their parameters, one line."""
    parts = []
    for e in report["effects"]:
        if e.get("significant"):
            ps = ", ".join(f"{k} {v:+.3g}" for k, v in (e.get("params") or {}).items())
            parts.append(f"{e['name']} ({ps})")
    return "; ".join(parts) or "nothing"


def main_bench(argv=None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--log", default=str(SEA_DIVE), help="a field log to convert (default: the shared sea dive)")
    ap.add_argument("--run", help="an already converted udrobot-run/1 CSV (instead of --log)")
    ap.add_argument("--mapping", default="ardusub")
    ap.add_argument("--model", default="bluerov2-heavy")
    ap.add_argument("--plants", default=",".join(PLANTS))
    ap.add_argument("--dir", required=True, help="scratch folder for the run, the models and the reports")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    plants = [PLANTS[p] for p in args.plants.split(",") if p]
    if args.run:
        run = Path(args.run)
    else:
        run = d / "run.csv"
        if _quiet(["convert", args.log, "--mapping", args.mapping, "--out", str(run), "--force"]) != 0:
            raise SystemExit(f"convert failed on {args.log}")
    base = d / "nominal.json"
    _quiet(["model", "export", "--model", args.model, "--out", str(base), "--force"])
    model = json.loads(base.read_text())
    t0 = time.process_time()
    ref = diagnose(base, run, d / "reference.json")
    print(f"reference ({args.model}): named {named(ref)}  [{time.process_time() - t0:.0f} s CPU in this process]")
    figures = {}
    for plant in plants:
        path = d / f"planted_{plant.name}.json"
        path.write_text(json.dumps(plant.apply(model), indent=1))
        t0 = time.process_time()
        rep = diagnose(path, run, d / f"report_{plant.name}.json")
        ref_value, _ = effect_value(ref, plant)
        value, is_named = effect_value(rep, plant)
        want = plant.expected(ref_value)
        print(f"planted {plant.name}: named {named(rep)}")
        print(f"  {plant.effect}.{plant.param}: {value:+.4g} ({'named' if is_named else 'not named'}); reference "
              f"{ref_value:+.4g}, expected {want:+.4g}; error {value - want:+.4g}  "
              f"[{time.process_time() - t0:.0f} s CPU]")
        figures[plant.name] = {"value": value, "named": is_named, "reference": ref_value, "expected": want}
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main_bench())
