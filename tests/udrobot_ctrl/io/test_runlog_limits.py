"""Work is bounded by the data: clock jumps are named, large logs are read in batches with the same result."""
from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.cli import main
from udrobot_ctrl.io import runlog
from udrobot_ctrl.io.runlog import RunLogError, check_time_gaps, read_run, write_run

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _unix_stamped(path, n=200):
    """A 20 Hz run whose last row is stamped in UNIX time (a logger that lost its relative clock)."""
    t = np.arange(n) * 0.05
    lines = ["t,thrust_1,thrust_2,thrust_3,thrust_4,z"]
    lines += [f"{float(ti)!r},1,1,0,0,{0.01 * k}" for k, ti in enumerate(t[:-1])]
    lines.append("1700000000.25,1,1,0,0,0.5")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_unix_time_row_is_named_by_the_reader(tmp_path):
    path = _unix_stamped(tmp_path / "r.csv")
    with pytest.raises(RunLogError) as exc:
        read_run(path)
    msg = str(exc.value)
    assert "data row 200 (file line 201)" in msg and "t = 1700000000.25 s follows 9.9 s" in msg
    assert "clock jump" in msg


@pytest.mark.parametrize("cmd", ["simulate", "diagnose"])
def test_unix_time_row_stops_commands_quickly(tmp_path, capsys, cmd):
    path = _unix_stamped(tmp_path / "r.csv")
    argv = (["simulate", "--model", "cfd:chin", "--input", str(path), "--out", str(tmp_path / "s.csv")]
            if cmd == "simulate" else ["diagnose", "--model", "cfd:chin", "--json", str(tmp_path / "d.json"),
                                       str(path)])
    t0 = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - t0 < 30  # was: a hang (simulate) or a 633 GiB allocation (diagnose)
    err = capsys.readouterr().err
    assert "data row 200" in err and "clock jump" in err


def test_simulate_bounds_substeps_of_an_in_memory_run():
    from udrobot_ctrl.cli.simulate import check_work

    with pytest.raises(RunLogError, match="clock jump"):
        check_work(np.array([0.0, 1.7e9]), 0.01, "two rows")
    assert check_work(np.array([0.0, 0.5, 1.0]), 0.01) == 100


def test_gap_rule_accepts_pauses_and_slow_logs():
    check_time_gaps(np.r_[np.arange(0, 10, 0.01), 10 + 50.0 + np.arange(0, 10, 0.01)])  # a 50 s pause at 100 Hz
    check_time_gaps(np.arange(0, 7200.0, 60.0))  # one sample a minute for two hours
    with pytest.raises(RunLogError, match="data row 1001"):
        check_time_gaps(np.r_[np.arange(0, 10, 0.01), 10 + 120.0 + np.arange(0, 10, 0.01)])  # 2 min at 100 Hz
    with pytest.raises(RunLogError, match="limit 21600 s"):
        check_time_gaps(np.array([0.0, 7.0 * 3600]))  # 7 h between two samples


_cells = st.one_of(st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr), st.just(""),
                   st.sampled_from(["nan", "-NaN", " 1.5 ", "1.", ".5e-3", "+2", "00012"]))
_extra = st.one_of(_cells, st.sampled_from(["inf", "-Infinity", "abc", "1_000", "0x10", "١"]))


@SETTINGS
@given(data=st.data(), n=st.integers(1, 40), chunk=st.integers(1, 7))
def test_batched_reader_equals_cell_by_cell_parse(tmp_path, monkeypatch, data, n, chunk):
    """Batches of any size (the fast numpy path and the per-cell path) give the same run as one cell at a time."""
    monkeypatch.setattr(runlog, "_CHUNK_ROWS", chunk)
    z = data.draw(st.lists(_cells, min_size=n, max_size=n))
    foo = data.draw(st.lists(_extra, min_size=n, max_size=n))
    rows = [f"{k * 0.1!r},{k % 3},{z[k]},{foo[k]}" for k in range(n)]
    path = tmp_path / "b.csv"
    path.write_text("t,thrust_1,z,foo\n" + "\n".join(rows) + "\n", encoding="utf-8")
    run = read_run(path)
    expect_z = np.array([runlog._parse_cell(c) for c in z])
    np.testing.assert_array_equal(run.channels["z"], expect_z)
    parsed = [runlog._parse_cell(c) for c in foo]
    if any(v is None for v in parsed):
        assert run.extra["foo"].dtype == object and list(run.extra["foo"]) == foo
    else:
        np.testing.assert_array_equal(run.extra["foo"], np.array(parsed, float))
    np.testing.assert_array_equal(run.inputs[:, 0], np.arange(n) % 3)


@pytest.mark.parametrize("chunk", [1, 2, 3, 64])
def test_errors_name_the_same_row_whatever_the_batch(tmp_path, monkeypatch, chunk):
    monkeypatch.setattr(runlog, "_CHUNK_ROWS", chunk)
    rows = [f"{0.1 * k!r},1.0,{0.5 * k!r}" for k in range(10)]
    rows[6] = "0.6,1.0,inf"  # data row 7, file line 8
    path = tmp_path / "e.csv"
    path.write_text("t,thrust_1,z\n" + "\n".join(rows) + "\n")
    with pytest.raises(RunLogError, match=r"data row 7 \(file line 8\): column 'z': infinite"):
        read_run(path)
    rows[6] = "0.05,1.0,3.0"  # t back in time
    path.write_text("t,thrust_1,z\n" + "\n".join(rows) + "\n")
    with pytest.raises(RunLogError, match=r"data row 7 \(file line 8\): column 't'.*strictly increasing"):
        read_run(path)


def test_not_utf8_is_located_in_a_large_file(tmp_path):
    t = np.arange(30000) * 0.01
    path = write_run(tmp_path / "u.csv", t, {}, "thrust", np.ones((t.size, 1)))
    raw = bytearray(path.read_bytes())
    pos = raw.index(b"\n", len(raw) - 200) + 1  # start of a line near the end, beyond the first 1 MiB block
    line = raw[:pos].count(b"\n") + 1
    assert line > 29900
    raw[pos] = 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(RunLogError, match=rf"file line {line} \(byte offset {pos}\): not UTF-8"):
        read_run(path)


HEADER = "t,z,thrust_1,thrust_2,thrust_3,thrust_4"


def _with_row(path, k, text, n=8):
    """A run of ``n`` data rows whose data row ``k`` (1-based) is ``text``."""
    rows = [f"{0.1 * i:.1f},0,1,1,1,1" for i in range(n)]
    rows[k - 1] = text
    path.write_text("\n".join([HEADER, *rows]) + "\n")
    return path


@pytest.mark.parametrize("text, words", [
    ('0.2,"0,1,1,1,1', ["data row 3 (file line 4)", "malformed CSV", "found at file line 9"]),  # the quote runs on
    ('0.2,"0"x,1,1,1,1', ["data row 3 (file line 4)", "malformed CSV"]),
    ("0.2,abc,1,1,1,1", ["data row 3 (file line 4)", "column 'z'"]),
    ("0.2,0,1,1,1", ["data row 3 (file line 4)", "5 cells"]),
])
def test_error_lines_are_the_files_own_numbers(tmp_path, capsys, text, words):
    """Issue 62: file lines are 1-based with the header as line 1 (a malformed record was named one line on)."""
    path = _with_row(tmp_path / "r.csv", 3, text)
    assert path.read_text().splitlines()[3] == text  # file line 4 (1-based) is data row 3
    assert main(["simulate", "--model", "cfd:chin", "--input", str(path), "--out", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(path) in err, err
    for w in words:
        assert w in err, err


def test_an_endless_line_is_refused_without_holding_it(tmp_path, capsys):
    """Issue 62: a single line of millions of cells (a damaged file) is refused at the line limit, read in pieces
    of at most MAX_LINE_CHARS: the reader's memory does not grow with the line."""
    path = tmp_path / "r.csv"
    cells = 4 * runlog.MAX_LINE_CHARS // 2  # 4 Mi characters of "0,"
    with open(path, "w") as fh:
        fh.write(HEADER + "\n0.0,0,1,1,1,1\n")
        fh.write("0," * cells + "\n")
    with pytest.raises(RunLogError, match=r"file line 3: a line longer than 1048576 characters"):
        read_run(path)
    lines = []
    with open(path) as fh:  # what the reader took from the file before refusing: the limit, not the line
        with pytest.raises(RunLogError):
            for line in runlog._bounded_lines(fh, path):
                lines.append(line)
        assert fh.tell() <= len(HEADER) + 16 + runlog.MAX_LINE_CHARS + 1
    assert main(["simulate", "--model", "cfd:chin", "--input", str(path), "--out", str(tmp_path / "s.csv")]) == 2
    assert "a line longer than" in capsys.readouterr().err
