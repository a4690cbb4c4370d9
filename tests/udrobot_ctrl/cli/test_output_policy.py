"""One output policy for every command: an input (or its sidecar) is never overwritten, an existing file only
with --force, and what is written is atomic and follows the user's umask (udrobot_files.output)."""
from __future__ import annotations

import os
import stat
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.cli import main
from udrobot_ctrl.io.runlog import read_run, write_run
from udrobot_files import output as files

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
NAMES = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=12)


def _run(path, n=40, metadata=True):
    t = np.arange(n) * 0.05
    return write_run(path, t, {"z": 0.1 * np.sin(t), "u": 0.05 * np.cos(t)}, "thrust", np.full((n, 4), 2.0),
                     metadata={"notes": "measured"} if metadata else None)


def _tlog(path):
    """A small MAVLink telemetry log (ATTITUDE at 50 Hz, UNIX-time stamps), convertible with --mapping ardusub."""
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(path, "wb") as fh:
        for k in range(100):
            msg = mav.attitude_encode(20 * k, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0)
            fh.write(struct.pack(">Q", int(round((1.7e9 + 0.02 * k) * 1e6))) + msg.pack(mav))
    return path


def _snapshot(folder):
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and not p.is_symlink()}


def _collide(tmp_path, inp, how):
    """An output path that collides with input ``inp`` in the way ``how``."""
    if how == "same":
        return inp
    if how == "sidecar":
        return inp.with_suffix(".json")
    if how == "symlink":
        link = tmp_path / "link_to_input.csv"
        link.symlink_to(inp)
        return link
    if how == "hardlink":
        hard = tmp_path / "hard_link.csv"
        os.link(inp, hard)
        return hard
    if how == "relative":
        return os.path.relpath(inp)
    raise AssertionError(how)


def _refused(argv, tmp_path, capsys, what="refusing to overwrite input data"):
    capsys.readouterr()  # drop the output of earlier calls
    before = _snapshot(tmp_path)
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("udrobot-ctrl ") and ": error: " in err and len(err.strip().splitlines()) == 1, err
    assert what in err, err
    assert _snapshot(tmp_path) == before  # every input byte-identical, nothing written
    return err


HOW = ["same", "sidecar", "symlink", "hardlink", "relative"]


@pytest.mark.parametrize("how", HOW)
def test_diagnose_never_writes_over_a_run(tmp_path, capsys, monkeypatch, how):
    monkeypatch.chdir(tmp_path)
    run = _run(tmp_path / "run.csv")
    out = _collide(tmp_path, run, how)
    if how == "sidecar":  # the sidecar exists: --force must not help
        _refused(["diagnose", "--model", "cfd:chin", "--json", out, "--force", run], tmp_path, capsys)
    else:
        _refused(["diagnose", "--model", "cfd:chin", "--json", out, run], tmp_path, capsys)


def test_diagnose_holdout_and_model_are_inputs_too(tmp_path, capsys):
    fit, hold = _run(tmp_path / "fit.csv"), _run(tmp_path / "hold.csv")
    assert main(["model", "export", "--model", "cfd:chin", "--out", str(tmp_path / "m.json")]) == 0
    for out in (hold, tmp_path / "hold.json", tmp_path / "m.json"):
        _refused(["diagnose", fit, "--model", tmp_path / "m.json", "--json", out, "--force", "--holdout", hold],
                 tmp_path, capsys)
    _refused(["diagnose", "--model", "cfd:chin", "--json", tmp_path / "r.json", "--plot", fit, fit], tmp_path,
             capsys, what="not a folder")


@pytest.mark.parametrize("how", HOW)
def test_simulate_never_writes_over_its_inputs(tmp_path, capsys, monkeypatch, how):
    monkeypatch.chdir(tmp_path)
    run = _run(tmp_path / "run.csv")
    _refused(["simulate", "--model", "cfd:chin", "--input", run, "--out", _collide(tmp_path, run, how), "--force"],
             tmp_path, capsys)


def test_simulate_model_file_and_output_sidecar(tmp_path, capsys):
    run = _run(tmp_path / "run.csv")
    model = tmp_path / "model.json"
    assert main(["model", "export", "--model", "cfd:chin", "--out", str(model)]) == 0
    _refused(["simulate", "--model", model, "--input", run, "--out", model, "--force"], tmp_path, capsys)
    # output X.csv would replace (or go with) an existing X.json: only with --force
    (tmp_path / "sim.json").write_text('{"notes": "someone else\'s"}')
    _refused(["simulate", "--model", model, "--input", run, "--out", tmp_path / "sim.csv"], tmp_path, capsys,
             what="exists; pass --force")
    assert main(["simulate", "--model", str(model), "--input", str(run), "--out", str(tmp_path / "sim.csv"),
                 "--force"]) == 0
    assert read_run(tmp_path / "sim.csv").n == read_run(run).n
    _refused(["simulate", "--model", model, "--input", run, "--out", tmp_path / "sim.csv"], tmp_path, capsys,
             what="exists; pass --force")


def test_convert_force_never_overwrites_the_input_and_guards_the_sidecar(tmp_path, capsys):
    log = _tlog(tmp_path / "dive.tlog")
    base = ["convert", log, "--mapping", "ardusub", "--allow-missing-inputs"]
    _refused(base + ["--out", log, "--force"], tmp_path, capsys)
    (tmp_path / "x.json").write_text("{}")
    _refused(base + ["--out", tmp_path / "x.csv"], tmp_path, capsys, what="x.json: exists; pass --force")
    assert main([str(a) for a in base + ["--out", tmp_path / "y.csv"]]) == 0
    _refused(base + ["--out", tmp_path / "y.csv"], tmp_path, capsys, what="exists; pass --force")


def test_model_identify_compare_sensitivity_demo_refuse(tmp_path, capsys):
    model = tmp_path / "m.json"
    assert main(["model", "export", "--model", "cfd:chin", "--out", str(model)]) == 0
    _refused(["model", "export", "--model", model, "--out", model, "--force"], tmp_path, capsys)
    _refused(["model", "export", "--model", "cfd:chin", "--out", model], tmp_path, capsys, what="exists; pass --force")
    table = tmp_path / "cfd_surge.csv"
    table.write_text("speed,force\n0.5,12.0\n1,45.0\n2,170.0\n")
    for opt in ("--json", "--out"):
        _refused(["identify", "cfd", table, opt, table, "--force"], tmp_path, capsys)
    _refused(["identify", "cfd", table, "--plot", table], tmp_path, capsys, what="not a folder")
    _refused(["compare", "--models", f"{model},cfd:chin", "--json", model, "--force"], tmp_path, capsys)
    _refused(["sensitivity", "--model", model, "--out", model], tmp_path, capsys, what="not a folder")
    _refused(["demo", "--out", model], tmp_path, capsys, what="not a folder")


@SETTINGS
@given(name=NAMES, how=st.sampled_from(["same", "sidecar", "symlink"]), force=st.booleans())
def test_any_run_name_and_collision_is_refused(tmp_path_factory, name, how, force):
    tmp = tmp_path_factory.mktemp("p")
    run = _run(tmp / f"{name}.csv")
    out = _collide(tmp, run, how)
    before = _snapshot(tmp)
    with pytest.raises(files.OutputError, match="refusing to overwrite input data"):
        files.check_outputs(files.run_files(out), [run], force=force)
    with pytest.raises(files.OutputError):
        write_run(out, [0.0, 1.0], {}, "tau", np.zeros((2, 6)), protect=[run])
    assert _snapshot(tmp) == before


@SETTINGS
@given(metadata=st.booleans(), stale=st.booleans())
def test_replacing_a_run_replaces_its_stale_sidecar(tmp_path_factory, metadata, stale):
    tmp = tmp_path_factory.mktemp("s")
    path = tmp / "r.csv"
    _run(path, metadata=stale)
    _run(path, n=10, metadata=metadata)  # overwrite=True (the API default; the CLIs ask for --force)
    run = read_run(path)
    assert run.n == 10
    assert ("notes" in run.metadata) == metadata  # never the sidecar of the replaced run alone
    with pytest.raises(ValueError, match="exists"):
        write_run(path, [0.0, 1.0], {}, "tau", np.zeros((2, 6)), overwrite=False)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077, 0o002])
def test_written_files_follow_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        path = _run(tmp_path / "r.csv")
        report = files.atomic_write(tmp_path / "rep.json", "{}")
    finally:
        os.umask(old)
    for p in (path, path.with_suffix(".json"), report):
        assert stat.S_IMODE(os.stat(p).st_mode) == 0o666 & ~umask


def test_failed_write_leaves_no_temp_file_and_the_old_file(tmp_path):
    target = tmp_path / "keep.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with files.open_atomic(target, "w") as fh:
            fh.write("half")
            raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.csv"]


def test_a_symlinked_output_is_replaced_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    link = tmp_path / "out.json"
    link.symlink_to(victim)
    files.atomic_write(link, "report", force=True)
    assert victim.read_text() == "precious"
    assert not link.is_symlink() and link.read_text() == "report"


def test_unwritable_folder_is_reported_before_any_work(tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root can write anywhere")
    run = _run(tmp_path / "run.csv")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    _refused(["simulate", "--model", "cfd:chin", "--input", run, "--out", locked / "s.csv"], tmp_path, capsys,
             what="not writable")


def test_a_file_output_in_a_missing_folder_is_refused_naming_the_folder(tmp_path, capsys):
    """``simulate --out /missing/dir/x.csv`` names the missing folder (exit 2) and creates nothing."""
    run = _run(tmp_path / "run.csv")
    missing = tmp_path / "missing" / "dir"
    for argv in (["simulate", "--model", "cfd:chin", "--input", run, "--out", missing / "x.csv"],
                 ["simulate", "--model", "cfd:chin", "--windows", "--input", run, "--json", missing / "gap.json"],
                 ["compare", "--models", "cfd:chin", "--controllers", "pid", "--json", missing / "r.json"],
                 ["model", "export", "--model", "cfd:chin", "--out", missing / "m.json"],
                 ["diagnose", "--model", "cfd:chin", run, "--json", missing / "d.json"],
                 ["design", "ardusub", "--model", "bluerov2", "--out", missing / "gains.params"],
                 ["identify", "cfd", run, "--out", missing / "set.toml"],
                 ["convert", _tlog(tmp_path / "t.tlog"), "--mapping", "ardusub", "--out", missing / "r.csv"]):
        err = _refused(argv, tmp_path, capsys, what=f"folder {missing} does not exist")
        assert "--out" in err or "--json" in err, argv
        assert not (tmp_path / "missing").exists()
    # a file where the folder should be is named too
    (tmp_path / "afile").write_text("x")
    _refused(["simulate", "--model", "cfd:chin", "--input", run, "--out", tmp_path / "afile" / "x.csv"], tmp_path,
             capsys, what=f"folder {tmp_path / 'afile'} is not a folder")


def test_a_folder_option_still_creates_its_folder(tmp_path):
    """Options whose value is a folder (demo/compare ``--out DIR``, ``--plot DIR``) create it when written."""
    folder = tmp_path / "new" / "plots"
    assert files.check_output_dir(folder, names=["a.png"]) == folder
    assert files.check_outputs([folder / "a.png"], option="--plot") == [folder / "a.png"]  # default: folder option
    with pytest.raises(files.OutputError, match="does not exist"):
        files.check_outputs([folder / "a.png"], option="--json", create_folders=False)
    assert not (tmp_path / "new").exists()  # checking creates nothing
    files.atomic_write(folder / "a.png", b"png")
    assert (folder / "a.png").read_bytes() == b"png"


def test_a_json_inside_the_folder_compare_creates_is_written(tmp_path):
    """``compare --out DIR --json DIR/r.json``: the folder --out creates holds the --json file (no refusal)."""
    out = tmp_path / "cmp"
    assert main(["compare", "--models", "pendulum:chin", "--controllers", "pid", "--quick", "--no-ekf",
                 "--workers", "1", "--out", str(out), "--json", str(out / "r.json")]) == 0
    assert (out / "r.json").is_file() and (out / "compare.csv").is_file()
