"""One output file named by two options of a command is refused before any work (issue 40, item 3)."""
from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_files.output import OutputError, check_distinct_outputs, run_files


def _spellings(tmp_path, name):
    """Ways to name tmp_path/name: plain, with ./ and ../, through a symbolic link to the folder, and (for an
    existing file) a hard link."""
    sub = tmp_path / "sub"
    sub.mkdir(exist_ok=True)
    link = tmp_path / "link"
    if not link.exists():
        link.symlink_to(tmp_path, target_is_directory=True)
    return [tmp_path / name, tmp_path / "." / name, sub / ".." / name, link / name]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(a=st.integers(0, 3), b=st.integers(0, 3), name=st.sampled_from(["r.json", "out.csv", "x"]),
       options=st.permutations(["--json", "--out-model", "--out", "--plot"]))
def test_two_options_naming_one_file_are_refused(tmp_path, a, b, name, options):
    ways = _spellings(tmp_path, name)
    with pytest.raises(OutputError) as err:
        check_distinct_outputs({options[0]: ways[a], options[1]: str(ways[b]), options[2]: tmp_path / "other.txt"})
    assert f"{options[0]} and {options[1]} name the same file" in str(err.value)


def test_a_hard_link_is_the_same_file(tmp_path):
    (tmp_path / "a.json").write_text("{}")
    os.link(tmp_path / "a.json", tmp_path / "b.json")
    with pytest.raises(OutputError, match="--json and --out-model name the same file"):
        check_distinct_outputs([("--json", tmp_path / "a.json"), ("--out-model", tmp_path / "b.json")])


def test_a_run_outputs_sidecar_counts_and_distinct_files_pass(tmp_path):
    with pytest.raises(OutputError, match="--json and --out's sidecar name the same file"):
        check_distinct_outputs({"--json": tmp_path / "sim.json", "--out": run_files(tmp_path / "sim.csv")})
    check_distinct_outputs({"--json": tmp_path / "gap.json", "--out": run_files(tmp_path / "sim.csv"),
                            "--out-model": None, "--plot": [tmp_path / "p" / "a.png", tmp_path / "p" / "b.png"]})
