"""Issue 40 item 3: no command replaces a file it did not create without --force, never an input, never a node."""
from __future__ import annotations

import os
import shutil
import stat
from importlib import resources

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.udrobot_ctrl.cli.test_output_policy import _snapshot, _tlog
from udrobot_ctrl.cli import main
from udrobot_ctrl.cli.demo import write_index
from udrobot_ctrl.io import log_input_files
from udrobot_ctrl.sensitivity.results import TEMP_NAME, remove_stale_temp_files
from udrobot_files import output as files


def _refused(argv, tmp_path, capsys, what="refusing to overwrite input data"):
    """The command exits 2 with a one-line error containing ``what`` and changes no byte under ``tmp_path``."""
    capsys.readouterr()
    before = _snapshot(tmp_path)
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert ": error: " in err and what in err, err
    assert _snapshot(tmp_path) == before
    return err


def test_demo_refuses_a_folder_with_a_readme_and_a_planted_link(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "README.md").write_text("my notes")
    _refused(["demo", "--out", out], tmp_path, capsys, what="exists")
    (out / "README.md").unlink()
    target = tmp_path / "victim.txt"
    target.write_text("keep")
    (out / "README.md").symlink_to(target)
    _refused(["demo", "--out", out], tmp_path, capsys, what="exists")
    assert target.read_text() == "keep"
    (out / "README.md").unlink()
    (out / "mine.txt").write_text("mine")  # any file: the demo writes dozens of names
    _refused(["demo", "--out", out], tmp_path, capsys, what="not empty")


def test_demo_index_replaces_a_planted_link_and_never_writes_through_it(tmp_path):
    target = tmp_path / "victim.txt"
    target.write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / "README.md").symlink_to(target)
    path = write_index(out)  # as under --force
    assert target.read_text() == "keep"
    assert not path.is_symlink() and "demo output" in path.read_text()


def test_convert_force_never_overwrites_its_mapping_file(tmp_path, capsys):
    log = _tlog(tmp_path / "dive.tlog")
    mapping = tmp_path / "m.toml"
    shutil.copyfile(_shipped("ardusub"), mapping)
    _refused(["convert", log, "--mapping", mapping, "--out", mapping, "--force"], tmp_path, capsys)
    assert mapping in log_input_files(log, mapping)


def _shipped(name):
    return resources.files("udrobot_ctrl.models") / "mappings" / f"{name}.toml"


@pytest.mark.parametrize("out", ["wrench_3.csv", "navigation_state_3.json", "wrench_3.json"])
def test_convert_force_never_overwrites_a_file_of_the_rostopic_set(tmp_path, capsys, out):
    nav, wrench = tmp_path / "navigation_state_3.csv", tmp_path / "wrench_3.csv"
    nav.write_text("%time,field.position.x\n1,0\n")
    wrench.write_text("%time,field.force.x\n1,0\n")
    (tmp_path / "wrench_3.json").write_text("{}")  # a sidecar belongs to its CSV
    _refused(["convert", nav, "--mapping", "tartan-auv", "--out", tmp_path / out, "--force"], tmp_path, capsys)
    assert set(log_input_files(nav, "tartan-auv")) == {nav, wrench}


def test_output_on_a_device_or_pipe_is_refused_even_with_force(tmp_path, capsys):
    with pytest.raises(files.OutputError, match="character device"):
        files.check_outputs(["/dev/null"], force=True)
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    _refused(["model", "export", "--model", "cfd:chin", "--out", fifo, "--force"], tmp_path, capsys,
             what="named pipe")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    with pytest.raises(files.OutputError, match="named pipe"):
        files.atomic_write(fifo, "x", force=True)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


USER_TMP = st.one_of(
    st.from_regex(r"\A\.[a-z_]{1,8}\.tmp\Z"),  # .notes.tmp
    st.from_regex(r"\A\.[a-z_]{1,8}\.[0-9]{1,9}\.tmp\Z"),  # .draft.123.tmp: no token
    st.from_regex(r"\A\.[a-z_]{1,8}\.[0-9]{6,9}\.[0-9a-f]{1,11}\.tmp\Z"),  # too short a token
    st.from_regex(r"\A\.[a-z_]{1,8}\.[a-z]{1,5}\.[0-9a-f]{12}\.tmp\Z"),  # not a pid
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=USER_TMP)
def test_sensitivity_removes_only_its_own_stale_temporaries(tmp_path_factory, name):
    folder = tmp_path_factory.mktemp("study")
    user = folder / name
    user.write_text("the user's")
    dead = folder / ".c00000008-0008.csv.999999999.d4e5f6a7b8c9.tmp"  # ours, its writer gone
    dead.write_text("sample_id\n")
    link_target = folder / "target.txt"
    link_target.write_text("keep")
    link = folder / ".x.999999998.0123456789ab.tmp"  # our name, but a link: not a file we wrote
    link.symlink_to(link_target)
    assert TEMP_NAME.match(dead.name) and not TEMP_NAME.match(name)
    before = _snapshot(folder)
    removed = remove_stale_temp_files(folder)
    assert removed == [dead] and user.read_text() == "the user's" and link.is_symlink()
    assert _snapshot(folder) == {p: b for p, b in before.items() if p != dead}
