"""Run the benchmarks (and, with ``--suite``, the test commands) and write ``docs/performance.md`` from what they print.

Usage: ``PYTHONPATH=. python bench/performance_page.py [--benches demo,plant,...] [--suite] [--cold] [--out PATH]``.

Every figure on the page is one this script measured in this run, on this machine, at this commit: each bench runs
in its own process with ``--json`` and its last JSON line is tabulated as it is; the suite's wall and CPU time are
those of ``python -m pytest -q`` (and the fast lane, ``-m "not slow"``) as the README gives them. With ``--cold``
the compile caches (``UDROBOT_CACHE``, ``NUMBA_CACHE_DIR``, ``XDG_CACHE_HOME``) point at empty temporary folders,
as on a fresh machine. The page says which machine (CPU model, cores, memory), the date and the commit; nothing on
it is written by hand, so nothing on it goes stale without the date saying so.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: bench name -> (arguments after ``bench/NAME.py``, what it measures)
BENCHES = {
    "demo": ([], "the demo's steps (`udrobot-ctrl demo`): wall and CPU time of each"),
    "plant": ([], "the plant's derivative and one RK4 step: numpy, casadi, numba"),
    "sim_numba": ([], "the compiled batch simulator"),
    "identify": ([], "identification of 72 synthetic launches"),
    "control": (["--quick"], "one control step: linear MPC, NMPC, EKF, fault monitor, anchors"),
    "diagnose": (["--sensors", "stock"], "a 10-minute stock-sensor diagnosis"),
    "autopilot": ([], "the ArduSub emulation against the logs' own motor outputs (NRMSE per channel)"),
    "design": (["--models", "bluerov2-heavy"], "one `design ardusub` of one model"),
}
DEFAULT_BENCHES = ("demo", "plant", "identify", "control", "diagnose", "autopilot", "design")


@dataclass(frozen=True)
class Measured:
    """One command's figures.

    Attributes
    ----------
    name : str
        Bench name, or ``suite`` / ``fast lane``.
    command : str
        The command as run.
    wall_s, cpu_s : float
        Wall time and the CPU time of its process tree (s).
    figures : dict
        The bench's JSON line (empty for the test commands).
    status : int
        Exit status.
    summary : str
        The last line it printed (pytest's summary; a bench's last non-JSON line).
    """

    name: str
    command: str
    wall_s: float
    cpu_s: float
    figures: dict = field(default_factory=dict)
    status: int = 0
    summary: str = ""


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_command(name: str, argv: list, env: dict) -> Measured:
    """Run ``argv`` from the repository root and measure it.

    Parameters
    ----------
    name : str
        Label on the page.
    argv : list of str
        The command.
    env : dict
        Its environment.

    Returns
    -------
    Measured
    """
    cpu0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    lines = [ln for ln in proc.stdout.strip().splitlines() if ln.strip()]
    figures, summary = {}, ""
    if lines and lines[-1].lstrip().startswith("{"):
        try:
            figures = json.loads(lines[-1])
        except json.JSONDecodeError:
            figures = {}
        lines = lines[:-1]
    if lines:
        summary = lines[-1].strip()
    if proc.returncode and not summary:
        summary = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
    return Measured(name, " ".join(argv[1:] if argv[0] == sys.executable else argv), wall, cpu, figures,
                    proc.returncode, summary)


def machine() -> str:
    """CPU model, usable cores and memory of this machine, one line."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        kib = int(next(ln for ln in Path("/proc/meminfo").read_text().splitlines()
                       if ln.startswith("MemTotal")).split()[1])
        mem = f"{kib / 2**20:.0f} GiB"
    except (OSError, StopIteration, ValueError):
        mem = "memory unknown"
    return f"{model}, {cores} cores, {mem}, Python {platform.python_version()}, {platform.system()}"


def commit() -> str:
    """The checkout's commit (short hash, ``+changes`` when the tree differs from it)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
    except OSError:
        return "unknown"
    return head + ("+changes" if dirty else "") if head else "unknown"


def _flat(figures: dict, prefix: str = "") -> list:
    out = []
    for k, v in figures.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.extend(_flat(v, key + "."))
        elif isinstance(v, float):
            out.append((key, f"{v:.4g}"))
        else:
            out.append((key, str(v)))
    return out


def _sentence(text: str) -> str:
    """``text`` with its first letter upper-cased (the rest as written: names such as ArduSub keep their case)."""
    return text[:1].upper() + text[1:] + "."


def render(results: list, cold: bool, invocation: str) -> str:
    """The page (markdown); ``invocation`` is the command that wrote it."""
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    caches = "empty compile caches (a fresh machine)" if cold else "the compile caches as found (warm)"
    lines = ["# Performance", "",
             f"Written by `bench/performance_page.py` on {when}, commit `{commit()}`, with {caches}.", "",
             f"Machine: {machine()}.", "",
             "Each row is one command run once, in its own process; wall and CPU times are its process tree's. On a",
             "loaded machine compare CPU times. Regenerate this page rather than editing it:", "",
             f"    PYTHONPATH=. python bench/performance_page.py {invocation}", "",
             "| command | wall (s) | CPU (s) | exit | last line |", "|---|---|---|---|---|"]
    for m in results:
        summary = m.summary.replace("|", "\\|")[:160]
        lines.append(f"| `{m.command}` | {m.wall_s:.1f} | {m.cpu_s:.1f} | {m.status} | {summary} |")
    for m in results:
        if not m.figures:
            continue
        lines += ["", f"## `{m.command}`", "", _sentence(BENCHES.get(m.name, ("", m.name))[1]), "",
                  "| figure | value |", "|---|---|"]
        lines += [f"| `{k}` | {v} |" for k, v in _flat(m.figures)]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--benches", default=",".join(DEFAULT_BENCHES),
                    help=f"comma-separated, of {', '.join(BENCHES)} (default: %(default)s; '' for none)")
    ap.add_argument("--suite", action="store_true", help="also time the fast lane and the full test command")
    ap.add_argument("--cold", action="store_true", help="empty compile caches for every command")
    ap.add_argument("--out", default=str(ROOT / "docs" / "performance.md"))
    args = ap.parse_args(argv)
    names = [b for b in args.benches.split(",") if b]
    unknown = sorted(set(names) - set(BENCHES))
    if unknown:
        ap.error(f"unknown bench {', '.join(unknown)}: expected one of {', '.join(BENCHES)}")
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        def fresh(tag):
            e = dict(env)
            if args.cold:
                for var in ("UDROBOT_CACHE", "NUMBA_CACHE_DIR", "XDG_CACHE_HOME"):
                    e[var] = tempfile.mkdtemp(prefix=f"{tag}-{var.lower()}-", dir=scratch)
            return e
        for name in names:
            extra, _ = BENCHES[name]
            argv_b = [sys.executable, f"bench/{name}.py", *extra, "--json"]
            results.append(run_command(name, argv_b, fresh(name)))
            print(f"{name}: {results[-1].wall_s:.1f} s wall, {results[-1].cpu_s:.1f} s CPU", flush=True)
        if args.suite:
            for name, argv_t in (("fast lane", ["-m", "pytest", "-q", "-m", "not slow"]),
                                 ("suite", ["-m", "pytest", "-q"])):
                results.append(run_command(name, [sys.executable, *argv_t], fresh(name.replace(" ", "_"))))
                print(f"{name}: {results[-1].wall_s:.1f} s wall, {results[-1].cpu_s:.1f} s CPU", flush=True)
    invocation = " ".join(a for a in (f"--benches {','.join(names)}", "--suite" if args.suite else "",
                                      "--cold" if args.cold else "") if a)
    Path(args.out).write_text(render(results, args.cold, invocation), encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
