"""``simulate --windows``: the diagnoser's windowed replay and gap for any model, from the command line."""
import json

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.io.runlog import write_run
from udrobot_ctrl.vehicle import load_model, write_model_file

RATE = 20.0  # Hz, logging and command rate
CABLE = PlantEffect("tether_drag", {"k_quadratic_N_s2_per_m2": 30.0, "k_linear_N_s_per_m": 0.0,
                                    "cable_azimuth_rad": 0.0, "cable_elevation_rad": np.pi / 2})


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 40 s run of surge/yaw/heave thrust sweeps flown (open loop, no noise) by UDrobot with a tether, and the model
    files with and without the tether."""
    d = tmp_path_factory.mktemp("windows")
    nominal = load_model("pendulum:chin")
    tethered = nominal.with_changes(effects=(CABLE,), name="pendulum:chin+tether_drag")
    paths = {"nominal": d / "nominal.json", "tethered": d / "tethered.json"}
    write_model_file(nominal, paths["nominal"])
    write_model_file(tethered, paths["tethered"])
    t = np.arange(0.0, 40.0, 1.0 / RATE)
    s = np.sin(2 * np.pi * t / 9.0)
    f = np.column_stack([20 * s + 10, 20 * s + 8, 6 * np.cos(2 * np.pi * t / 7.0), 6 * np.cos(2 * np.pi * t / 7.0)])
    x0 = np.zeros(12)
    x0[2] = 1.0
    res = simulate(tethered, x0, t[-1] + 1.0 / RATE, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    xs = res.x[::5][: t.size]
    paths["run"] = write_run(d / "run.csv", t, {c: xs[:, i] for i, c in enumerate(STATE_NAMES)}, "thrust", f)
    return paths


def test_the_model_that_flew_the_run_replays_it_and_the_nominal_does_not(files, tmp_path):
    """Noise-free data from the tethered plant: replayed with the tethered model only the smoothing of the window's
    initial velocities (Savitzky-Golay, 0.8 s) and the integration step differ, a small fraction of the channels'
    spread; the nominal model misses ~30 u^2 N of cable drag and drifts away within each 8 s window."""
    out = tmp_path / "gap.json"
    assert main(["simulate", "--model", str(files["tethered"]), "--windows", "--input", str(files["run"]),
                 "--json", str(out)]) == 0
    g = json.loads(out.read_text())
    assert g["effects"] == ["tether_drag"] and g["window_s"] == 8.0 and g["runs"] == ["run.csv"]
    assert "u" in g["scored"] and g["value"] < 0.02
    assert main(["simulate", "--model", str(files["nominal"]), "--windows", "8", "--input", str(files["run"]),
                 "--json", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["per_channel"]["u"] > 10 * g["per_channel"]["u"]


def test_out_writes_the_windowed_replay_on_the_runs_grid(files, tmp_path):
    from udrobot_ctrl.io.runlog import read_run

    out = tmp_path / "sim.csv"
    assert main(["simulate", "--model", str(files["tethered"]), "--windows", "8", "--input", str(files["run"]),
                 "--out", str(out)]) == 0
    sim, run = read_run(out), read_run(files["run"])
    assert sim.n == run.n and np.allclose(sim.t, run.t)
    u, u_run = sim.channels["u"], run.channels["u"]
    ok = np.isfinite(u)
    assert ok.mean() > 0.9  # consecutive windows cover the run but for a tail shorter than a quarter window
    assert np.sqrt(np.mean((u[ok] - u_run[ok]) ** 2)) < 0.02 * np.std(u_run)


@pytest.mark.parametrize("extra, message", [
    (["--json", "g.json"], "add --windows"),
    (["--windows", "0"], "seconds > 0"),
    (["--windows", "8", "--out", "a.csv"], "one simulated run"),
])
def test_bad_windowed_options_are_refused(files, tmp_path, capsys, extra, message):
    runs = [str(files["run"])] * (2 if "--out" in extra else 1)
    argv = ["simulate", "--model", str(files["nominal"]), "--input", *runs]
    argv += [a if a.startswith("--") or a[0].isdigit() else str(tmp_path / a) for a in extra]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "a.csv").exists() and not (tmp_path / "g.json").exists()
