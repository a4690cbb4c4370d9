"""Run every command of ``docs/tutorial.md`` as printed and write what it prints into the tutorial.

The tutorial's outputs are not pasted by hand: each one sits between two markers,

    <!-- tutorial-output: KEY -->
    ```console
    $ the command, exactly as this script ran it
    what it printed (an excerpt chosen by the step, ``...`` where lines are left out)
    ```
    <!-- /tutorial-output -->

and this script (the step list :data:`STEPS`) runs the commands in a scratch folder, with the tutorial's own
scripts (the ```python blocks after ``<!-- tutorial-file: NAME -->``) written there first, and rewrites the
blocks. It also regenerates the example files it owns (:data:`EXAMPLE_FILES`, from ``examples/diagnose_tartan.py``).

    python docs/tutorial_run.py                     # run everything, rewrite docs/tutorial.md and examples/
    python docs/tutorial_run.py --check             # run everything, compare with docs/tutorial.md (exit 1 if stale)
    python docs/tutorial_run.py --groups tartan     # only the Tartan AUV walk-through (tartan, dive, design, example)
    python docs/tutorial_run.py --list              # the steps, their groups and commands

Run it from anywhere; it uses the source tree it sits in (``python -m udrobot_ctrl.cli`` as ``udrobot-ctrl``) and
the shared data in ``../shared/data`` beside the repository (``--data DIR`` to change). Exit status: 0 when every
block was written (or, with ``--check``, matches), 1 on a stale block, 2 when the data are missing.

Comparison (``--check`` and ``tests/test_tutorial.py``): run times (``(7.6 s)``, ``in 6.6 s``, ``took 49.4 s``) are
masked; every other number must agree to one unit in its last printed digit (the runs are deterministic: two runs
of every step printed identical text; the unit absorbs a rounding flip of a last digit between machines); all other
text must agree exactly.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
DATA = ROOT.parent / "shared" / "data"
TARTAN = "tartan_auv_2022-12-01"
DIVE = "guided_above_terrain/00000029_filtered.BIN"

#: Files of ``examples/`` this script regenerates (from ``examples/diagnose_tartan.py``'s run in the ``example``
#: group); written only by a full write run of that group.
EXAMPLE_FILES = ("tartan_model.json", "tartan_report.json", "tartan_report.md")

BLOCK = re.compile(r"(<!-- tutorial-output: (?P<key>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /tutorial-output -->)",
                   re.DOTALL)
FILE = re.compile(r"<!-- tutorial-file: (?P<name>[\w.-]+) -->\n```python\n(?P<code>.*?)```", re.DOTALL)
#: Run times in the outputs: masked before comparing (they vary with the machine's load).
TIMES = (re.compile(r"\((\d+\.\d+) s\)"), re.compile(r"\bin (\d+\.\d+) s\b"), re.compile(r"\btook (\d+\.\d+) s\b"))
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


@dataclass
class Step:
    """One tutorial block: its commands, the group it belongs to and how its output is excerpted.

    Parameters
    ----------
    key : str
        The block's marker key in docs/tutorial.md.
    group : str
        ``tartan``, ``dive``, ``design`` or ``example``; steps of a group run in order in one folder.
    commands : list of str
        Shell commands, run with bash in the group's folder (``cwd='repo'``: in the repository root), exactly as
        printed in the block.
    head, tail : int or None
        Keep the first ``head`` and the last ``tail`` output lines of each command (None: all), ``...`` between.
    drop : str or None
        A regular expression: runs of matching lines are reduced to their first and last line, ``...`` between.
    keep : str or None
        A regular expression: only matching lines are kept, ``...`` where others were left out.
    cwd : str
        ``work`` (the step's folder) or ``repo`` (the repository root).
    folder : str or None
        The scratch subfolder the step works in (default: its group's); ``design`` works in the dive's folder,
        on the dive's corrected model.
    drop_last : bool
        With ``drop``: keep the last line of a dropped run too (False: only its first line, then ``...``).
    """

    key: str
    group: str
    commands: list
    head: int | None = None
    tail: int | None = None
    drop: str | None = None
    keep: str | None = None
    cwd: str = "work"
    folder: str | None = None
    drop_last: bool = True


LEGEND = r"^(legend|preview|  )"

STEPS = [
    Step("tartan-convert", "tartan", [
        "for i in 0 1 2 3 4; do udrobot-ctrl convert $D/navigation_state_$i.csv --mapping tartan-auv "
        "--out run$i.csv; done"], head=2, tail=2),
    Step("tartan-firstrow", "tartan", ["head -2 run4.csv | cut -c1-110"]),
    Step("tartan-show", "tartan", ["udrobot-ctrl model show --model tartan_model.json"]),
    Step("tartan-thrusters", "tartan", ["python add_thrusters.py",
                                        "udrobot-ctrl model show --model tartan_nominal.json"],
         keep=r"^(model |  mass|  actuated|    thrusters)"),
    Step("tartan-simulate", "tartan", ["udrobot-ctrl simulate --model tartan_model.json --input run4.csv "
                                       "--out run4_sim.csv"]),
    Step("tartan-diagnose", "tartan", [
        "udrobot-ctrl diagnose --model tartan_nominal.json --json gap.json --holdout run4.csv --plot gap_plots "
        "--out-model tartan_corrected.json run0.csv run1.csv run2.csv run3.csv"], drop=r"^wrote gap_plots/"),
    Step("tartan-correct", "tartan", ["udrobot-ctrl model show --model tartan_corrected.json"],
         keep=r"^(model |  actuated|  effects|    effects\.)"),
    Step("tartan-windows", "tartan", [
        "udrobot-ctrl simulate --model tartan_nominal.json --windows 8 --input run4.csv",
        "udrobot-ctrl simulate --model tartan_corrected.json --windows 8 --input run4.csv --json run4_gap.json"]),
    Step("tartan-compare", "tartan", [
        "python drop_lag.py",
        "udrobot-ctrl compare --models tartan_nominal.json,tartan_design.json,tartan_corrected.json "
        "--controllers lqr,pid --quick --no-ekf --out compare_out"], drop=LEGEND, drop_last=False),
    Step("dive-convert", "dive", ["udrobot-ctrl convert 00000029_filtered.BIN --out dive.csv"]),
    Step("dive-notes", "dive", ["python -c \"import json; print(json.load(open('dive.json'))['notes'])\""],
         keep=r"^(vehicle:|source: (u/v/w|x/y) <-|motors:|autopilot:|cut:)"),
    Step("dive-actuation", "dive", ["python bench/actuation.py"], cwd="repo"),
    Step("dive-closed-loop", "dive", ["udrobot-ctrl simulate --closed-loop --model bluerov2-heavy --input dive.csv "
                                      "--out dive_cl.csv"]),
    Step("dive-windows", "dive", ["udrobot-ctrl simulate --model bluerov2-heavy --windows --input dive.csv"]),
    Step("dive-diagnose", "dive", [
        "udrobot-ctrl diagnose --model bluerov2-heavy --json dive_gap.json --plot dive_plots "
        "--out-model dive_model.json dive.csv"], drop=r"^wrote dive_plots/"),
    Step("design-dive", "design", folder="dive", commands=[
        "udrobot-ctrl design ardusub --model dive_model.json --from dive.csv --out dive_gains.params "
        "--report dive_design"]),
    Step("design-heavy", "design", folder="dive", commands=[
        "udrobot-ctrl design ardusub --model bluerov2-heavy --out heavy.params --report heavy_report"]),
    Step("example-tartan", "example", ["python examples/diagnose_tartan.py --out $W"], cwd="repo",
         keep=r"^(Nominal model|Mean commanded|Gap before|Significant effects)"),
]
GROUPS = ("tartan", "dive", "design", "example")
#: Groups that need another group's files: ``design`` starts from the dive's corrected model.
NEEDS = {"design": ("dive",)}
#: Groups ``tests/test_tutorial.py`` checks: the others take minutes (``design ardusub`` flies the emulated
#: autopilot on every model of the spread) and are checked by a full ``--check`` run.
FAST_GROUPS = ("tartan", "dive")


def with_needs(groups) -> list:
    """``groups`` with the groups they need (:data:`NEEDS`), in :data:`GROUPS` order."""
    wanted = set(groups) | {n for g in groups for n in NEEDS.get(g, ())}
    return [g for g in GROUPS if g in wanted]


def data_ok(data: Path, groups) -> str | None:
    """None when the shared data the groups need are present, else what is missing."""
    need = {"tartan": data / TARTAN, "example": data / TARTAN, "dive": data / DIVE, "design": data / DIVE}
    missing = [str(need[g]) for g in groups if g in need and not need[g].exists()]
    return f"shared data not found: {', '.join(sorted(set(missing)))}" if missing else None


def tutorial_files(text: str) -> dict:
    """The tutorial's scripts: ``{name: code}`` of the ```python blocks after ``<!-- tutorial-file: NAME -->``."""
    return {m["name"]: m["code"] for m in FILE.finditer(text)}


def blocks(text: str) -> dict:
    """The tutorial's generated blocks: ``{key: body}`` (the text between the markers)."""
    return {m["key"]: m["body"] for m in BLOCK.finditer(text)}


def _terminal(raw: str) -> list:
    """Output lines as a terminal shows them: a carriage return (progress bars) rewrites its line."""
    return [line.rsplit("\r", 1)[-1].rstrip() for line in raw.replace("\r\n", "\n").split("\n")]


def excerpt(lines: list, step: Step) -> list:
    """The lines of one command's output that the tutorial shows (see :class:`Step`), ``...`` where cut."""
    while lines and not lines[-1]:
        lines = lines[:-1]
    out = list(lines)
    if step.keep:
        out, gap = [], False
        for line in lines:
            if re.search(step.keep, line):
                out.append(line)
                gap = False
            elif not gap:
                out.append("...")
                gap = True
    if step.drop:
        kept, run = [], []
        for line in out + [None]:
            if line is not None and re.search(step.drop, line):
                run.append(line)
                continue
            if len(run) <= (2 if step.drop_last else 1):
                kept += run
            else:
                kept += [run[0], "...", run[-1]] if step.drop_last else [run[0], "..."]
            run = []
            if line is not None:
                kept.append(line)
        out = kept
    if step.head is not None and step.tail is not None and len(out) > step.head + step.tail + 1:
        out = out[:step.head] + ["..."] + out[-step.tail:]
    return out


def _shim(folder: Path) -> Path:
    """A folder holding ``udrobot-ctrl``: this tree's CLI through this interpreter."""
    folder.mkdir(parents=True, exist_ok=True)
    exe = folder / "udrobot-ctrl"
    exe.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m udrobot_ctrl.cli "$@"\n')
    exe.chmod(0o755)
    return folder


def _environment(work: Path, data: Path, shim: Path) -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{shim}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.update(PYTHONUNBUFFERED="1", MPLBACKEND="Agg", D=str(data / TARTAN), W=str(work / "example"),
               PYTHONHASHSEED="0", COLUMNS="120")
    env.pop("PYTHONSTARTUP", None)
    return env


def _clean(text: str, work: Path, data: Path) -> str:
    """Absolute paths of this run replaced by what the reader typed (``$D``, ``$W``, nothing)."""
    for path, name in ((work / "example", "$W"), (data / TARTAN, "$D")):
        text = text.replace(str(path), name)
    for path in (work / "tartan", work / "dive", work / "example", ROOT):
        text = text.replace(str(path) + "/", "")
    return text


def prepare(group: str, folder: Path, data: Path, text: str) -> None:
    """Put what the group's first command expects into its folder (the reader's copies and scripts)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, code in tutorial_files(text).items():
        (folder / name).write_text(code)
    if group == "tartan":
        shutil.copyfile(ROOT / "examples" / "tartan_model.json", folder / "tartan_model.json")
    if group == "dive":
        (folder / Path(DIVE).name).symlink_to(data / DIVE)


def run_steps(groups, work: Path, data: Path, text: str, log=print) -> dict:
    """Run the steps of ``groups`` in ``work`` (one subfolder per group); returns ``{key: block body}``.

    A command that exits non-zero is shown with its exit status in the block (and reported through ``log``).
    """
    shim = _shim(work / "bin")
    env = _environment(work, data, shim)
    out, started = {}, set()
    for step in STEPS:
        if step.group not in groups:
            continue
        folder = work / (step.folder or step.group)
        if folder not in started:
            prepare(folder.name, folder, data, text)
            started.add(folder)
        lines = []
        for cmd in step.commands:
            t0 = time.perf_counter()
            proc = subprocess.run(["bash", "-c", cmd], cwd=ROOT if step.cwd == "repo" else folder, env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, check=False)
            raw = proc.stdout.decode("utf-8", errors="replace")  # bytes: keep the carriage returns of progress bars
            log(f"{step.key}: {cmd[:70]}{'...' if len(cmd) > 70 else ''} ({time.perf_counter() - t0:.1f} s, "
                f"exit {proc.returncode})")
            shown = excerpt(_terminal(_clean(raw, work, data)), step)
            lines += [f"$ {cmd}", *shown]
            if proc.returncode:
                lines.append(f"(exit status {proc.returncode})")
        out[step.key] = "```console\n" + "\n".join(lines) + "\n```\n"
    return out


def _mask(text: str) -> str:
    for pattern in TIMES:
        text = pattern.sub(lambda m: m.group(0).replace(m.group(1), "<time>"), text)
    return text


def _close(a: str, b: str) -> bool:
    """Two printed numbers agree to one unit in the last printed digit of the less precise one."""
    def unit(s):
        mant = re.split(r"[eE]", s)[0]
        digits = len(mant.split(".")[1]) if "." in mant else 0
        exp = int(re.split(r"[eE]", s)[1]) if re.search(r"[eE]", s) else 0
        return 10.0 ** (exp - digits)
    return abs(float(a) - float(b)) <= max(unit(a), unit(b)) * (1 + 1e-9)


def differences(expected: str, actual: str) -> list:
    """Where two block bodies disagree (timings masked, numbers to one unit in the last digit); [] if they agree."""
    exp, act = _mask(expected).splitlines(), _mask(actual).splitlines()
    out = []
    if len(exp) != len(act):
        out.append(f"{len(exp)} lines in the tutorial, {len(act)} now")
    for n, (e, a) in enumerate(zip(exp, act), 1):
        if e == a:
            continue
        ne, na = NUMBER.findall(e), NUMBER.findall(a)
        same_text = NUMBER.sub("#", e) == NUMBER.sub("#", a)
        if same_text and len(ne) == len(na) and all(_close(x, y) for x, y in zip(ne, na)):
            continue
        out.append(f"line {n}:\n  tutorial: {e}\n  now:      {a}")
    return out


def write_blocks(text: str, new: dict) -> str:
    """``text`` with the bodies of the blocks in ``new`` replaced."""
    missing = set(new) - set(blocks(text))
    if missing:
        raise KeyError(f"docs/tutorial.md has no block for {', '.join(sorted(missing))}")
    return BLOCK.sub(lambda m: m.group(1) + new.get(m["key"], m["body"]) + m.group(4), text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="compare with docs/tutorial.md instead of writing")
    ap.add_argument("--groups", default=",".join(GROUPS), help=f"comma-separated subset of {', '.join(GROUPS)}")
    ap.add_argument("--data", type=Path, default=DATA, help="the shared data folder (default ../shared/data)")
    ap.add_argument("--work", type=Path, default=None, help="keep the scratch folder here (default: a temporary one)")
    ap.add_argument("--tutorial", type=Path, default=TUTORIAL, help="the tutorial file (default docs/tutorial.md)")
    ap.add_argument("--list", action="store_true", help="list the steps and exit")
    ap.add_argument("--show", action="store_true", help="also print the new blocks on stdout")
    args = ap.parse_args(argv)
    groups = [g.strip() for g in args.groups.split(",") if g.strip()]
    bad = sorted(set(groups) - set(GROUPS))
    if bad:
        ap.error(f"--groups: unknown {', '.join(bad)} (expected some of {', '.join(GROUPS)})")
    groups = with_needs(groups)
    if args.list:
        for step in STEPS:
            print(f"{step.key:<18} {step.group:<8} " + "\n                            ".join(step.commands))
        return 0
    missing = data_ok(args.data, groups)
    if missing:
        print(f"tutorial_run: {missing}", file=sys.stderr)
        return 2
    text = args.tutorial.read_text(encoding="utf-8")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="udrobot_tutorial_") as tmp:
        work = args.work.resolve() if args.work else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        new = run_steps(groups, work, args.data.resolve(),
                        text, log=lambda s: print(s, file=sys.stderr))
        print(f"tutorial_run: {len(new)} blocks in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        if args.show:
            print("".join(f"<!-- tutorial-output: {k} -->\n{v}<!-- /tutorial-output -->\n\n" for k, v in new.items()))
        if args.check:
            old = blocks(text)
            stale = {k: differences(old.get(k, ""), v) for k, v in new.items()}
            stale = {k: d for k, d in stale.items() if d}
            for k, d in stale.items():
                print(f"stale block {k}:\n" + "\n".join(d[:10]), file=sys.stderr)
            exact = [k for k, v in new.items() if _mask(old.get(k, "")) == _mask(v)]
            print(f"tutorial_run: {len(exact)} of {len(new)} blocks identical (run times masked), "
                  f"{len(new) - len(exact) - len(stale)} within one unit of the last digit, {len(stale)} stale",
                  file=sys.stderr)
            return 1 if stale else 0
        args.tutorial.write_text(write_blocks(text, new), encoding="utf-8")
        print(f"wrote {args.tutorial}", file=sys.stderr)
        if "example" in groups:
            for name in EXAMPLE_FILES:
                shutil.copyfile(work / "example" / name, ROOT / "examples" / name)
            print(f"wrote examples/{', examples/'.join(EXAMPLE_FILES)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
