"""Synthetic launches following Cely 2019's protocol, with known coefficients (for tests and the demo).

Spring (sec. 3.2.1): 6 launches at each of 10, 20, 30, 40 mm per axis, the 0.97 kg / 344,868 mm^3
model on K = 63.6 N/m, LX-EP-40 encoder at 2.45 counts/mm (quantised) with 0.2 mm white noise
(assumed: the stated 0.4 mm accuracy read as +-2 sigma), sampled at 100 Hz (assumed; the paper
does not state the rate). Pendulum (sec. 3.3.1): 6 launches at 2.5, 5, 10, 15 deg per axis, the
0.146 kg / 107,597 mm^3 PVC model, IMU attitude at 100 Hz with 0.02 deg white noise (assumed for
an EKF attitude estimate of a still IMU).

Truth coefficients default to the paper's values brought to model scale with the laws of
:mod:`identification.similitude` (C_m unchanged, K_Q x lambda^2, K_L x lambda); the model's
projected areas are the full-size ones of ``models/udrobot.toml`` times lambda^2. Each launch starts
with a 0.5 s hold at the launch position, then is released from rest.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.decay import simulate_decay
from udrobot_files.output import open_atomic

AXES = ("surge", "sway", "heave")
FULL_AREA = (0.04938, 0.09039, 0.09039)  # m^2, derived from Table 5 (models/udrobot.toml)
SPRING_AMPLITUDES = (0.010, 0.020, 0.030, 0.040)  # m, Cely 2019 sec. 3.2.1
PENDULUM_AMPLITUDES = tuple(math.radians(a) for a in (2.5, 5.0, 10.0, 15.0))  # rad, sec. 3.3.1
REPEATS = 6
IMU_NOISE = math.radians(0.02)  # rad, white noise of the IMU attitude (assumed)


@dataclass(frozen=True)
class SpringTruth:
    """Known spring-test truth for one axis (model scale, SI)."""

    axis: str
    Cm: float
    CD: float
    area: float
    mechanical_damping: float = 0.5  # N s/m: zeta_s ~ 0.03 (assumed: spring, guide and wire)
    mass: float = 0.97
    volume: float = 344_868e-9
    stiffness: float = 63.6
    rho: float = 1000.0

    @property
    def added_mass(self) -> float:
        return self.Cm * self.rho * self.volume

    @property
    def KQ(self) -> float:
        return 0.5 * self.rho * self.CD * self.area


@dataclass(frozen=True)
class PendulumTruth:
    """Known pendulum-test truth for one axis (model scale, SI)."""

    axis: str
    Cm: float
    KL: float
    KQ: float
    area: float
    mass: float = 0.146
    volume: float = 107_597e-9
    length: float = 0.30  # m, pivot to model centre (assumed; not given in the paper)
    rho: float = 1000.0
    g: float = 9.81

    @property
    def added_mass(self) -> float:
        return self.Cm * self.rho * self.volume

    @property
    def CD(self) -> float:
        return 2 * self.KQ / (self.rho * self.area)


def paper_spring_truth(scale=0.30) -> dict:
    """Truth per axis from Table 7 (C_m, C_D) on the 30 % model."""
    cm = (0.8172, 0.1945, 1.1564)
    cd = (1.4015, 0.5075, 0.9917)
    return {a: SpringTruth(a, cm[i], cd[i], FULL_AREA[i] * scale ** 2) for i, a in enumerate(AXES)}


def paper_pendulum_truth(scale=0.22, morison=False) -> dict:
    """Truth per axis from Table 10 (Chin: C_m, K_L, K_Q) on the 22 % model.

    With ``morison=True`` K_L = 0 and K_Q = 1/2 rho C_D A with Table 10's Morison C_D.
    """
    cm = (0.9024, 0.2404, 0.8283)
    kl = (1.0745, 0.6508, 0.3834)
    kq = (50.8618, 17.4666, 55.7484)
    cd = (2.3432, 0.5838, 1.1145)
    out = {}
    for i, a in enumerate(AXES):
        area = FULL_AREA[i] * scale ** 2
        if morison:
            out[a] = PendulumTruth(a, cm[i], 0.0, 0.5 * 1000.0 * cd[i] * area, area)
        else:
            out[a] = PendulumTruth(a, cm[i], kl[i] * scale, kq[i] * scale ** 2, area)
    return out


@dataclass
class SyntheticLaunch:
    """One generated launch: time (s), the measured column, and its label."""

    axis: str
    amplitude: float
    repeat: int
    t: np.ndarray
    values: np.ndarray
    column: str
    meta: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.axis}_A{self.amplitude:.4g}_r{self.repeat}".replace(".", "p")


def _time(duration, fs, hold):
    t = np.arange(0.0, hold + duration, 1.0 / fs)
    return t, t >= hold - 1e-12


def spring_launch(truth: SpringTruth, amplitude, rng, repeat=0, fs=100.0, duration=6.0, hold=0.5,
                  noise=0.2e-3, counts_per_mm=2.45, offset=None, as_counts=True) -> SyntheticLaunch:
    """One spring launch: released from rest at ``amplitude`` (m) from the rest position."""
    t, moving = _time(duration, fs, hold)
    M = truth.mass + truth.added_mass
    a0, aL, aQ = truth.stiffness / M, truth.mechanical_damping / M, truth.KQ / M
    tm = np.ascontiguousarray(t[moving] - t[moving][0])
    y = np.full(t.size, float(amplitude))
    y[moving] = simulate_decay(tm, float(amplitude), 0.0, a0, aL, aQ, False, 1e-3)
    off = rng.uniform(0.05, 0.15) if offset is None else offset  # sensor reading at rest, m
    meas = y + off + noise * rng.standard_normal(t.size)
    q = 1e-3 / counts_per_mm
    counts = np.round(meas / q)
    if as_counts:
        return SyntheticLaunch(truth.axis, amplitude, repeat, t, counts, "counts")
    return SyntheticLaunch(truth.axis, amplitude, repeat, t, counts * q, "y")


def pendulum_launch(truth: PendulumTruth, amplitude, rng, repeat=0, fs=100.0, duration=8.0, hold=0.5,
                    noise=IMU_NOISE, pivot_inertia=0.0) -> SyntheticLaunch:
    """One pendulum launch released from rest at ``amplitude`` (rad), angle about the rest position."""
    t, moving = _time(duration, fs, hold)
    r = truth.length
    R = abs(truth.mass - truth.rho * truth.volume) * truth.g * r
    J = (truth.mass + truth.added_mass) * r ** 2 + pivot_inertia
    a0, aL, aQ = R / J, truth.KL * r ** 2 / J, truth.KQ * r ** 3 / J
    tm = np.ascontiguousarray(t[moving] - t[moving][0])
    th = np.full(t.size, float(amplitude))
    th[moving] = simulate_decay(tm, float(amplitude), 0.0, a0, aL, aQ, True, 1e-3)
    bias = rng.normal(0.0, math.radians(0.1))  # IMU level offset (assumed)
    return SyntheticLaunch(truth.axis, amplitude, repeat, t, th + bias + noise * rng.standard_normal(t.size),
                           "theta")


def protocol(kind, truths: dict, seed=0, axes=AXES, repeats=REPEATS, amplitudes=None, **kw) -> list:
    """All launches of the protocol: ``repeats`` x 4 amplitudes per axis (72 for three axes)."""
    rng = np.random.default_rng(seed)
    gen = {"spring": spring_launch, "pendulum": pendulum_launch}[kind]
    amps = amplitudes or (SPRING_AMPLITUDES if kind == "spring" else PENDULUM_AMPLITUDES)
    out = []
    for axis in axes:
        for a in amps:
            for k in range(repeats):
                sign = 1.0 if k % 2 == 0 else -1.0  # alternate the launch side
                out.append(gen(truths[axis], sign * a, rng, repeat=k, **kw))
    return out


def write_launch(launch: SyntheticLaunch, path) -> Path:
    """Write ``t,<column>`` CSV."""
    path = Path(path)
    fmt = "%.0f" if launch.column == "counts" else "%.9g"
    data = np.column_stack([launch.t, launch.values])
    with open_atomic(path, "wb") as fh:
        np.savetxt(fh, data, delimiter=",", header=f"t,{launch.column}", comments="", fmt=["%.4f", fmt])
    return path


def write_protocol(directory, launches, prefix) -> list:
    """Write every launch as ``<prefix>_<axis>_L<k>_r<j>.csv`` in ``directory``; returns the paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    amps = sorted({abs(round(x.amplitude, 9)) for x in launches})
    paths = []
    for x in launches:
        level = amps.index(abs(round(x.amplitude, 9))) + 1
        paths.append(write_launch(x, directory / f"{prefix}_{x.axis}_L{level}_r{x.repeat + 1}.csv"))
    return paths
