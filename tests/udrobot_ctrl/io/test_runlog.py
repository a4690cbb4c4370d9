"""udrobot-run/1 reader/writer: round trip, every bad-input rule, and fuzzing (no crash, no dropped row)."""
from __future__ import annotations

import json
import math
import os
import random
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.io.runlog import (
    STATE_CHANNELS,
    TAU_COLUMNS,
    Run,
    RunLogError,
    read_run,
    resample,
    write,
    write_run,
)

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _write_text(path, text):
    path.write_text(text, encoding="utf-8")
    return path


def _good_csv(tmp_path, name="run.csv"):
    return _write_text(tmp_path / name, "t,thrust_1,thrust_2,z,psi,u,note\n"
                                         "0.0,1.5,-2,0.5,0.1,,a\n"
                                         "0.1,1.5,-2,0.52,nan,0.2,b\n"
                                         "0.25,0,0,0.55,0.3,0.25,c\n")


# ------------------------------------------------------------------------------------------ round trip


def test_read_valid_file(tmp_path):
    run = read_run(_good_csv(tmp_path))
    assert run.n == 3 and run.input_kind == "thrust" and run.input_names == ("thrust_1", "thrust_2")
    np.testing.assert_array_equal(run.t, [0.0, 0.1, 0.25])
    np.testing.assert_array_equal(run.inputs, [[1.5, -2], [1.5, -2], [0, 0]])
    assert set(run.channels) == {"z", "psi", "u"}
    assert math.isnan(run.channels["u"][0]) and math.isnan(run.channels["psi"][1])
    assert list(run.extra["note"]) == ["a", "b", "c"]
    assert run.metadata == {}
    assert run.duration == pytest.approx(0.25) and run.dt_median == pytest.approx(0.125)
    sm = run.state_matrix()
    assert sm.shape == (3, 12)
    assert np.isnan(sm[:, 0]).all() and sm[2, 2] == 0.55
    assert np.isnan(run.channel("x")).all()
    np.testing.assert_array_equal(run.channel("thrust_2"), [-2, -2, 0])
    with pytest.raises(KeyError, match="no column 'bogus'"):
        run.channel("bogus")


def test_round_trip_bit_exact_with_metadata(tmp_path):
    rng = np.random.default_rng(1)
    n = 50
    t = np.cumsum(rng.uniform(1e-4, 0.2, n))
    channels = {c: rng.normal(size=n) for c in STATE_CHANNELS + ("altitude", "voltage")}
    channels["voltage"] = 15.0 + channels["voltage"]  # a battery's voltage (0..60 V, read_run's range)
    channels["x"][::3] = np.nan
    tau = rng.normal(size=(n, 6)) * 10
    meta = {"vehicle": "udrobot", "water_density": 998.0, "seabed_depth": 3.0,
            "walls": [{"point": [0.0, 2.0, 0.0], "normal": [0.0, -1.0, 0.0]}], "notes": "pool",
            "cut": {"invalid_share": {"disarmed (armed = 0)": 0.25}, "kept": {"t_start": 1.5, "t_stop": 9.0,
                                                                               "rows": [12, 61], "of": 80}}}
    extra = {"t_source": t + 1e9, "label": np.array(["a"] * n)}
    path = write_run(tmp_path / "r.csv", t, channels, "tau", tau, metadata=meta, extra=extra)
    run = read_run(path)
    np.testing.assert_array_equal(run.t, t)
    np.testing.assert_array_equal(run.inputs, tau)
    assert run.input_names == TAU_COLUMNS
    for c, v in channels.items():
        np.testing.assert_array_equal(run.channels[c], v)
    np.testing.assert_array_equal(run.extra["t_source"], t + 1e9)
    assert run.metadata == {"format": "udrobot-run/1", **meta}
    # writing the run back gives byte-identical files
    write(run, tmp_path / "r2.csv")
    assert (tmp_path / "r2.csv").read_bytes() == path.read_bytes()
    assert json.loads((tmp_path / "r2.json").read_text()) == run.metadata


def test_write_is_atomic_and_validates_first(tmp_path):
    path = _good_csv(tmp_path)
    before = path.read_bytes()
    with pytest.raises(RunLogError, match="strictly increasing"):
        write_run(path, [0, 1, 1], {}, "pwm", np.ones((3, 4)))
    with pytest.raises(RunLogError, match="water_density"):
        write_run(path, [0, 1, 2], {}, "pwm", np.ones((3, 4)), metadata={"water_density": -1})
    with pytest.raises(RunLogError, match="refusing to overwrite"):
        write_run(path, [0, 1, 2], {}, "pwm", np.ones((3, 4)), overwrite=False)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["run.csv"]  # no temp files left behind


def test_reading_never_modifies_the_file(tmp_path):
    path = _good_csv(tmp_path)
    before, mtime = path.read_bytes(), path.stat().st_mtime_ns
    read_run(path)
    assert path.read_bytes() == before and path.stat().st_mtime_ns == mtime


def test_multiple_input_sets_first_wins_others_kept(tmp_path):
    path = _write_text(tmp_path / "r.csv", "t,pwm_1,thrust_1\n0,1500,0.5\n1,1600,1.0\n")
    run = read_run(path)
    assert run.input_kind == "thrust" and list(run.extra["pwm_1"]) == [1500, 1600]


# ------------------------------------------------------------------------------------------ bad input rules

BAD_CASES = [
    ("t,thrust_1\n0,1\n0.5,1\n0.5,2\n", r"data row 3 \(file line 4\): column 't'.*strictly increasing"),
    ("t,thrust_1\n0,1\n-1,1\n", r"data row 2 \(file line 3\): column 't'.*strictly increasing"),
    ("t,thrust_1\n0,1\n,1\n", r"data row 2 \(file line 3\): column 't'.*empty/nan time"),
    ("t,z\n0,1\n", r"file line 1: missing input columns"),
    ("t,thrust_1,thrust_3\n0,1,1\n", r"file line 1: column 'thrust_2': missing input column"),
    ("t,pwm_2\n0,1\n", r"column 'pwm_1': missing input column"),
    ("t,tau_X,tau_Y,tau_Z,tau_K,tau_M\n0,1,1,1,1,1\n", r"column 'tau_N': missing input column"),
    ("t,thrust_1,t\n0,1,2\n", r"column 't': duplicate column"),
    ("t,thrust_1,,z\n0,1,2,3\n", r"file line 1: header column 3 has an empty name"),
    ("time,thrust_1\n0,1\n", r"file line 1: no 't' column"),
    ("t;thrust_1;z\n0;1;1\n", r"file line 1: no 't' column.*semicolon-separated: the file must be comma-separated"),
    ("t\tthrust_1\n0\t1\n", r"no 't' column.*tab-separated"),
    ("t,thrust_1,z\n0,1,abc\n", r"data row 1 \(file line 2\): column 'z': non-numeric cell 'abc'"),
    ("t,thrust_1,z\n0,1,1\n1,0x10,1\n", r"data row 2 \(file line 3\): column 'thrust_1': non-numeric"),
    ("t,thrust_1,z\n0,1,1_0\n", r"column 'z': non-numeric"),
    ("t,thrust_1,z\n0,1,inf\n", r"data row 1 \(file line 2\): column 'z': infinite value"),
    ("t,thrust_1,z\n0,-Infinity,1\n", r"column 'thrust_1': infinite value"),
    ("t,thrust_1,z\n0,1,1e999\n", r"column 'z': infinite value"),
    ("t,thrust_1\ninf,1\n", r"column 't': infinite value"),
    ("t,thrust_1\n0,1\n1,2,3\n", r"data row 2 \(file line 3\): 3 cells, the header has 2"),
    ("t,thrust_1\n0,1\n\n1,2\n", r"file line 3: blank line inside the data"),
    ("t,thrust_1\n", r"no data rows"),
    ("", r"empty file"),
    ("t,thrust_1\n0,\"1\n", r"malformed CSV"),
]


@pytest.mark.parametrize("text, pattern", BAD_CASES)
def test_bad_input_rejected_with_location(tmp_path, text, pattern):
    path = _write_text(tmp_path / "bad.csv", text)
    with pytest.raises(RunLogError, match=pattern) as info:
        read_run(path)
    assert str(path) in str(info.value)


def test_non_utf8_bytes_named_with_offset(tmp_path):
    path = tmp_path / "bin.csv"
    path.write_bytes(b"t,thrust_1\n0,1\n1,\xff\n")
    with pytest.raises(RunLogError, match=r"file line 3 \(byte offset 17\): not UTF-8"):
        read_run(path)


def test_trailing_blank_lines_and_whitespace_accepted(tmp_path):
    run = read_run(_write_text(tmp_path / "r.csv", "\ufeff t , thrust_1 \n0, 1 \n1,NaN\n\n\n"))
    assert run.n == 2 and math.isnan(run.inputs[1, 0])


@pytest.mark.parametrize("meta, pattern", [
    ("[1]", "expected a JSON object"),
    ('{"format": "udrobot-run/2"}', "field 'format'"),
    ('{"water_density": "1000"}', "field 'water_density'"),
    ('{"water_density": true}', "field 'water_density'"),
    ('{"seabed_depth": -2}', "field 'seabed_depth'"),
    ('{"walls": {}}', "field 'walls'"),
    ('{"walls": [{"point": [0, 0], "normal": [1, 0, 0]}]}', r"walls\[0\]'.point"),
    ('{"walls": [{"point": [0, 0, 0], "normal": [2, 0, 0]}]}', r"walls\[0\]'.normal: must be a unit"),
    ('{"walls": [{"point": [0, 0, 0], "normal": [0, 0, 1]}]}', r"normal's z component"),
    ('{"walls": [{"point": [0, 0, 0]}]}', r"walls\[0\]'"),
    ('{"vehicle": 3}', "field 'vehicle'"),
    ('{"notes": ', r"line 1 column \d+: invalid JSON"),
    ('{"cut": {"kept": null}}', "field 'cut': expected an object with 'invalid_share' and 'kept'"),
    ('{"cut": {"invalid_share": {"disarmed": 1.5}, "kept": null}}', r"'cut'.invalid_share: .*\(0 to 1\)"),
    ('{"cut": {"invalid_share": {}, "kept": {"t_start": 0}}}', r"'cut'.kept: expected null"),
    ('{"cut": {"invalid_share": {}, "kept": {"t_start": 5, "t_stop": 1, "rows": [0, 9], "of": 10}}}',
     r"'cut'.kept: 't_start' and 't_stop'"),
    ('{"cut": {"invalid_share": {}, "kept": {"t_start": 0, "t_stop": 1, "rows": [0, 10], "of": 10}}}',
     r"'cut'.kept: 'rows' must be \[first, last\]"),
])
def test_bad_sidecar(tmp_path, meta, pattern):
    path = _good_csv(tmp_path)
    (tmp_path / "run.json").write_text(meta)
    with pytest.raises(RunLogError, match=pattern) as info:
        read_run(path)
    assert "run.json" in str(info.value)


# ------------------------------------------------------------------------------------------ resampling


def test_resample_linear_states_zoh_inputs(tmp_path):
    t = np.array([0.0, 1.0, 2.0, 3.0])
    chans = {"z": np.array([0.0, 1.0, np.nan, 3.0]), "psi": np.array([3.0, -3.0, -2.9, -2.8])}
    run = read_run(write_run(tmp_path / "r.csv", t, chans, "pwm", [[1500], [1600], [1700], [1800]],
                             extra={"t_source": t + 100}))
    t_new = np.array([-0.5, 0.0, 0.5, 1.0, 1.5, 2.5, 3.0, 3.5])
    out = resample(run, t_new)
    z = out.channels["z"]
    assert math.isnan(z[0]) and z[1] == 0.0 and z[2] == 0.5 and z[3] == 1.0
    assert math.isnan(z[4]) and math.isnan(z[5])  # never bridges the missing sample
    assert z[6] == 3.0 and math.isnan(z[7])
    # yaw through +-pi: the midpoint of 3.0 and -3.0 is pi (the short way round), not 0
    assert abs(abs(out.channels["psi"][2]) - np.pi) < 1e-12
    pwm = out.inputs[:, 0]
    assert math.isnan(pwm[0])
    np.testing.assert_array_equal(pwm[1:], [1500, 1500, 1600, 1600, 1700, 1800, 1800])
    np.testing.assert_array_equal(out.extra["t_source"][1:4], [100, 100, 101])
    with pytest.raises(RunLogError, match="strictly increasing"):
        resample(run, [0.0, 0.0])


# ------------------------------------------------------------------------------------------ fuzzing

_finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
_columns = st.lists(st.sampled_from(["x", "y", "z", "phi", "psi", "u", "q", "altitude", "voltage", "foo"]),
                    unique=True, max_size=5)


@pytest.mark.slow
@FUZZ
@given(data=st.data(), n=st.integers(1, 30), k=st.integers(1, 6), kind=st.sampled_from(["thrust", "pwm", "tau"]),
       cols=_columns)
def test_fuzz_valid_files_return_exactly_their_rows(tmp_path, data, n, k, kind, cols):
    # steps below MIN_RATIO_GAP_S (60 s): any ratio of them is a pause, not a clock jump (check_time_gaps)
    t = np.cumsum(np.array(data.draw(st.lists(st.floats(1e-6, 50.0), min_size=n, max_size=n))))
    k = 6 if kind == "tau" else k
    vals = st.one_of(_finite, st.just(float("nan")))
    # values with a physical range (read_run's check_measured_values) drawn inside it
    pulses = st.one_of(st.floats(500.0, 2200.0), st.just(float("nan")))
    volts = st.one_of(st.floats(0.0, 60.0, exclude_min=True), st.just(float("nan")))
    cell = pulses if kind == "pwm" else vals
    inputs = np.array(data.draw(st.lists(st.lists(cell, min_size=k, max_size=k), min_size=n, max_size=n)))
    channels = {c: np.array(data.draw(st.lists(volts if c == "voltage" else vals, min_size=n, max_size=n)))
                for c in cols if c != "foo"}
    extra = {"foo": np.arange(n) * 1.0} if "foo" in cols else None
    path = write_run(tmp_path / "f.csv", t, channels, kind, inputs, extra=extra)
    run = read_run(path)
    assert run.n == n == len(path.read_text().splitlines()) - 1
    np.testing.assert_array_equal(run.t, t)
    np.testing.assert_array_equal(run.inputs, inputs)
    for c, v in channels.items():
        np.testing.assert_array_equal(run.channels[c], v)


def _assert_clean(exc: RunLogError, path):
    msg = str(exc)
    assert str(path) in msg and len(msg) < 2000 and "\n" not in msg


@FUZZ
@given(raw=st.binary(max_size=300))
def test_fuzz_random_bytes_never_crash(tmp_path, raw):
    path = tmp_path / "g.csv"
    path.write_bytes(raw)
    try:
        run = read_run(path)
    except RunLogError as exc:
        _assert_clean(exc, path)
    else:
        assert isinstance(run, Run) and run.n >= 1


_cell = st.one_of(st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e400", "abc", " ", "1,2", '"', "0x1", "1.5",
                                   "-0", "+3e-2", "\t2"]),
                  st.text(alphabet=string.printable, max_size=6), _finite.map(repr))


@pytest.mark.slow
@FUZZ
@given(header=st.lists(st.sampled_from(["t", "thrust_1", "thrust_2", "pwm_1", "z", "psi", "tau_X", "", "x", "t "]),
                       min_size=1, max_size=6),
       cells=st.lists(st.lists(_cell, min_size=0, max_size=7), min_size=0, max_size=8))
def test_fuzz_garbage_tables_never_crash_or_drop_rows(tmp_path, header, cells):
    path = tmp_path / "g.csv"
    text = ",".join(header) + "\n" + "".join(",".join(row) + "\n" for row in cells)
    _write_text(path, text)
    try:
        run = read_run(path)
    except RunLogError as exc:
        _assert_clean(exc, path)
    else:
        non_blank = [ln for ln in text.splitlines()[1:] if ln.strip()]
        assert run.n == len(non_blank)
        assert np.all(np.diff(run.t) > 0) and np.all(np.isfinite(run.t))
        for v in list(run.channels.values()) + [run.inputs]:
            assert not np.any(np.isinf(v))


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), mutation=st.sampled_from(["shuffle", "drop_col", "nan_t", "inf", "swap"]))
def test_fuzz_mutated_valid_file_rejected_with_location(tmp_path, seed, mutation):
    rng = random.Random(seed)
    n = 12
    header = ["t", "thrust_1", "thrust_2", "thrust_3", "z", "psi"]
    rows = [[repr(0.1 * i), "1.0", "2.0", "3.0", repr(0.01 * i), "0.5"] for i in range(n)]
    if mutation == "shuffle":
        order = list(range(n))
        while order == sorted(order):
            rng.shuffle(order)
        rows = [rows[i] for i in order]
        expect = "strictly increasing"
    elif mutation == "drop_col":
        j = rng.choice([1, 2])  # thrust_1 or thrust_2: leaves a gap
        header.pop(j)
        for r in rows:
            r.pop(j)
        expect = f"'thrust_{j}': missing input column"
    elif mutation == "nan_t":
        rows[rng.randrange(n)][0] = rng.choice(["", "nan"])
        expect = "empty/nan time"
    elif mutation == "inf":
        rows[rng.randrange(n)][rng.randrange(6)] = rng.choice(["inf", "-inf", "Infinity", "1e999"])
        expect = "infinite value"
    else:
        i = rng.randrange(1, n)
        rows[i][0] = rows[i - 1][0]
        expect = f"data row {i + 1} (file line {i + 2}): column 't'"
    path = _write_text(tmp_path / "m.csv", ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows))
    with pytest.raises(RunLogError) as info:
        read_run(path)
    assert expect in str(info.value)
    _assert_clean(info.value, path)
