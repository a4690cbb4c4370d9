"""Every valid stretch of a field log kept, as the segments of one run (issue 58): a dataflash ArduSub dive that
crosses the surface band several times (three 2.5 m dives between surface visits, then a 7 m dive and a 1 s dip),
packed with pymavlink's format table as in test_ardusub_dive; the ``segment`` column read, validated and written."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.udrobot_ctrl.io.test_ardusub_dive import DEG, motor_pwm, write_dataflash
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io.mapping import CutSpec
from udrobot_ctrl.io.runlog import Run, RunLogError, read_run, resample, split_segments, write, write_run
from udrobot_ctrl.io.stretches import MIN_SEGMENT_S, TOO_SHORT, cut_run

MIN_DEPTH = CutSpec().min_depth  # the ardusub mapping's [cut] threshold (0.3 m)
#: log time (s) -> depth (m): three 2.5 m dives between surface visits, a shorter 7 m dive (the deepest is not the
#: longest: keeping the longest stretch alone wrote 2.5 m of the 7 m), a 1 s dip to 0.45 m
PROFILE = ([100.0, 105.0, 115.0, 135.0, 140.0, 145.0, 155.0, 175.0, 180.0, 185.0, 195.0, 215.0, 220.0, 225.0, 235.0,
            245.0, 250.0, 250.75, 251.5, 265.0],
           [0.0, 0.0, 2.5, 2.5, 0.0, 0.0, 2.5, 2.5, 0.0, 0.0, 2.5, 2.5, 0.0, 0.0, 7.0, 0.0, 0.0, 0.45, 0.0, 0.0])
TRUE_MAX = 7.0


def depth_of(t):
    return np.interp(t, *PROFILE)


def crossings():
    """(down, up) log times (s) where the profile crosses MIN_DEPTH, in order."""
    t = np.arange(100.0, 265.0, 1e-3)
    below = depth_of(t) >= MIN_DEPTH
    edges = np.flatnonzero(np.diff(below.astype(int)))
    return [(t[a + 1], t[b]) for a, b in zip(edges[::2], edges[1::2])]


def surface_crossing_dive(path):
    """165 s of a BlueROV2 Heavy dive at 10 Hz (ATT, BARO, CTUN, RCOU, RCIN; armed at 101 s, STABILIZE)."""
    recs = [("MODE", (int(100.0e6), 0, 0, 1)), ("EV", (int(101.0e6), 10))]
    for t in np.arange(100.0, 265.0, 0.1):
        us = int(round(t * 1e6))
        recs.append(("ATT", (us, 0.0, 1.0, 0.0, -1.0, 30.0, 30.0 + 0.1 * (t - 100.0))))
        recs.append(("BARO", (us + 1, 1, -depth_of(t), 0.0)))
        recs.append(("CTUN", (us + 2, 0.0, -depth_of(t))))
        recs.append(("RCOU", (us + 3, *motor_pwm(t, 8))))
        recs.append(("RCIN", (us + 4, *[1500] * 8, *[0] * 6)))
    recs.sort(key=lambda r: r[1][0])
    return write_dataflash(path, recs)


def log_time(run):
    """Log time (s) of each row: the stamp in force at the first row + the converted log's t since that row."""
    return run.extra["t_source"][0] + run.t - run.t[0]


def test_convert_keeps_every_submerged_dive_as_its_own_segment(tmp_path):
    run = convert_log(surface_crossing_dive(tmp_path / "00000012.BIN"), "ardusub")
    notes = run.metadata["notes"]
    dives = crossings()
    assert len(dives) == 5  # the three 2.5 m dives, the 7 m dive and the dip
    kept, dip = dives[:4], dives[4]
    assert dip[1] - dip[0] < MIN_SEGMENT_S  # the dip is valid but too short for a replay window
    # one segment per dive, numbered in time order, each spanning its submerged rows (10 Hz: within a sample)
    seg = run.segment
    assert list(np.unique(seg)) == [1, 2, 3, 4] and np.all(np.diff(seg) >= 0)
    t = log_time(run)
    for k, (down, up) in enumerate(kept, start=1):
        ts = t[seg == k]
        assert ts[0] == pytest.approx(down, abs=0.15) and ts[-1] == pytest.approx(up, abs=0.15)
    assert np.all(np.diff(run.t) > 0)  # t strictly increasing across the segments: the log's own time
    # the written depth reaches the log's true maximum, and every kept row is below the surface band
    z = run.channels["z"]
    assert np.nanmax(z) == pytest.approx(TRUE_MAX, abs=1e-3) and np.nanmin(z) >= MIN_DEPTH
    # notes: each segment with its span, each stretch left out with why
    assert "cut: kept 4 segment(s)" in notes
    for k in range(1, 5):
        assert f"cut: segment {k}: rows " in notes
    left = [line for line in notes.splitlines() if line.startswith("cut: left out")]
    assert len(left) == 7  # six surface visits (before, between and after the dives and the dip) and the dip
    assert sum("at or near the surface" in line for line in left) == 6 and sum(TOO_SHORT in line for line in left) == 1
    # the sidecar's record: the span kept and each segment's rows and times, in the file's t
    cut = run.metadata["cut"]
    segments = cut["kept"]["segments"]
    assert [s["segment"] for s in segments] == [1, 2, 3, 4]
    for s in segments:
        rows = run.t[run.segment == s["segment"]]
        assert (s["t_start"], s["t_stop"]) == (rows[0], rows[-1])
    assert sum(s["rows"][1] - s["rows"][0] + 1 for s in segments) == run.n < cut["kept"]["of"]
    # written and read back: the segment column survives as integers, the sidecar validates
    path = write(run, tmp_path / "dive.csv")
    back = read_run(path)
    np.testing.assert_array_equal(back.segment, run.segment)
    assert back.metadata["cut"] == json.loads(json.dumps(cut))
    assert [p.n for p in split_segments(back)] == [int((seg == k).sum()) for k in range(1, 5)]


def test_no_replayable_stretch_keeps_the_longest_alone_with_a_warning():
    """A stretch a window cannot open on is kept only when nothing longer is valid (it still serves the sensors)."""
    t = np.arange(0.0, 30.0, 0.1)
    z = np.where((t > 10.0) & (t < 11.5), 1.0, 0.0)  # 1.4 s submerged
    run = Run("", t, {"z": z}, "thrust", np.zeros((t.size, 1)))
    res = cut_run(run, CutSpec(armed_column=None))
    assert len(res.segments) == 1 and res.run.n == 14 and np.all(res.run.channels["z"] == 1.0)
    assert "no valid stretch is long enough to replay" in "\n".join(res.notes)


def _csv(tmp_path, segments, name="s.csv"):
    rows = "\n".join(f"{0.1 * k:.1f},0,{s}" for k, s in enumerate(segments))
    path = tmp_path / name
    path.write_text("t,thrust_1,segment\n" + rows + "\n")
    return path


@pytest.mark.parametrize(("cells", "row", "what"), [
    (["1", "1", "1.5", "2"], 3, "segment 1.5; expected an integer"),
    (["1", "", "2", "2"], 2, "segment empty/nan; expected an integer"),
    (["1", "1", "two", "2"], 3, "non-numeric cell 'two'; expected an integer"),
    (["1", "2", "1", "2"], 3, "segment 1 follows segment 2; segment numbers must not decrease"),
    (["1", "1", "inf", "2"], 3, "segment inf; expected an integer"),
])
def test_reader_rejects_a_bad_segment_column_naming_file_row_and_column(tmp_path, cells, row, what):
    path = _csv(tmp_path, cells)
    with pytest.raises(RunLogError) as err:
        read_run(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: data row {row} (file line {row + 1}): column 'segment': {what}")


def test_segments_round_trip_and_the_gap_between_them_is_not_a_clock_jump(tmp_path):
    """A 50 Hz run whose second segment starts 15 min after the first ends: the interval between segments is the
    cut, not a clock error (the same file without its segment column is refused)."""
    t = np.concatenate([np.arange(0.0, 10.0, 0.02), 910.0 + np.arange(0.0, 10.0, 0.02)])
    seg = np.repeat([3, 7], 500)  # numbers need not be consecutive (rows of a segment deleted by hand)
    path = write_run(tmp_path / "r.csv", t, {"z": np.full(t.size, 2.0)}, "thrust", np.zeros((t.size, 1)),
                     extra={"segment": seg})
    assert "\n0.0,0.0,2.0,3\n" in path.read_text()  # written as integers
    back = read_run(path)
    np.testing.assert_array_equal(back.segment, seg)
    assert back.segment_bounds() == [(0, 500), (500, 1000)]
    parts = split_segments(back)
    assert [p.path for p in parts] == [f"{path}[segment 3]", f"{path}[segment 7]"]
    assert parts[1].t[0] == 910.0 and parts[1].n == 500
    with pytest.raises(RunLogError, match="a gap of 900.02 s"):
        write_run(tmp_path / "j.csv", t, {"z": np.full(t.size, 2.0)}, "thrust", np.zeros((t.size, 1)))
    with pytest.raises(RunLogError, match="column 'segment': segment 3 follows segment 7"):
        write_run(tmp_path / "d.csv", t, {}, "thrust", np.zeros((t.size, 1)), extra={"segment": seg[::-1]})


def test_resample_does_not_bridge_two_segments():
    t = np.array([0.0, 1.0, 2.0, 10.0, 11.0, 12.0])
    run = Run("", t, {"z": np.array([1.0, 1.0, 1.0, 5.0, 5.0, 5.0]), "psi": np.full(6, 170 * DEG)}, "thrust",
              np.zeros((6, 1)), extra={"segment": np.repeat([1.0, 2.0], 3)})
    r = resample(run, np.arange(0.0, 12.5))
    assert np.all(r.channels["z"][:3] == 1.0) and np.all(r.channels["z"][10:] == 5.0)
    assert np.isnan(r.channels["z"][3:10]).all()  # between the segments: nothing measured, nothing invented
    np.testing.assert_allclose(r.channels["psi"][[0, 12]], 170 * DEG)
    assert r.extra["segment"][11] == 2.0


def test_sidecar_cut_segments_are_validated(tmp_path):
    path = _csv(tmp_path, ["1"] * 4)
    bad = {"invalid_share": {}, "kept": {"t_start": 0.0, "t_stop": 0.3, "rows": [2, 5], "of": 9,
                                         "segments": [{"segment": 1, "t_start": 0.0, "t_stop": 0.3, "rows": [4, 9]}]}}
    path.with_suffix(".json").write_text(json.dumps({"cut": bad}))
    with pytest.raises(RunLogError, match=r"'cut'.kept.segments\[0\]: expected an integer 'segment'"):
        read_run(path)
