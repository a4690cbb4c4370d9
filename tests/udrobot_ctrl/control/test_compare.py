"""udrobot-ctrl compare: every (design, plant, controller) pair, the EKF matrix and the JSON contract."""
import json
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.control.compare import MPC_PREVIEW, RESULT_KEYS
from udrobot_ctrl.control.metrics import T200_POWER_12V, fit_t200_power, thrust_power
from udrobot_ctrl.control.missions import CONTROLLER_KINDS, SafeController

MODELS = ("cfd:chin", "free_decay:morison")
T200_CSV = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "t200" / "t200_performance_tidy.csv"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("cmp")
    js = d / "r.json"
    rc = main(["compare", "--quick", "--models", ",".join(MODELS), "--json", str(js), "--out", str(d / "o")])
    assert rc == 0
    return json.loads(js.read_text()), d / "o"


@pytest.mark.slow
def test_json_has_every_pair_for_every_controller(report):
    doc, _ = report
    assert set(doc) == {"models", "results", "ekf"}
    assert doc["models"] == list(MODELS)
    got = {(r["design"], r["plant"], r["controller"]) for r in doc["results"]}
    assert got == {(a, b, c) for a in MODELS for b in MODELS for c in CONTROLLER_KINDS}
    for r in doc["results"]:
        assert set(r) == set(RESULT_KEYS)
    assert {(e["filter_model"], e["plant"]) for e in doc["ekf"]} == {(a, b) for a in MODELS for b in MODELS}
    for e in doc["ekf"]:
        assert set(e) == {"filter_model", "plant", "rmse", "nis_mean"} and set(e["rmse"]) == {"z", "psi", "u"}


@pytest.mark.slow
def test_matched_lqr_and_pid_track_the_mission(report):
    doc, _ = report
    rows = {(r["design"], r["plant"], r["controller"]): r for r in doc["results"]}
    for m in MODELS:
        lqr = rows[(m, m, "lqr")]
        assert lqr["settling_s"] is not None and lqr["settling_s"] < 4.0
        assert lqr["overshoot"] < 10.0 and lqr["energy_J"] > 0 and lqr["saturation_s"] >= 0
        assert rows[(m, m, "pid")]["iae"] < 10.0


@pytest.mark.slow
def test_ekf_matched_model_is_better_than_mismatched(report):
    doc, _ = report
    ekf = {(e["filter_model"], e["plant"]): e for e in doc["ekf"]}
    a, b = MODELS
    if ekf[(a, a)]["rmse"]["u"] is None:
        pytest.skip("EKF module unavailable in this build")
    # the surge drag differs between the two coefficient sets: the wrong model estimates u worse
    assert ekf[(a, a)]["rmse"]["u"] < ekf[(a, b)]["rmse"]["u"]
    assert ekf[(b, b)]["rmse"]["u"] < ekf[(b, a)]["rmse"]["u"]


@pytest.mark.slow
def test_outputs_written(report):
    _, out = report
    for f in ("compare.csv", "compare_ekf.csv", "compare.txt", "compare_full.json", "compare_iae_lqr.png",
              "compare_missions.png"):
        assert (out / f).exists(), f
    assert len((out / "compare.csv").read_text().splitlines()) == 1 + len(MODELS) ** 2 * len(CONTROLLER_KINDS)
    # the MPCs' preview (they move before each reference step) is explained where the comparison is shown
    text = " ".join((out / "compare.txt").read_text().split())
    assert "preview: " + MPC_PREVIEW in text


def test_cli_rejects_unknown_controller(capsys):
    assert main(["compare", "--controllers", "mpc9"]) == 2
    assert "unknown controller" in capsys.readouterr().err


def test_energy_fit_is_monotone_and_matches_data():
    f = np.array([-28.0, -10.0, 0.0, 10.0, 36.0])
    P = thrust_power(f)
    assert P[2] == 0 and P[0] > P[1] > 0 and P[4] > P[3] > 0
    assert 150 < thrust_power(36.4) < 260  # measured 203 W at full forward thrust, 12 V
    if not T200_CSV.exists():
        pytest.skip("shared T-200 data absent")
    fit = fit_t200_power(T200_CSV)
    for d in ("forward", "reverse"):
        assert np.allclose(fit[d], T200_POWER_12V[d], rtol=1e-3)


def test_safe_controller_never_throws():
    def bad(t, x):
        if t > 0.1:
            raise RuntimeError("solver exploded")
        return np.array([1.0, 1.0, 50.0, np.nan if t > 0.05 else 0.0])

    safe = SafeController(bad, -np.ones(4) * 28.61, np.ones(4) * 36.42)
    with pytest.warns(RuntimeWarning):
        assert np.allclose(safe(0.0, np.zeros(12)), [1, 1, 36.42, 0])
        assert np.allclose(safe(0.06, np.zeros(12)), [1, 1, 36.42, 0])  # non-finite -> last good
        assert np.allclose(safe(0.2, np.zeros(12)), [1, 1, 36.42, 0])
    assert safe.fallbacks == 2 and "solver exploded" in safe.last_error


def test_text_table_wraps_a_long_failure_reason_instead_of_cutting_it():
    """The whole reason is printed, wrapped between words under the status column (issue 42: ``...cg_cb_o``)."""
    from udrobot_ctrl.control.compare import STATUS_WIDTH, text_table

    status = ("design failed: ValueError: model 'tartan-auv-nominal+cg_cb_offset+thruster_lag' has a thruster_lag "
              "effect: the casadi plant works on the static plant (no actuator states) and does not represent it")
    rows = [{"controller": "lqr", "design": "a.json", "plant": "b.json", "status": status},
            {"controller": "pid", "design": "a.json", "plant": "b.json", "status": "ok"}]
    body = text_table(rows).splitlines()[2:]
    col = body[0].index("design failed")
    wrapped = [body[0][col:]] + [line[col:] for line in body[1:-1]]
    assert all(line[:col].strip() == "" for line in body[1:-1]), body  # continuation lines: indented, no cells
    assert " ".join(wrapped) == status
    assert all(len(part) <= STATUS_WIDTH for part in wrapped) and len(wrapped) > 1
    assert body[-1].startswith("pid ") and body[-1].endswith("  ok")


def _contract_before(result: dict) -> dict:
    """The ``--json`` document as ``contract_json`` built it from compare()'s dict before compare() returned a
    :class:`~udrobot_ctrl.control.compare.Comparison` (issue 60 item 3), kept verbatim as the reference."""
    from udrobot_ctrl.control.compare import _finite

    return _finite({"models": list(result["models"]),
            "results": [{k: r.get(k) for k in RESULT_KEYS} for r in result["results"]],
            "ekf": [{"filter_model": e["filter_model"], "plant": e["plant"], "rmse": dict(e["rmse"]),
                     "nis_mean": e["nis_mean"]} for e in result["ekf"]]})


@pytest.mark.slow
def test_comparison_gives_the_json_and_text_compare_gave_as_a_dict(tmp_path, capsys):
    """compare() returns a Comparison whose ``to_json()`` is the document the dict gave and whose ``summary()`` is
    what the command printed; the CLI's --json file, compare_full.json and stdout are built from it unchanged."""
    from udrobot_ctrl.control.compare import TABLE_LEGEND, Comparison, _finite, compare, text_table

    models, controllers = ("cfd:chin", "free_decay:morison"), ("lqr",)
    res = compare(models, controllers, quick=True, workers=1, progress=False)
    assert isinstance(res, Comparison) and res.models == models and res.mission_name.endswith("quick")
    assert [(r["design"], r["plant"]) for r in res.results] == [(a, b) for a in models for b in models]
    before = {"models": list(res.models), "results": res.results, "ekf": res.ekf, "skipped": res.skipped,
              "mission": {"name": res.mission_name, "t_final": res.mission_t_final}, "wall_s": res.wall_s}
    assert res.to_json() == _contract_before(before)
    # compare_full.json as write_outputs wrote the dict (less its trajectories): same keys, order and values
    assert json.dumps(res.full_json(), indent=1, default=float) == json.dumps(_finite(before), indent=1, default=float)
    assert res.summary() == "\n".join([text_table(res.results, res.ekf), TABLE_LEGEND])

    js = tmp_path / "r.json"
    assert main(["compare", "--quick", "--models", ",".join(models), "--controllers", "lqr", "--workers", "1",
                 "--json", str(js)]) == 0
    printed = capsys.readouterr().out.splitlines()
    doc = json.loads(js.read_text())
    assert doc == res.to_json()  # the flights are deterministic: the same numbers from the command
    assert "\n".join(printed[:-2]) == res.summary()
    assert printed[-2].startswith(f"{len(res.results)} controller runs, {len(res.ekf)} EKF runs in ")
    assert printed[-1] == f"wrote {js}"
