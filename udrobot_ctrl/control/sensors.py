"""Sensor models of a UDrobot-class ROV: noisy, multi-rate measurement streams with DVL dropouts.

Channels (each measures one state of ``x y z phi theta psi u v w p q r`` directly)::

    depth               pressure sensor (Blue Robotics Bar30 class), z in m
    phi, theta, psi     IMU / AHRS attitude, rad
    p, q, r             IMU gyro rates, rad/s
    dvl_u, dvl_v, dvl_w DVL bottom-track velocity in body axes (Water Linked A50 class), m/s
    usbl_x, usbl_y, usbl_z  optional USBL position (Water Linked Underwater GPS class), m

The DVL drops out when the altitude above the seabed is below ``dvl_min_altitude`` or the depth below
``dvl_min_depth`` (near the surface: bubbles, surface reflections). All noise levels are *assumed*
(no UDrobot sensor data is available); their sources are given on :class:`SensorConfig`. Noise is
white Gaussian; biases, lever arms and time delays are not modelled.

A stream is a :class:`SensorStream`: ``values`` (n, 13) with NaN where a channel has no sample at that
step (multi-rate sampling, dropout), plus the per-channel standard deviations used to generate it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.dynamics.plant import wrap_angle

CHANNELS = ("depth", "phi", "theta", "psi", "p", "q", "r", "dvl_u", "dvl_v", "dvl_w", "usbl_x", "usbl_y", "usbl_z")
#: state index measured by each channel
CHANNEL_STATE = np.array([2, 3, 4, 5, 9, 10, 11, 6, 7, 8, 0, 1, 2])
#: channels whose residual must be wrapped to [-pi, pi)
ANGLE_CHANNELS = np.array([False, True, True, True] + [False] * 9)
DVL = slice(7, 10)
USBL = slice(10, 13)
#: physical sensors and the channels each one delivers (innovation gating is done per sensor)
SENSORS = (("depth", (0,)), ("attitude", (1, 2, 3)), ("gyro", (4, 5, 6)), ("dvl", (7, 8, 9)), ("usbl", (10, 11, 12)))


def channel_index(name: str) -> int:
    """Index of a channel by name (see :data:`CHANNELS`); ``ValueError`` naming the valid ones otherwise."""
    try:
        return CHANNELS.index(name)
    except ValueError:
        raise ValueError(f"unknown sensor channel {name!r}; expected one of {', '.join(CHANNELS)}") from None


@dataclass(frozen=True)
class SensorConfig:
    """Sensor noise (1-sigma), rates and dropout thresholds. Every value is assumed (no UDrobot sensor logs).

    Attributes
    ----------
    depth_sigma : float
        m. Assumed 0.01 m: the MS5837-30BA (Bar30) resolves 0.2 mbar (2 mm of water) but is specified to
        +-50 mbar absolute accuracy; 1 cm covers noise plus short-term drift and surface waves in a tank.
    roll_pitch_sigma : float
        rad. Assumed 0.01 rad (0.6 deg), a typical ArduSub/Pixhawk AHRS figure for roll and pitch.
    heading_sigma : float
        rad. Assumed 0.035 rad (2 deg): magnetometer heading is disturbed by thruster currents and steel.
    rate_sigma : float
        rad/s. Assumed 0.005 rad/s: MEMS gyro (MPU-6000 class, 0.005 deg/s/sqrt(Hz)) noise plus uncompensated
        bias at 20 Hz.
    dvl_sigma : float
        m/s. Assumed 0.01 m/s single-ping noise: Water Linked A50 datasheet gives 0.1 mm/s resolution and
        +-1.01 % / +-1 mm/s long-term accuracy; single pings are noisier.
    dvl_min_altitude, dvl_min_depth : float
        m. Dropout thresholds (assumed 0.3 m altitude, 0.2 m depth; the A50 datasheet minimum altitude is
        0.05 m, we keep a margin for the lock-on range and near-surface bubbles).
    seabed_depth : float
        m, depth of a flat seabed (altitude = seabed_depth - z).
    usbl : bool
        Whether USBL fixes are produced.
    usbl_sigma : float
        m. Assumed 0.2 m: Water Linked Underwater GPS quotes ~1 % of slant range; 0.2 m at ~20 m.
    imu_rate_hz, depth_rate_hz, dvl_rate_hz, usbl_rate_hz : float
        Sample rates (assumed: IMU and pressure 20 Hz, DVL 5 Hz within the A50's 2-15 Hz, USBL 1 Hz).
    """

    depth_sigma: float = 0.01
    roll_pitch_sigma: float = 0.01
    heading_sigma: float = 0.035
    rate_sigma: float = 0.005
    dvl_sigma: float = 0.01
    dvl_min_altitude: float = 0.3
    dvl_min_depth: float = 0.2
    seabed_depth: float = 10.0
    usbl: bool = False
    usbl_sigma: float = 0.2
    imu_rate_hz: float = 20.0
    depth_rate_hz: float = 20.0
    dvl_rate_hz: float = 5.0
    usbl_rate_hz: float = 1.0

    def __post_init__(self):
        for name in ("depth_sigma", "roll_pitch_sigma", "heading_sigma", "rate_sigma", "dvl_sigma", "usbl_sigma",
                     "imu_rate_hz", "depth_rate_hz", "dvl_rate_hz", "usbl_rate_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SensorConfig.{name} must be > 0, got {getattr(self, name)!r}")

    def sigmas(self) -> np.ndarray:
        """Per-channel standard deviations (13,) in channel order."""
        rp, h, w, d, u = self.roll_pitch_sigma, self.heading_sigma, self.rate_sigma, self.dvl_sigma, self.usbl_sigma
        return np.array([self.depth_sigma, rp, rp, h, w, w, w, d, d, d, u, u, u])

    def rates(self) -> np.ndarray:
        """Per-channel sample rates (13,) in Hz."""
        return np.array([self.depth_rate_hz] + [self.imu_rate_hz] * 6 + [self.dvl_rate_hz] * 3
                        + [self.usbl_rate_hz] * 3)


@dataclass
class SensorStream:
    """Measurements at times ``t`` (n,) s: ``values`` (n, 13) in channel order, NaN where absent."""

    t: np.ndarray
    values: np.ndarray
    sigmas: np.ndarray
    channels: tuple = CHANNELS

    def available(self) -> np.ndarray:
        """(n, 13) bool mask of present samples."""
        return np.isfinite(self.values)


def dvl_valid(x, config: SensorConfig) -> np.ndarray:
    """True where the DVL has bottom lock: depth >= dvl_min_depth and altitude >= dvl_min_altitude (x (..., 12))."""
    z = np.asarray(x, float)[..., 2]
    return (z >= config.dvl_min_depth) & (config.seabed_depth - z >= config.dvl_min_altitude)


def sample_mask(t, x, config: SensorConfig) -> np.ndarray:
    """(n, 13) bool: which channels sample at each time (multi-rate schedule, DVL dropout, USBL on/off)."""
    t = np.asarray(t, float)
    rates = config.rates()
    # a channel samples at the first step at or after each multiple of its period
    tick = np.floor(t[:, None] * rates[None, :] + 1e-9)
    mask = np.ones((len(t), len(CHANNELS)), bool)
    mask[1:] = tick[1:] > tick[:-1]
    mask[:, DVL] &= dvl_valid(x, config)[:, None]
    if not config.usbl:
        mask[:, USBL] = False
    return mask


def measure(t, x, config: SensorConfig | None = None, seed=0) -> SensorStream:
    """Noisy measurement stream of a trajectory.

    Parameters
    ----------
    t : (n,) array_like
        Sample times, s (the EKF step is ``t[1] - t[0]``).
    x : (n, 12) array_like
        True states.
    config : SensorConfig, optional
    seed : int or numpy Generator

    Returns
    -------
    SensorStream
        Angles are wrapped to [-pi, pi).
    """
    config = config or SensorConfig()
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] != 12 or len(t) != len(x):
        raise ValueError(f"measure needs t (n,) and x (n, 12), got {t.shape} and {x.shape}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    sig = config.sigmas()
    vals = x[:, CHANNEL_STATE] + rng.standard_normal((len(t), len(CHANNELS))) * sig
    vals[:, ANGLE_CHANNELS] = wrap_angle(vals[:, ANGLE_CHANNELS])
    vals[~sample_mask(t, x, config)] = np.nan
    return SensorStream(t=t, values=vals, sigmas=sig)


class SensorSampler:
    """Online version of :func:`measure` for closed loops: ``sampler(t, x) -> (13,)`` row, NaN where absent.

    Keeps each channel's sample clock (a channel samples at the first call at or after each multiple of its
    period) and its own random generator.
    """

    def __init__(self, config: SensorConfig | None = None, seed=0):
        self.config = config or SensorConfig()
        self.sigmas = self.config.sigmas()
        self.rates = self.config.rates()
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self._tick = None

    def __call__(self, t, x) -> np.ndarray:
        x = np.asarray(x, float).reshape(12)
        tick = np.floor(float(t) * self.rates + 1e-9)
        mask = np.ones(len(CHANNELS), bool) if self._tick is None else tick > self._tick
        self._tick = tick
        if not dvl_valid(x, self.config):
            mask[DVL] = False
        if not self.config.usbl:
            mask[USBL] = False
        vals = x[CHANNEL_STATE] + self.rng.standard_normal(len(CHANNELS)) * self.sigmas
        vals[ANGLE_CHANNELS] = wrap_angle(vals[ANGLE_CHANNELS])
        vals[~mask] = np.nan
        return vals
