"""Issue 62: one output check for every command (never an input, never two outputs on one file, report folders
included), outputs claimed against a concurrent run, and a full disk or a size limit as one line naming the file."""
from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import textwrap
import time

import pytest

from tests.udrobot_ctrl.cli.test_output_policy import _run, _snapshot, _tlog
from udrobot_ctrl.cli import main
from udrobot_ctrl.sensitivity.results import StudyLock, StudyLockedError
from udrobot_files import caches, locks

PYTHON = sys.executable


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    """The claims in a cache folder of this test (outside the folder whose bytes the tests compare)."""
    home = tmp_path_factory.mktemp("xdg")
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.setattr(caches, "_FALLBACKS", {})
    return home


def _refused(argv, tmp_path, capsys, *words):
    """Exit 2, one line naming every word, every byte under ``tmp_path`` as before; returns the line."""
    capsys.readouterr()
    before = _snapshot(tmp_path)
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err
    assert _snapshot(tmp_path) == before
    return err


@pytest.fixture
def model(tmp_path):
    path = tmp_path / "heavy.json"
    assert main(["model", "export", "--model", "bluerov2-heavy", "--out", str(path)]) == 0
    return path


DESIGN = ["design", "ardusub", "--evaluations", "1", "--no-sensitivity"]


@pytest.mark.parametrize("force", [False, True])
def test_design_never_writes_over_its_model_or_a_spread_model(tmp_path, capsys, model, force):
    flag = ["--force"] if force else []
    spread = tmp_path / "spread.json"
    assert main(["model", "export", "--model", "bluerov2-heavy", "--out", str(spread)]) == 0
    for argv in (["--model", model, "--out", model],
                 ["--model", "bluerov2-heavy", "--spread", spread, "--out", spread]):
        err = _refused(DESIGN + argv + flag, tmp_path, capsys, "refusing to overwrite input data", str(argv[-1]))
        assert "pass --force" not in err  # the flag that would destroy the input is never advised
    # --report DIR whose design.json is the model file
    inside = tmp_path / "rep"
    inside.mkdir()
    report_model = inside / "design.json"
    report_model.write_bytes(model.read_bytes())
    err = _refused(DESIGN + ["--model", report_model, "--out", tmp_path / "g.params", "--report", inside] + flag,
                   tmp_path, capsys, "--report", "design.json", "refusing to overwrite input data")
    assert "pass --force" not in err


@pytest.mark.parametrize("force", [False, True])
def test_design_out_inside_its_report_folder_on_a_report_file_is_refused(tmp_path, capsys, force):
    rep = tmp_path / "rep"
    _refused(DESIGN + ["--model", "bluerov2", "--out", rep / "design.json", "--report", rep]
             + (["--force"] if force else []), tmp_path, capsys, "name the same file", "design.json")
    assert not rep.exists()


def _hold_claim(path, ready):
    """A process that claims ``path`` as another udrobot-ctrl run would, until killed."""
    code = textwrap.dedent(f"""
        import pathlib, time
        from udrobot_files.locks import claim_outputs
        claim_outputs([{str(path)!r}], ["--json"])
        pathlib.Path({str(ready)!r}).write_text("held")
        time.sleep(120)
    """)
    proc = subprocess.Popen([PYTHON, "-c", code], env=os.environ.copy())
    deadline = time.monotonic() + 60
    while not ready.exists():
        assert proc.poll() is None and time.monotonic() < deadline, "the claiming process did not start"
        time.sleep(0.05)
    return proc


@pytest.mark.parametrize("spelling", ["same", "symlinked_folder"])
def test_a_second_diagnose_on_a_claimed_report_is_refused(tmp_path, capsys, spelling):
    run = _run(tmp_path / "run.csv", n=80)
    report = tmp_path / "gap.json"
    proc = _hold_claim(report, tmp_path.parent / f"{tmp_path.name}_ready")
    try:
        target = report
        if spelling == "symlinked_folder":
            link = tmp_path / "alias"
            link.symlink_to(tmp_path, target_is_directory=True)
            target = link / "gap.json"
        _refused(["diagnose", "--model", "cfd:chin", "--json", target, "--force", run], tmp_path, capsys,
                 "in use by another udrobot-ctrl run", f"pid {proc.pid}", "gap.json")
    finally:
        proc.kill()
        proc.wait()
    assert not report.exists()


def test_an_output_claim_ends_with_the_command(tmp_path, private_cache):
    out = tmp_path / "m.json"
    assert main(["model", "export", "--model", "cfd:chin", "--out", str(out)]) == 0
    assert locks._CLAIMS == {}
    code = f"from udrobot_files.locks import claim_outputs; claim_outputs([{str(out)!r}])"
    done = subprocess.run([PYTHON, "-c", code], env=os.environ.copy(), capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert not list((private_cache / "udrobot_ctrl" / "locks").iterdir())  # no lock file left by either


def test_a_planted_study_lock_link_is_refused_not_followed(tmp_path):
    out = tmp_path / "study"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (out / ".lock").symlink_to(victim)
    with pytest.raises(StudyLockedError, match=r"\.lock is a symbolic link"):
        StudyLock(out).acquire()
    assert victim.read_text() == "keep"
    os.mkfifo(out / "fifo")
    (out / ".lock").unlink()
    os.rename(out / "fifo", out / ".lock")
    with pytest.raises(StudyLockedError, match="not a regular file"):
        StudyLock(out).acquire()


LIMITED = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
from udrobot_ctrl.cli import main
sys.exit(main({argv!r}))
"""


def _size_limited(argv, limit):
    """Run the CLI in a process whose files may not grow past ``limit`` bytes (``ulimit -f``)."""
    code = LIMITED.format(limit=limit, argv=[str(a) for a in argv])
    return subprocess.run([PYTHON, "-c", code], env=os.environ.copy(), capture_output=True, text=True, timeout=300)


def _one_line_naming(done, path):
    assert done.returncode == 2, (done.returncode, done.stderr)
    lines = [line for line in done.stderr.strip().splitlines() if ": error: " in line]
    assert "Traceback" not in done.stderr and len(lines) == 1, done.stderr  # (warnings of the run may precede it)
    assert str(path) in lines[0] and "EFBIG" in lines[0] and "cannot be written" in lines[0], lines[0]


def test_a_size_limit_in_simulate_convert_and_model_export_is_one_line(tmp_path):
    run = _run(tmp_path / "run.csv", n=400)
    log = _tlog(tmp_path / "dive.tlog")
    before = _snapshot(tmp_path)
    sim = tmp_path / "sim.csv"
    _one_line_naming(_size_limited(["simulate", "--model", "cfd:chin", "--input", run, "--out", sim], 4096), sim)
    conv = tmp_path / "dive.csv"
    _one_line_naming(_size_limited(["convert", log, "--mapping", "ardusub", "--allow-missing-inputs", "--out", conv],
                                   2048), conv)
    model = tmp_path / "m.json"
    _one_line_naming(_size_limited(["model", "export", "--model", "cfd:chin", "--out", model], 1024), model)
    assert _snapshot(tmp_path) == before  # no partial file, no temporary file, no sidecar without its run
    assert sorted(tmp_path.iterdir()) == sorted(before)


def test_a_full_disk_while_diagnosing_is_one_line_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    run = _run(tmp_path / "run.csv", n=200)
    report = tmp_path / "gap.json"
    real_fsync = os.fsync

    def full_disk(fd):  # the device fills up while the report is written
        if "gap.json" in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", full_disk)
    err = _refused(["diagnose", "--model", "cfd:chin", "--json", report, "--quiet", run], tmp_path, capsys,
                   str(report), "no space left on the device (ENOSPC)", "no partial file")
    assert err.startswith("udrobot-ctrl diagnose: error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.json"]


@pytest.mark.slow
def test_a_size_limit_in_designs_report_is_one_line(tmp_path):
    """design ardusub --report under ulimit -f: one line naming the report file, no partial file (a design flight
    takes tens of seconds, hence slow)."""
    report = tmp_path / "rep"
    done = _size_limited(["design", "ardusub", "--model", "bluerov2", "--loops", "depth", "--evaluations", "1",
                          "--no-sensitivity", "--report", report, "--out", tmp_path / "g.params"], 4096)
    _one_line_naming(done, report / "design.json")
    assert not list(report.glob("*")) if report.exists() else True  # neither the file nor its temporary


@pytest.mark.slow
def test_two_diagnose_runs_on_one_report_at_once(tmp_path, capsys, private_cache):
    """The audit's case: two `diagnose --json X --force` at once. The second is refused while the first runs (it
    claims X before reading its runs); the first writes X. Before, both wrote and both said so."""
    run = _run(tmp_path / "run.csv", n=200)
    report = tmp_path / "gap.json"
    locks_dir = private_cache / "udrobot_ctrl" / "locks"
    first = subprocess.Popen([PYTHON, "-m", "udrobot_ctrl.cli", "diagnose", "--model", "cfd:chin", "--json",
                              str(report), "--force", str(run)], env=os.environ.copy(), text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (locks_dir.is_dir() and any(locks_dir.iterdir())):  # the first run has claimed its report
            assert first.poll() is None and time.monotonic() < deadline, first.stderr.read() if first.poll() else ""
            time.sleep(0.02)
        capsys.readouterr()
        assert main(["diagnose", "--model", "cfd:chin", "--json", str(report), "--force", str(run)]) == 2
        err = capsys.readouterr().err
        assert "in use by another udrobot-ctrl run" in err and f"pid {first.pid}" in err, err
        out, err_first = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert first.returncode == 0, err_first
    assert json.loads(report.read_text())["format"].startswith("udrobot-diagnosis/")
    assert not any(locks_dir.iterdir())  # the claim ended with the run
