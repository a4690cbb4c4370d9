"""ArduSub gains designed on a model (udrobot_ctrl/autopilot/design.py) and the QGroundControl .params file."""
from __future__ import annotations

import math

import numpy as np
import pytest

from udrobot_ctrl.ardusub.params import ArduSubParameters
from udrobot_ctrl.autopilot.check_flight import check_flight, checklist_markdown
from udrobot_ctrl.autopilot.design import (
    LOOP_PARAMETERS,
    STEP_SIZE,
    ArduSubDesign,
    LoopDesign,
    SpecFailure,
    Specification,
    StepMetrics,
    StepResponse,
    _Robustness,
    design_ardusub,
    gain_values,
    layout_frame,
    linear_search,
    model_spread,
    step_flight,
    vehicle_frame,
    with_motor_lag,
)
from udrobot_ctrl.autopilot.firmware import (
    ASSUMED_FIRMWARE,
    UnverifiedConversion,
    firmware_of_run,
    from_firmware,
    gain_range,
    parse_firmware,
    range_violations,
    to_firmware,
)
from udrobot_ctrl.autopilot.loop_margins import Margins, margins_from_response
from udrobot_ctrl.autopilot.motors import frame
from udrobot_ctrl.autopilot.qgc_params import format_params, parse_params, read_params
from udrobot_ctrl.cli.design import _start_params
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.dynamics.effects import parse_effects
from udrobot_ctrl.parallel import JOBS_ENV
from udrobot_ctrl.sensitivity.parameters import default_space
from udrobot_ctrl.vehicle import load_model, write_model_file

#: ArduCopter's ranges, which the design used before (the issue's runaway was measured against them)
COPTER_RANGES = {"ATC_ANG_RLL_P": (3.0, 12.0), "ATC_ANG_PIT_P": (3.0, 12.0), "ATC_ANG_YAW_P": (3.0, 12.0),
                 "ATC_RAT_RLL_P": (0.01, 0.5), "ATC_RAT_RLL_I": (0.01, 2.0), "ATC_RAT_PIT_P": (0.01, 0.5),
                 "ATC_RAT_PIT_I": (0.01, 2.0), "ATC_RAT_YAW_P": (0.1, 2.5), "ATC_RAT_YAW_I": (0.01, 1.0),
                 "PSC_POSZ_P": (1.0, 3.0), "PSC_VELZ_P": (1.0, 8.0), "PSC_ACCZ_P": (0.2, 1.5), "PSC_ACCZ_I": (0.0, 3.0)}
V46, V47 = parse_firmware("4.5.1"), parse_firmware("ArduSub V4.7.0 (abc)")


@pytest.fixture(scope="module")
def heavy_depth_yaw():
    """The depth and yaw loops designed on bluerov2-heavy from ArduSub's defaults (small search)."""
    return design_ardusub("bluerov2-heavy", loops=("depth", "yaw"), max_evaluations=4)


# ------------------------------------------------------------------------------------------------ ranges, names
def test_ranges_are_ardusubs_own():
    """AC_AttitudeControl_Sub.cpp / AC_AttitudeControl.cpp @Range{Sub} / AC_PosControl.cpp, not ArduCopter's."""
    assert gain_range("ATC_RAT_RLL_P", V46)[:2] == (0.0, 0.30)
    assert gain_range("ATC_RAT_RLL_I", V46)[:2] == (0.0, 0.5)
    assert gain_range("ATC_RAT_YAW_P", V46)[:2] == (0.0, 0.50)
    assert gain_range("ATC_RAT_YAW_I", V46)[:2] == (0.0, 0.05)
    assert gain_range("ATC_ANG_YAW_P", V46)[:2] == (0.0, 6.0)
    assert gain_range("PSC_ACCZ_P", V46)[:2] == (0.2, 1.5)
    # 4.7: PSC_D_ACC_P 0.010-0.250 is PSC_ACCZ_P 0.1-2.5 in the canonical units
    assert gain_range("PSC_ACCZ_P", V47)[:2] == pytest.approx((0.1, 2.5))
    # the issue's files: ATC_RAT_YAW_P 2.5, ATC_RAT_YAW_I 0.576, ATC_RAT_RLL_I 2 are all refused
    bad = range_violations({"ATC_RAT_YAW_P": 2.5, "ATC_RAT_YAW_I": 0.576, "ATC_RAT_RLL_I": 2.0,
                            "ATC_RAT_PIT_P": 0.2}, V46)
    assert {v.name for v in bad} == {"ATC_RAT_YAW_P", "ATC_RAT_YAW_I", "ATC_RAT_RLL_I"}
    assert "AC_AttitudeControl_Sub.cpp" in bad[0].sentence() and "documented range" in bad[0].sentence()
    # a 4.7 range is said in the 4.7 name and units
    (v,) = range_violations({"PSC_ACCZ_P": 3.0}, V47)
    assert "PSC_D_ACC_P = 0.3" in v.sentence() and "0.01-0.25" in v.sentence()


@pytest.mark.parametrize("firmware", [V46, V47, ASSUMED_FIRMWARE])
def test_params_file_round_trip_per_firmware(tmp_path, firmware):
    """Written with a version's names and units, read back with the same version's names: the same gains."""
    gains = {"PSC_POSZ_P": 1.5, "PSC_VELZ_P": 6.0, "PSC_ACCZ_P": 0.8, "PSC_ACCZ_I": 1.2, "PSC_VELZ_IMAX": 800.0,
             "PSC_ACCZ_IMAX": 700.0, "ATC_RAT_YAW_P": 0.3, "ATC_ANG_RLL_P": 5.0}
    path = tmp_path / "gains.params"
    path.write_text(format_params(to_firmware(gains, firmware)))
    written = read_params(path)
    if firmware.renamed:
        assert not any(k.startswith(("PSC_POSZ", "PSC_VELZ", "PSC_ACCZ")) for k in written)
        # AC_PosControl::convert_parameters: ACCZ P/I x 0.1, VELZ_IMAX x 0.01, ACCZ_IMAX x 0.001, POSZ_P unscaled
        assert written["PSC_D_ACC_P"] == pytest.approx(0.08) and written["PSC_D_ACC_I"] == pytest.approx(0.12)
        assert written["PSC_D_VEL_IMAX"] == pytest.approx(8.0) and written["PSC_D_ACC_IMAX"] == pytest.approx(0.7)
        assert written["PSC_D_POS_P"] == pytest.approx(1.5) and written["PSC_D_VEL_P"] == pytest.approx(6.0)
    else:
        assert written == pytest.approx(gains)
    back = from_firmware(written, firmware)
    assert back == pytest.approx(gains)
    # the SI gains the emulation flies are the same whatever the version's names
    si = ArduSubParameters.from_log_params(back)
    assert si.depth.accel.p == pytest.approx(0.08) and si.depth.pos_p == pytest.approx(1.5)


def test_unverified_rescale_is_not_written_for_4_7():
    """PSC_ACCZ_FF: moved unscaled by convert_parameters, documented as x 0.1: refused for 4.7, fine for 4.5."""
    assert to_firmware({"PSC_ACCZ_FF": 0.1}, V46) == {"PSC_ACCZ_FF": 0.1}
    with pytest.raises(UnverifiedConversion, match="PSC_D_ACC_FF"):
        to_firmware({"PSC_ACCZ_FF": 0.1}, V47)


def test_firmware_read_from_the_runs_sidecar():
    assert firmware_of_run({"firmware": "ArduSub V4.7.0 (1a2b3c)"}).renamed
    fw = firmware_of_run({"notes": "text: ArduSub V4.1.2 (5e6f)\nother"})
    assert (fw.major, fw.minor, fw.patch) == (4, 1, 2) and not fw.renamed
    assert firmware_of_run({"notes": "no version"}) is None
    with pytest.raises(ValueError, match="expected a version"):
        parse_firmware("latest")


# ------------------------------------------------------------------------------------------------ margins
def test_margins_of_an_integrator_with_delay():
    """L = K exp(-sT) / s: crossover K, phase margin 90 deg - K T, gain margin 20 log10(pi / (2 K T))."""
    K, T = 4.0, 0.05
    w = np.logspace(-2, 3, 20000)
    pm, gm, wc = margins_from_response(w, K * np.exp(-1j * w * T) / (1j * w))
    assert wc == pytest.approx(K, rel=1e-3)
    assert pm == pytest.approx(90.0 - math.degrees(K * T), abs=0.1)
    assert gm == pytest.approx(20 * math.log10(math.pi / (2 * K * T)), abs=0.05)


def test_filters_and_delays_stop_the_runaway_to_the_range_end():
    """On ArduCopter's wide ranges (what the design used) and a loop without filters, delays and motor lag, the
    search for the highest bandwidth takes most gains to the range's end (the issue: nine of thirteen); with the
    vehicle's IMU and PID filters, motor lag and loop delays the margins stop it first."""
    vehicles, _ = model_spread("bluerov2-heavy")
    fr, _ = vehicle_frame(vehicles[0])
    old = gain_values(ArduSubParameters.defaults(100.0))
    spec = Specification()
    counts = {}
    for ideal in (True, False):
        robust = _Robustness(vehicles, fr, {}, 400.0)
        if ideal:
            robust.timings = tuple(t.ideal() for t in robust.timings)
        at_end, binding = 0, []
        for loop, names in LOOP_PARAMETERS.items():
            got = linear_search(loop, robust, old, {n: old[n] for n in names}, spec, ASSUMED_FIRMWARE,
                                iterations=200, ranges=COPTER_RANGES)
            ends = [n for n in names if math.isclose(got[n], COPTER_RANGES[n][1])]
            at_end += len(ends)
            margins = robust.margins({**old, **got}, loop)
            assert all(m.meets(spec.phase_margin_deg, spec.gain_margin_db) for m in margins), (loop, got)
            if len(ends) < len(names) - 1:  # stopped inside the range: a margin holds it
                binding.append(min(min(m.phase_margin_deg - spec.phase_margin_deg,
                                       3 * (m.gain_margin_db - spec.gain_margin_db)) for m in margins))
        counts[ideal] = (at_end, binding)
    n = sum(len(v) for v in LOOP_PARAMETERS.values())
    assert counts[True][0] > n / 2
    assert counts[False][0] < n / 2 < counts[True][0]
    # where the realistic loop stopped inside the range, a margin is within a search step of the specification
    assert counts[False][1] and all(b < 12.0 for b in counts[False][1])


# ------------------------------------------------------------------------------------------------ .params
def test_params_file_round_trips_names_and_units(tmp_path):
    """Only the changed gains, ArduSub's names, ArduSub's units (PSC_ACCZ_P 0.5 is 0.05 throttle per m/s^2 in SI),
    QGroundControl's tab-separated lines; read back equal, and read by from_log_params into the same SI gains."""
    changed = {"PSC_ACCZ_P": 0.75, "PSC_ACCZ_I": 1.5, "ATC_RAT_YAW_P": 0.36, "ATC_ANG_YAW_P": 7.5,
               "PSC_POSZ_P": 1.414, "SCHED_LOOP_RATE": 400}
    path = tmp_path / "gains.params"
    path.write_text(format_params(changed, comments=["test"]))
    text = path.read_text()
    assert text.startswith("# Onboard parameters for Vehicle 1\n")
    assert "# # Vehicle-Id Component-Id Name Value Type" in text
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    assert len(lines) == len(changed)
    fields = {ln.split("\t")[2]: ln.split("\t") for ln in lines}
    assert fields["PSC_ACCZ_P"] == ["1", "1", "PSC_ACCZ_P", "0.75", "9"]   # REAL32
    assert fields["SCHED_LOOP_RATE"][3:] == ["400", "4"]                  # INT16
    back = read_params(path)
    assert back == pytest.approx(changed)
    si = ArduSubParameters.from_log_params(back)
    assert si.depth.accel.p == pytest.approx(0.075)      # 0.1 x ArduSub's PSC_ACCZ_P
    assert si.depth.accel.i == pytest.approx(0.15)
    assert si.attitude.rate_yaw.p == pytest.approx(0.36)
    assert si.attitude.angle_p[2] == pytest.approx(7.5)
    assert gain_values(si)["PSC_ACCZ_P"] == pytest.approx(0.75)  # and back to ArduSub's units


def test_params_file_errors_name_the_line():
    with pytest.raises(ValueError, match="line 2"):
        parse_params("# header\n1\t1\tPSC_POSZ_P\n")
    with pytest.raises(ValueError, match="upper case"):
        format_params({"psc_posz_p": 1.0})
    with pytest.raises(ValueError, match="finite"):
        format_params({"PSC_POSZ_P": math.nan})


# ------------------------------------------------------------------------------------------------ frames, spread
def test_layout_frame_of_the_udrobot_has_no_pitch():
    """Two horizontal (yaw, forward) and two vertical thrusters (roll, throttle): no pitch factor."""
    fr = layout_frame(load_model("pendulum:chin"))
    assert fr.name == "CUSTOM" and fr.config == 7
    assert "pitch" in fr.unobservable and "lateral" in fr.unobservable
    np.testing.assert_allclose(np.abs(fr.factors[:, [0, 2, 3, 4]]).max(axis=0), 1.0)


def test_layout_frame_matches_the_heavy_table_signs():
    """The pseudo-inverse of the BlueROV2 Heavy's layout has the sign pattern of ArduSub's VECTORED_6DOF table."""
    v = load_model("bluerov2-heavy")
    table, mine = frame("VECTORED_6DOF").factors, layout_frame(v).factors
    for j in (2, 3, 4, 5):   # yaw, throttle, forward, lateral
        nz = table[:, j] != 0
        assert np.all(np.sign(mine[nz, j]) == np.sign(table[nz, j]))
    assert vehicle_frame(v)[0].name == "VECTORED_6DOF"


def test_spread_of_each_kind():
    vs, names = model_spread("pendulum:chin")
    assert len(vs) == 5 and names[0].startswith("pendulum:chin")
    vs, names = model_spread("bluerov2-heavy")
    assert len(vs) == 3 and "Wu2018" in names[1]
    assert vs[1].added_mass[2, 2] == pytest.approx(14.57)


def test_spread_of_a_corrected_model_holds_the_nominal(tmp_path):
    """A corrected model (diagnose --out-model: coefficients plus effects) is checked with and without its effects."""
    corrected = load_model("bluerov2-heavy").with_changes(
        effects=parse_effects([{"name": "thruster_lag", "params": {"T_lag_s": 0.15}}]))
    path = tmp_path / "corrected.json"
    write_model_file(corrected, path)
    vs, names = model_spread(str(path))
    assert vs[0].effects and not vs[-1].effects
    assert "without its 1 effect" in names[-1]


# ------------------------------------------------------------------------------------------------ the design
def _assert_written_gains_are_sound(d, firmware=ASSUMED_FIRMWARE):
    """Every designed gain inside ArduSub's range; a design that may be written keeps the margins everywhere."""
    new = {n: v for lp in d.loops.values() if lp.designed for n, v in lp.new.items()}
    assert not range_violations(new, firmware), range_violations(new, firmware)
    for lp in d.loops.values():
        if "cannot be commanded" not in lp.note:
            assert lp.margins_old, lp.loop  # the current gains' margins are reported beside the new ones
        if lp.designed:
            assert len(lp.margins_new) == len(lp.margins_old)
    if d.safe:
        for lp in d.loops.values():
            if lp.designed:
                assert all(m.meets(d.spec.phase_margin_deg, d.spec.gain_margin_db) for m in lp.margins_new)
    else:
        assert all(isinstance(f, SpecFailure) and f.sentence() for f in d.failures)


def _step(model, iae, settling=3.0, overshoot=5.0):
    t = np.linspace(0.0, 12.0, 13)
    return StepResponse("depth", model, t, np.zeros_like(t), 2.0, 3.0, overshoot, settling, iae, 0.5, 0.0, True)


def _design(new_iae, old_iaes=(1.0, 1.3, 1.1), margins_pm=60.0, failures=()):
    models = ("m0", "m1", "m2")
    old = tuple(_step(m, i) for m, i in zip(models, old_iaes))
    new = tuple(_step(m, new_iae if k == 0 else i) for k, (m, i) in enumerate(zip(models, old_iaes)))
    margins_old = tuple(Margins("depth", m, margins_pm, 12.0, 2.0, True) for m in models)
    margins_new = tuple(Margins("depth", m, 60.0, 12.0, 2.0, True) for m in models)
    loop = LoopDesign("depth", True, {"PSC_POSZ_P": 1.0}, {"PSC_POSZ_P": 1.2}, old[0], new[0], old, new,
                      margins_old, margins_new, 3)
    return ArduSubDesign("m0", "VECTORED", Specification(), {"depth": loop}, {}, models, tuple(failures), (), 100.0)


def test_verdict_says_when_the_current_gains_are_fine():
    """Current gains that meet the specification, new ones better by less than the IAE varies over the spread
    (0.3 s here): 'changing them buys little'; better by more: 'improves'; a failure of the new ones: 'refused'."""
    code, sentence = _design(new_iae=0.9).verdict()
    assert code == "current_fine" and "buys little" in sentence
    assert _design(new_iae=0.5).verdict()[0] == "improves"
    # the current gains lose their margins: the new ones are worth loading even for a small step improvement
    assert _design(new_iae=0.9, margins_pm=30.0).verdict()[0] == "improves"
    refused = _design(new_iae=0.5, failures=(SpecFailure("phase_margin", "depth", "m1", 40.0, 45.0),))
    code, sentence = refused.verdict()
    assert code == "refused" and "phase margin 40.0 deg on m1, below the 45 deg required" in sentence
    with pytest.raises(ValueError, match="unknown failure code"):
        SpecFailure("too_slow", "depth")


@pytest.mark.slow
def test_heavy_design_respects_ranges_and_margins(heavy_depth_yaw):
    d = heavy_depth_yaw
    _assert_written_gains_are_sound(d)
    assert set(d.changed_params()) <= set(LOOP_PARAMETERS["depth"]) | set(LOOP_PARAMETERS["yaw"])
    code, sentence = d.verdict()
    assert code in ("current_fine", "improves", "refused") and sentence
    # ArduSub's defaults on this model: the yaw angle loop has less than 45 deg (ANG_YAW_P 6 against a ~5 rad/s
    # rate loop behind a 5 Hz target filter and the motor lag): reported as a failure of the current gains
    assert any(f.code == "phase_margin" and f.loop == "yaw" for f in d.current_failures())
    # the new gains flown again through the design's parameters (and the motor lag of its flights) give the same
    # prediction
    vehicle = with_motor_lag(load_model("bluerov2-heavy"), d.timing.motor_tau_s)
    fr, _ = vehicle_frame(vehicle)
    again = step_flight(vehicle, d.parameters(), fr, "depth", spec=d.spec)
    assert again.iae == pytest.approx(d.loops["depth"].nominal_new.iae, rel=1e-9)


@pytest.mark.slow
def test_check_flight_commands_the_designed_steps(heavy_depth_yaw):
    """One doublet per designed loop in the mode that closes it; the stick inputs give the design's steps through
    ArduSub's pilot mapping (yaw: ACRO_YAW_P x stick rate; depth: PILOT_SPEED beyond THR_DZ); each level is held
    for twice the predicted settling."""
    d = heavy_depth_yaw
    ms = {m.loop: m for m in check_flight(d, STEP_SIZE)}
    assert set(ms) == {"depth", "yaw"}
    p = d.parameters()
    yaw = ms["yaw"]
    assert yaw.mode == "STABILIZE"
    rate = yaw.stick_pct / 100 * 4500 * p.pilot.acro_yaw_p / 100  # deg/s
    assert yaw.stick_s * rate == pytest.approx(45.0)
    depth = ms["depth"]
    assert depth.mode == "ALT_HOLD" and depth.amplitude == pytest.approx(1.0)
    dz = p.pilot.throttle_deadzone / 500
    assert depth.stick_s * p.depth.speed_down_effective * (0.5 - dz) / (1 - dz) == pytest.approx(1.0)
    for m in ms.values():
        settle = d.loops[m.loop].nominal_new.settling_s or d.spec.settling_s(m.loop)
        assert m.hold_s >= 2 * settle
    text = checklist_markdown(d, list(ms.values()))
    assert text.count("- [ ]") == 2 and "diagnose" in text
    assert ("not written" in text) == (not d.safe)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["bluerov2", "pendulum:chin"])
def test_design_respects_ranges_and_margins(model):
    """BlueROV2 (VECTORED: no pitch column, pitch not designed) and the UDrobot (CUSTOM frame)."""
    d = design_ardusub(model, loops=("depth", "roll", "pitch"), max_evaluations=3)
    _assert_written_gains_are_sound(d)
    assert not d.loops["pitch"].designed and "pitch" in d.loops["pitch"].note
    assert not set(d.changed_params()) & set(LOOP_PARAMETERS["pitch"])


@pytest.mark.slow
def test_failing_specification_is_not_written_without_force(tmp_path, capsys):
    """A depth step demanded in 0.5 s cannot be met: the command says which specification failed, writes nothing,
    and with --force writes the file in the named firmware's names (4.7: PSC_D_*)."""
    out = tmp_path / "gains.params"
    args = ["design", "ardusub", "--model", "bluerov2", "--out", str(out), "--loops", "depth",
            "--evaluations", "2", "--depth-settling", "0.5", "--firmware", "4.7"]
    code = main(args)
    text = capsys.readouterr().out
    assert code == 1 and not out.exists()
    assert "NOT MET: depth: " in text and "the specification is 0.5 s" in text and "--force" in text
    assert "margins (phase deg / gain dB; current -> new" in text and "verdict:" in text
    assert main(args + ["--force"]) == 0
    written = read_params(out)
    assert written and all(not k.startswith(("PSC_POSZ", "PSC_VELZ", "PSC_ACCZ")) for k in written)
    assert "SPECIFICATION NOT MET" in out.read_text()
    back = from_firmware(written, V47)
    assert not range_violations(back, V47)


def test_step_flight_reports_saturation():
    """A huge depth step with large speed limits drives the vertical thrusters to their limits: counted."""
    params = ArduSubParameters.from_log_params({"PILOT_SPEED_UP": 500.0, "PILOT_SPEED_DN": 500.0,
                                                "PILOT_ACCEL_Z": 500.0, "PSC_POSZ_P": 3.0}, 100.0)
    v = load_model("bluerov2")
    r = step_flight(v, params, vehicle_frame(v)[0], "depth", size=3.0, t_final=4.0)
    assert r.saturation_s > 0 and r.max_command == pytest.approx(1.0, abs=1e-6)
    assert not r.meets(Specification(depth_settling_s=100.0, depth_overshoot_pct=100.0))


def test_start_from_a_runs_sidecar(tmp_path):
    """--from RUN.csv reads the sidecar's logged parameters over the estimated ones (params.run_log_params)."""
    run = tmp_path / "dive.csv"
    run.write_text("t\n0\n")
    (tmp_path / "dive.json").write_text(
        '{"format": "udrobot-run/1", "autopilot_params": {"PSC_POSZ_P": 1.5}, '
        '"autopilot_params_estimated": {"PSC_POSZ_P": 9.0, "ATC_RAT_YAW_P": 0.2, "SCHED_LOOP_RATE": 200}}')
    params, origin, firmware = _start_params(run)
    assert params == {"PSC_POSZ_P": 1.5, "ATC_RAT_YAW_P": 0.2, "SCHED_LOOP_RATE": 200}
    assert "estimated" in origin and "ATC_RAT_YAW_P" in origin and firmware is None
    # a 4.7 log: its PSC_D_* names read back to the canonical ones, the version taken from the sidecar
    (tmp_path / "new.csv").write_text("t\n0\n")
    (tmp_path / "new.json").write_text('{"format": "udrobot-run/1", "firmware": "ArduSub V4.7.1 (deadbeef)", '
                                       '"autopilot_params": {"PSC_D_ACC_P": 0.06, "PSC_D_POS_P": 2.0}}')
    params, _, firmware = _start_params(tmp_path / "new.csv")
    assert firmware.renamed and params == pytest.approx({"PSC_ACCZ_P": 0.6, "PSC_POSZ_P": 2.0})
    (tmp_path / "bare.csv").write_text("t\n0\n")
    (tmp_path / "bare.json").write_text('{"format": "udrobot-run/1"}')
    with pytest.raises(ValueError, match="no autopilot_params"):
        _start_params(tmp_path / "bare.csv")


def test_step_metrics_are_the_same_over_the_cores(monkeypatch):
    """The sensitivity's flights spread over two workers (fork_map) give each sample and loop exactly the numbers
    of the serial evaluation, in the samples' order; a sample outside its range is an error row, not a flight."""
    v = load_model("bluerov2")
    space = default_space(v).subset(["roll.added_mass_scale", "yaw.linear_damping_scale"])
    lo, hi = np.asarray(space.bounds, float).T
    nominal = np.asarray(space.nominal, float)
    X = np.array([nominal, [hi[0], nominal[1]], [nominal[0], lo[1]], [-1.0, nominal[1]]])
    ev = StepMetrics(space, ArduSubParameters.defaults(100.0), vehicle_frame(v)[0], loops=("roll", "yaw"))
    got = {}
    for jobs in ("1", "2"):
        monkeypatch.setenv(JOBS_ENV, jobs)
        got[jobs] = ev(X)
    serial, spread = got["1"], got["2"]
    assert serial["error"] == spread["error"] and serial["error"][:3] == ["", "", ""] and serial["error"][3]
    for k, col in serial.items():
        if k != "error":
            np.testing.assert_array_equal(col, spread[k])
            assert np.all(np.isfinite(col[:3])) or k.endswith("settling_s")
            assert np.isnan(col[3])
    # the samples differ physically: more roll added mass slows the roll step (a larger IAE)
    assert spread["roll_iae_s"][1] > spread["roll_iae_s"][0]
