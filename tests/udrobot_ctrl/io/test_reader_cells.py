"""Damaged cells in text logs (issue 40, item 7): a bad QGC cell costs that cell only, a non-ASCII digit is never
read as a number, a NaN time stamp drops its sample for that reason."""
from __future__ import annotations

import unicodedata

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import LogImportError
from udrobot_ctrl.io.qgc_csv import read_qgc_csv
from udrobot_ctrl.io.rostopic_csv import read_topic_csv
from udrobot_ctrl.io.runlog import RunLogError, read_run
from udrobot_ctrl.io.streams import finish_stream

#: digits Python's float() reads but no log writes: Arabic-Indic, Devanagari, fullwidth, ...
NON_ASCII_DIGITS = [chr(c) for c in range(0x660, 0xFF20) if unicodedata.category(chr(c)) == "Nd"] + \
    [chr(c) for c in range(0xFF10, 0xFF1A)]

QGC_HEADER = "Timestamp,roll,pitch,heading,altitudeRelative,flightMode,battery0.voltage"
COLUMNS = QGC_HEADER.split(",")[1:]


def _qgc_rows(n=20):
    return [[f"2024-05-01 10:00:{k:02d}.000", "2.0", "-1.0", f"{10 + k}", f"{-0.1 * k:.2f}", "Manual", "15.5"]
            for k in range(n)]


def _write_qgc(path, rows):
    path.write_text("\n".join([QGC_HEADER] + [",".join(r) for r in rows]) + "\n", encoding="utf-8")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(0, 19), col=st.sampled_from([1, 2, 3, 4, 6]),
       junk=st.text(st.characters(codec="ascii", exclude_characters=",\"\r\n"), min_size=1, max_size=12)
       .filter(lambda s: s.strip() and s.strip().lower().lstrip("+-") not in ("nan", "inf", "infinity")))
def test_a_bad_qgc_cell_costs_that_cell_only(tmp_path, row, col, junk):
    try:
        float(junk.strip())  # the readers strip white space, str.strip's (which includes the ASCII separators)
        return  # a number after all
    except ValueError:
        pass
    rows = _qgc_rows()
    rows[row][col] = junk
    path = tmp_path / "qgc.csv"
    _write_qgc(path, rows)
    stream = read_qgc_csv(path)
    name = COLUMNS[col - 1]
    for h in ("roll", "pitch", "heading", "altitudeRelative", "battery0.voltage"):
        assert h in stream.fields, (h, stream.notes)
        values = stream.fields[h]
        assert values.size == 20
        if h == name:
            assert np.isnan(values[row]) and np.isfinite(np.delete(values, row)).all()
        else:
            assert np.isfinite(values).all()
    notes = "\n".join(stream.notes)
    assert "1 cell not a number, read as missing" in notes and f"{name}: 1 (first row {row + 2}" in notes
    assert "non-numeric QGC columns not read: flightMode" in notes


def test_a_bad_qgc_attitude_cell_keeps_the_attitude_in_the_run(tmp_path):
    rows = _qgc_rows(30)
    rows[7][1] = "2.0x"  # roll
    path = tmp_path / "qgc.csv"
    _write_qgc(path, rows)
    run = convert_log(path, require_inputs=False)
    assert "phi" in run.channels and np.isfinite(run.channels["phi"]).sum() >= 28
    assert "1 cell not a number, read as missing" in run.metadata["notes"]


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(digit=st.sampled_from(NON_ASCII_DIGITS), row=st.integers(0, 4), col=st.sampled_from(["t", "x", "thrust_1"]))
def test_a_non_ascii_digit_in_a_run_is_refused_naming_row_and_column(tmp_path, digit, row, col):
    assert float(digit) == unicodedata.digit(digit)  # what Python would have read
    cells = {"t": [f"{0.1 * k:.1f}" for k in range(5)], "x": ["1"] * 5, "thrust_1": ["2"] * 5}
    cells[col][row] = digit
    path = tmp_path / "run.csv"
    path.write_text("t,x,thrust_1\n" + "".join(f"{cells['t'][k]},{cells['x'][k]},{cells['thrust_1'][k]}\n"
                                               for k in range(5)), encoding="utf-8")
    with pytest.raises(RunLogError) as err:
        read_run(path)
    msg = str(err.value)
    assert str(path) in msg and f"data row {row + 1}" in msg and f"column '{col}'" in msg
    assert f"U+{ord(digit):04X}" in msg


@pytest.mark.parametrize("digit", ["٣", "３"])
def test_a_non_ascii_digit_in_a_qgc_or_rostopic_csv_is_refused(tmp_path, digit):
    rows = _qgc_rows()
    rows[3][2] = f"1{digit}"
    path = tmp_path / "qgc.csv"
    _write_qgc(path, rows)
    with pytest.raises(LogImportError, match=rf"qgc.csv: row 5, column pitch: .*U\+{ord(digit):04X}"):
        read_qgc_csv(path)
    topic = tmp_path / "pose.csv"
    topic.write_text("%time,field.x\n1000000000,1.0\n2000000000," + digit + "\n", encoding="utf-8")
    with pytest.raises(LogImportError, match=rf"pose.csv: line 3, column 'field.x'.*U\+{ord(digit):04X}"):
        read_topic_csv(topic, "pose", ["x"], time="receive")


def test_a_semicolon_separated_rostopic_csv_is_named_as_such(tmp_path):
    topic = tmp_path / "pose.csv"
    topic.write_text("%time;field.x\n1000000000;1.0\n", encoding="utf-8")
    with pytest.raises(LogImportError, match=r"pose.csv: line 1: .*semicolon-separated: the file must be "
                                             r"comma-separated"):
        read_topic_csv(topic, "pose", ["x"], time="receive")


def test_a_nan_stamp_drops_its_own_sample_for_a_bad_time_stamp(tmp_path):
    """Before: the NaN compared false with its neighbour, and the valid sample before it was dropped as 'sharing a
    time stamp with the next one'."""
    topic = tmp_path / "pose.csv"
    rows = ["%time,field.header.stamp,field.x"]
    for k in range(10):
        stamp = "nan" if k == 4 else str(1_000_000_000 * (k + 1))
        rows.append(f"{1_000_000_000 * (k + 1) + 5_000_000},{stamp},{float(k)}")
    topic.write_text("\n".join(rows) + "\n")
    s = read_topic_csv(topic, "pose", ["x"], time="header")
    assert list(s.fields["x"]) == [0.0, 1.0, 2.0, 3.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    notes = "\n".join(s.notes)
    assert "1 of 10 samples dropped for a bad time stamp" in notes and "message 5" in notes
    assert "share a time stamp" not in notes


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(["ok", "ok", "ok", "nan", "inf", "-inf"]), min_size=1, max_size=40))
def test_finish_stream_keeps_every_finite_stamp(kinds):
    """Whatever stamps are not numbers, every sample with a finite stamp is kept, none for a wrong reason."""
    times = [0.1 * i if k == "ok" else float(k) for i, k in enumerate(kinds)]
    values = np.arange(len(times), dtype=float)
    s = finish_stream("s", times, {"v": values}, "stamp")
    assert list(s.fields["v"]) == [v for v, k in zip(values, kinds) if k == "ok"]
    assert np.isfinite(s.t).all()
    bad = len(kinds) - kinds.count("ok")
    if bad:
        assert any(f"{bad} of {len(kinds)} samples dropped for a bad time stamp" in n for n in s.notes), s.notes
    assert not any("share a time stamp" in n or "corrupt time stamp" in n for n in s.notes), s.notes
