"""Fast nominal-plant runs logged with a chosen sensor set, for the smoother and identifiability tests.

The vehicle is the nominal model itself (no withheld effect), flown open loop through surge, heave and yaw
steps, so that what the smoother reconstructs can be compared with the exact state (``truth``). Sensor noise
(std, assumed typical of the class of sensor): depth 5 mm, attitude 3 mrad (heading 5 mrad), gyro 5 mrad/s,
accelerometer 0.03 m/s^2 with a constant bias of (0.02, -0.015, 0.025) m/s^2, DVL 8 mm/s, USBL 3 cm.
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.dynamics.plant import plant_parameters, state_derivative
from udrobot_ctrl.dynamics.plant_casadi import rk4_step_function
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model

from .truth import specific_force

NOISE = {"x": 0.03, "y": 0.03, "z": 0.005, "phi": 0.003, "theta": 0.003, "psi": 0.005, "u": 0.008, "v": 0.008,
         "w": 0.008, "p": 0.005, "q": 0.005, "r": 0.005, "ax": 0.03, "ay": 0.03, "az": 0.03}
ACCEL_BIAS = np.array([0.02, -0.015, 0.025])
STATE = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
STOCK = ("z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az")


def commands(t, f_max):
    """Open-loop thrusts (n, 4) of UDrobot's layout (two surge, two vertical): surge steps both ways, heave
    pulses around hover, yaw by differential surge thrust and a roll pulse."""
    n = t.size
    f = np.zeros((n, 4))
    surge = np.where((t % 20) < 8, 8.0, np.where((t % 20) < 12, -5.0, 2.0))
    yaw = 0.4 * np.sign(np.sin(2 * np.pi * t / 13.0))
    f[:, 0], f[:, 1] = surge + yaw, surge - yaw
    heave = 4.0 * np.sign(np.sin(2 * np.pi * t / 9.0))
    roll = np.where((t % 15) < 2, 0.3, 0.0)
    f[:, 2], f[:, 3] = heave - roll, heave + roll
    return np.clip(f, -0.8 * f_max, 0.8 * f_max)


def simulate(duration=60.0, rate=20.0, seed=0, sensors=STOCK, model="pendulum:chin"):
    """One open-loop run of the nominal plant logged with ``sensors`` (channel names).

    Returns (Run, truth) with truth a dict of the exact ``x ... r`` and ``nu_dot`` (n, 6) at the logged samples.
    """
    rng = np.random.default_rng(seed)
    p = plant_parameters(load_model(model))
    dt = 1.0 / rate
    t = np.arange(0.0, duration, dt)
    f = commands(t, p.f_max)
    x = np.zeros(12)
    x[2] = 1.0
    xs, nds = np.empty((t.size, 12)), np.empty((t.size, 6))
    sub = 2
    step = rk4_step_function(p, dt / sub, "thrust")
    for k in range(t.size):
        xs[k] = x
        nds[k] = state_derivative(x, p.T @ f[k], p)[6:]
        for _ in range(sub):
            x = np.asarray(step(x, f[k])).ravel()
    truth = {c: xs[:, i] for i, c in enumerate(STATE)}
    truth["nu_dot"] = nds
    sf = specific_force(xs, nds) + ACCEL_BIAS
    clean = dict(truth)
    clean.update({"ax": sf[:, 0], "ay": sf[:, 1], "az": sf[:, 2]})
    ch = {c: clean[c] + rng.normal(0.0, NOISE[c], t.size) for c in sensors}
    meta = {"format": "udrobot-run/1", "vehicle": "udrobot", "water_density": 1000.0, "seabed_depth": 3.0}
    run = Run(path=f"nominal_{seed}.csv", t=t, channels=ch, input_kind="thrust", inputs=f, metadata=meta)
    return run, truth
