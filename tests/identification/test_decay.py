"""Launch files and their validation (identification.decay): bad input gives a clear per-launch error naming
the file (and the row/field where there is one), and a batch keeps going (issue 2, requirement 3)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from identification import cfd, decay, free_decay, pendulum, synthetic
from identification.decay import LaunchError
from identification.identify import RigOptions, identify_files
from udrobot_ctrl.vehicle import full_size_vehicle

UDROBOT = full_size_vehicle()  # the full-size vehicle the scale-model results are referred to

Q = 1e-3 / free_decay.COUNTS_PER_MM


def _write(path: Path, column: str, t, values) -> Path:
    path.write_text(f"t,{column}\n" + "".join(f"{a},{b}\n" for a, b in zip(t, values)))
    return path


@pytest.fixture(scope="module")
def good_counts():
    tr = synthetic.paper_spring_truth()["surge"]
    x = synthetic.spring_launch(tr, 0.03, np.random.default_rng(0))
    return x.t.round(4), x.values.astype(int)


def _bad_spring_files(d: Path, good_counts) -> dict:
    """name -> (path, expected words in the error, expected row or None, expected field or None)."""
    t, c = good_counts
    rng = np.random.default_rng(1)
    out = {}
    flat = np.round(0.1 / Q + rng.normal(0, 0.4, t.size)).astype(int)
    out["flat"] = (_write(d / "surge_flat.csv", "counts", t, flat), "does not oscillate", None, None)
    heavy = synthetic.SpringTruth("surge", 0.8, 1.4, 0.0044, mechanical_damping=12.0)  # zeta ~ 0.8
    od = synthetic.spring_launch(heavy, 0.03, rng)
    out["overdamped"] = (synthetic.write_launch(od, d / "surge_overdamped.csv"), "fewer than 3 peaks", None, None)
    v = c.astype(str)
    v[100] = "nan"
    out["nan"] = (_write(d / "surge_nan.csv", "counts", t, v), "NaN", 102, "counts")
    clipped = np.minimum(c, int(np.percentile(c, 85)))
    out["clipped"] = (_write(d / "surge_clipped.csv", "counts", t, clipped), "clipped", "any", None)
    tt = t.copy()
    tt[60] = tt[58]
    out["time"] = (_write(d / "surge_time.csv", "counts", tt, c), "time not increasing", 62, "t")
    out["columns"] = (_write(d / "surge_columns.csv", "position", t, c), "lacks the expected columns", 1, None)
    v = c.astype(str)
    v[9] = "twelve"
    out["text"] = (_write(d / "surge_text.csv", "counts", t, v), "'twelve' is not a number", 11, "counts")
    (d / "surge_empty.csv").write_text("")
    out["empty"] = (d / "surge_empty.csv", "empty file", None, None)
    (d / "surge_header_only.csv").write_text("t,counts\n")
    out["header_only"] = (d / "surge_header_only.csv", "data rows", None, None)
    short = _write(d / "surge_short_missing.csv", "counts", t[:30], c[:30])
    short.write_text(short.read_text().replace(f"{t[20]},{c[20]}\n", f"{t[20]}\n"))
    out["missing"] = (short, "missing value", 22, "counts")
    return out


def test_each_bad_launch_has_a_clear_error_and_the_batch_continues(tmp_path, good_counts):
    bad = _bad_spring_files(tmp_path, good_counts)
    t, c = good_counts
    goods = [_write(tmp_path / f"surge_good_{k}.csv", "counts", t, c + k) for k in range(2)]
    paths = goods[:1] + [b[0] for b in bad.values()] + goods[1:]
    rep = identify_files("spring", paths, RigOptions(vehicle=UDROBOT, area=0.0044))
    entries = {Path(e["file"]).name: e for e in rep["launches"]}
    assert len(entries) == len(paths)
    for g in goods:
        e = entries[g.name]
        assert e["ok"] and e["error"] is None
        assert e["Cm"] == pytest.approx(0.8172, rel=0.03)
    for name, (path, words, row, field) in bad.items():
        e = entries[path.name]
        assert e["ok"] is False, name
        assert str(path) in e["error"], name
        assert words in e["error"], (name, e["error"])
        if row == "any":
            assert ", row " in e["error"], (name, e["error"])
        elif row is not None:
            assert f", row {row}" in e["error"], (name, e["error"])
        if field is not None:
            assert f"field {field!r}" in e["error"], (name, e["error"])
    assert rep["n_ok"] == 2 and rep["aggregate"]["Cm"]["n"] == 2


def test_clipped_row_points_at_the_flat_top(tmp_path, good_counts):
    t, c = good_counts
    top = int(np.percentile(c, 85))
    p = _write(tmp_path / "clip.csv", "counts", t, np.minimum(c, top))
    with pytest.raises(LaunchError, match="clipped") as exc:
        decay.prepare(free_decay.read_spring_launch(p))
    line = exc.value.row
    rows = p.read_text().splitlines()
    assert int(rows[line - 1].split(",")[1]) == top  # the reported file line is on the plateau
    assert exc.value.path == str(p)


def test_a_real_peak_is_not_taken_for_clipping(good_counts):
    """Quantised peaks stay on one level for a while: the limit follows from amplitude, step and frequency."""
    t, c = good_counts
    launch = decay.Launch("ok.csv", t, c * Q, Q)
    start, ext, _ = decay.prepare(launch)
    assert ext.count >= 10


def test_pendulum_batch_with_bad_launches(tmp_path):
    tr = synthetic.paper_pendulum_truth()["sway"]
    rng = np.random.default_rng(3)
    good = synthetic.write_launch(synthetic.pendulum_launch(tr, math.radians(10), rng), tmp_path / "sway_good.csv")
    x = synthetic.pendulum_launch(tr, math.radians(10), rng)
    deg = _write(tmp_path / "sway_degrees.csv", "theta", x.t, np.degrees(x.values))
    still = _write(tmp_path / "sway_still.csv", "theta", x.t, 1e-4 * rng.standard_normal(x.t.size))
    rep = identify_files("pendulum", [deg, good, still], RigOptions(vehicle=UDROBOT, length=0.3, area=tr.area))
    ok = {Path(e["file"]).name: e for e in rep["launches"]}
    assert ok["sway_good.csv"]["ok"]
    assert ok["sway_good.csv"]["Cm"] == pytest.approx(tr.Cm, rel=0.02)
    assert not ok["sway_degrees.csv"]["ok"] and "radians" in ok["sway_degrees.csv"]["error"]
    assert not ok["sway_still.csv"]["ok"] and "does not oscillate" in ok["sway_still.csv"]["error"]


def test_line_numbers_count_comments_and_blank_lines(tmp_path, good_counts):
    t, c = good_counts
    body = "".join(f"{a},{b}\n" for a, b in zip(t[:40], c[:40]))
    lines = body.splitlines()
    lines[5] = f"{t[5]},oops"
    p = tmp_path / "commented.csv"
    p.write_text("# LX-EP-40 log\n\n T , Counts \n" + "\n".join(lines[:3]) + "\n\n# pause\n" + "\n".join(lines[3:]))
    with pytest.raises(LaunchError) as exc:
        free_decay.read_spring_launch(p)
    assert exc.value.row == 11 and exc.value.field == "counts"  # header on line 3, data from line 4
    assert p.read_text().splitlines()[exc.value.row - 1].endswith("oops")


def test_missing_file_and_malformed_csv(tmp_path):
    with pytest.raises(LaunchError, match="file not found"):
        free_decay.read_spring_launch(tmp_path / "nope.csv")
    p = tmp_path / "quote.csv"
    p.write_text('t,y\n0,"' + "1" * 200_000 + "\n")  # unterminated quote: one enormous field
    with pytest.raises(LaunchError, match="malformed CSV"):
        free_decay.read_spring_launch(p)
    with pytest.raises(LaunchError, match="malformed CSV"):
        cfd.read_force_table(p)
    b = tmp_path / "binary.csv"
    b.write_bytes(b"t,y\n\xff\xfe\x00\x01")
    with pytest.raises(LaunchError, match="cannot read"):
        free_decay.read_spring_launch(b)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.text(max_size=5),
                  st.integers(-10**6, 10**6).map(str), st.just(""), st.just('"'))


@pytest.mark.slow
@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(header=st.sampled_from(["t,y", "t,counts", "t,theta", "speed,force", "T, Y", "y,t", "t", ""]),
       rows=st.lists(st.lists(_cell, max_size=4), max_size=30), tail=st.binary(max_size=40))
def test_readers_fuzz_raise_only_launch_errors(tmp_path_factory, header, rows, tail):
    p = tmp_path_factory.mktemp("fz") / "f.csv"
    p.write_bytes((header + "\n" + "\n".join(",".join(r) for r in rows)).encode("utf-8", "surrogatepass") + tail)
    for reader in (free_decay.read_spring_launch, pendulum.read_pendulum_launch, cfd.read_force_table):
        try:
            reader(p)
        except LaunchError as exc:
            assert str(p) in str(exc)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(n=st.integers(20, 300), kind=st.sampled_from(["spring", "pendulum"]), data=st.data())
def test_analysis_of_arbitrary_traces_raises_only_launch_errors(n, kind, data):
    """Whatever numbers a valid file holds, the analysis either identifies or raises LaunchError."""
    dt = data.draw(st.sampled_from([0.001, 0.01, 0.1]))
    t = np.arange(n) * dt
    shape = data.draw(st.sampled_from(["noise", "decay", "step", "constant"]))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    if shape == "noise":
        x = rng.uniform(-1, 1, n)
    elif shape == "decay":
        w, z, a = data.draw(st.floats(0.2, 60)), data.draw(st.floats(0.0, 2.0)), data.draw(st.floats(1e-6, 1.0))
        x = a * np.exp(-z * w * t) * np.cos(w * t) + data.draw(st.floats(0, 1e-2)) * rng.standard_normal(n)
    elif shape == "step":
        x = np.where(np.arange(n) < data.draw(st.integers(0, n - 1)), 0.0, data.draw(st.floats(-1, 1)))
    else:
        x = np.full(n, data.draw(st.floats(-1, 1)))
    launch = decay.Launch("trace.csv", t, x, 0.0)
    try:
        if kind == "spring":
            rig = free_decay.SpringRig(0.97, 344_868e-9, 63.6, 0.0044)
            for method in ("output-error", "graphical"):
                free_decay.identify_launch(launch, rig, method=method)
        else:
            rig = pendulum.PendulumRig(0.146, 107_597e-9, 0.3, 0.0024)
            for method in ("output-error", "regression"):
                pendulum.identify_launch(launch, rig, method=method)
    except LaunchError as exc:
        assert "trace.csv" in str(exc)


def _slope_coverage(phi, reps=400, n=600, seed=0):
    """Coverage of the HAC 95 % interval of a regression slope with AR(1) errors (and of plain OLS's)."""
    from scipy import signal as sps

    rng = np.random.default_rng(seed)
    x = np.sin(np.linspace(0, 12 * np.pi, n)) * np.exp(-np.linspace(0, 2, n))  # a decaying regressor
    X = np.column_stack([x, np.ones(n)])
    hac, ols = [], []
    for _ in range(reps):
        e = sps.lfilter([1.0], [1.0, -phi], rng.standard_normal(n))
        y = 2.0 * x + 0.3 + 0.1 * e
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ coef
        J = -X  # residual Jacobian of r = y - X b
        cov, _ = decay.hac_covariance(J, r)
        s_ols = math.sqrt(float(r @ r) / (n - 2) * np.linalg.inv(X.T @ X)[0, 0])
        hac.append(abs(coef[0] - 2.0) <= 1.96 * math.sqrt(cov[0, 0]))
        ols.append(abs(coef[0] - 2.0) <= 1.96 * s_ols)
    return np.mean(hac), np.mean(ols)


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_hac_intervals_hold_for_white_and_persistent_errors(phi):
    """Prewhitened Newey-West: nominal coverage for white noise and for AR(1) 0.9 (Kalman-filtered IMU)."""
    hac, ols = _slope_coverage(phi)
    assert 0.90 <= hac <= 0.99, hac
    if phi:
        assert ols < 0.75  # the textbook s^2 (X^T X)^-1 is far too narrow for persistent errors
