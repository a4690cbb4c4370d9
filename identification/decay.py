"""Shared machinery of the free-decay tests: launch files, validation, extrema, 1-DOF output-error fit.

Both rigs of Cely 2019 (spring, eqs. 6-9; pendulum, eqs. 10-16) are one-degree-of-freedom decays

    x'' = -a0 g(x) - aL x' - aQ |x'| x',     g(x) = x (spring) or sin(x) (pendulum),

written per unit of the oscillating inertia. This module reads and validates launch logs, finds the
release and the turning points, and fits (a0, aL, aQ, x0, v0, offset) to a whole trace by simulating
the ODE (output error, scipy ``least_squares``). The physical coefficients are derived from the
``a`` coefficients by the rig modules (:mod:`identification.free_decay`, :mod:`identification.pendulum`).

Confidence intervals
--------------------
Residuals of a decay fit are not white: sensor quantisation on a slow signal, IMU filtering and
small model mismatch all make them autocorrelated, and the textbook ``s^2 (J^T J)^-1`` is then too
narrow. We use the Newey-West (HAC, Bartlett kernel) sandwich covariance
``(J^T J)^-1 S (J^T J)^-1`` on VAR(1)-prewhitened scores (Andrews-Monahan), with the lag window
chosen from the autocorrelation of the prewhitened residual (the first lag where it falls below
2/sqrt(n), at least the Newey-West rule 4 (n/100)^(2/9)); see :func:`hac_covariance`.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize, signal, stats

from udrobot_files.caches import configure_numba_cache

configure_numba_cache()  # numba's cache in a private user folder, not the source tree (before @njit below)

from numba import njit  # noqa: E402

MIN_ROWS = 20
MIN_EXTREMA = 3


class LaunchError(ValueError):
    """A launch that cannot be analysed; the message names the file and, where known, row and field."""

    def __init__(self, path, message, row=None, field=None):
        where = str(path)
        if row is not None:
            where += f", row {row}"
        if field is not None:
            where += f", field {field!r}"
        super().__init__(f"{where}: {message}")
        self.path, self.row, self.field, self.reason = str(path), row, field, message


@dataclass
class Launch:
    """One free-decay launch.

    Attributes
    ----------
    path : str
        Source file.
    t : ndarray
        Time, s (strictly increasing).
    x : ndarray
        Position (m, spring) or angle (rad, pendulum).
    resolution : float
        Sensor quantisation step in the units of ``x`` (0 when unknown / continuous).
    meta : dict
        Optional information (e.g. axis from the file name).
    """

    path: str
    t: np.ndarray
    x: np.ndarray
    resolution: float = 0.0
    meta: dict = field(default_factory=dict)


def read_columns(path, wanted: dict) -> tuple[dict, str]:
    """Read a numeric CSV with a header; return the first matching column set.

    Parameters
    ----------
    path : path-like
        CSV file.
    wanted : dict
        ``{label: (col1, col2, ...)}`` alternative column sets; the first complete one is used.

    Returns
    -------
    columns : dict
        ``{name: ndarray}`` for the chosen set.
    label : str
        Key of ``wanted`` that matched.
    """
    path = Path(path)
    numbered = read_csv_rows(path)
    if not numbered:
        raise LaunchError(path, "empty file (expected a header line and data rows)")
    header_line, head = numbered[0]
    lines = [n for n, _ in numbered[1:]]
    rows = [r for _, r in numbered]
    header = [h.strip().lower() for h in head]
    for label, cols in wanted.items():  # noqa: B007 (label is returned)
        if all(c in header for c in cols):
            break
    else:
        expected = " or ".join(",".join(c) for c in wanted.values())
        raise LaunchError(path, f"header {','.join(header)!r} lacks the expected columns ({expected})",
                          row=header_line)
    idx = [header.index(c) for c in cols]
    data = np.empty((len(rows) - 1, len(cols)))
    for i, r in enumerate(rows[1:]):
        for j, (k, c) in enumerate(zip(idx, cols)):
            row_no = lines[i]  # 1-based line of the file (blank and comment lines counted)
            if k >= len(r):
                raise LaunchError(path, "missing value", row=row_no, field=c)
            s = r[k].strip()
            try:
                v = float(s)
            except ValueError:
                raise LaunchError(path, f"{s!r} is not a number", row=row_no, field=c) from None
            if not math.isfinite(v):
                raise LaunchError(path, f"non-finite value {s!r} (NaN/inf)", row=row_no, field=c)
            data[i, j] = v
    if len(data) < MIN_ROWS:
        raise LaunchError(path, f"only {len(data)} data rows, need at least {MIN_ROWS}")
    t = data[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise LaunchError(path, f"time not increasing ({t[i - 1]:.9g} then {t[i]:.9g})", row=lines[i],
                          field=cols[0])
    return {c: data[:, j] for j, c in enumerate(cols)}, label


def read_csv_rows(path) -> list:
    """Non-blank, non-comment (``#``) rows of a CSV file with their 1-based line numbers.

    Raises :class:`LaunchError` for a missing/unreadable file, a non-UTF-8 file or a malformed CSV
    (e.g. an unterminated quote swallowing the rest of the file).
    """
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            out = []
            for r in reader:
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#"):
                    out.append((reader.line_num, r))
    except FileNotFoundError as exc:
        raise LaunchError(path, "file not found") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise LaunchError(path, f"cannot read ({exc})") from exc
    except csv.Error as exc:
        raise LaunchError(path, f"malformed CSV ({exc})") from exc
    return out


def estimate_resolution(x) -> float:
    """Quantisation step of a sampled signal (0 if it looks continuous)."""
    d = np.abs(np.diff(x))
    d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(x))))]
    if d.size < 5:
        return 0.0
    q = float(np.min(d))
    # quantised: the nonzero steps are (near) integer multiples of the smallest one
    ratios = d / q
    if np.mean(np.abs(ratios - np.round(ratios)) < 0.02) > 0.95:
        return q
    return 0.0


def noise_level(x) -> float:
    """Robust white-noise standard deviation from second differences (units of ``x``)."""
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def find_hold(x, band, offset) -> tuple[int, int, float]:
    """Pre-release hold of a launch: (first hold sample, release index, hold level).

    The model is released from rest at its largest excursion from the rest position ``offset``, so
    the hold is reached at the first sample within ``band`` of that excursion. A log that starts at
    the hold (the protocol's) gives a hold starting at 0; one that also records the model at rest and
    being pulled out by hand before the release gives the hold after the pull. The release is the last
    sample of the hold (within ``band`` of the hold's first samples); the hold level is the median of
    the first half of the hold, before the release starts to move the trace inside ``band``. When
    the log starts moving at once, the hold is the first sample.
    """
    a = np.abs(x - offset)
    i0 = int(np.flatnonzero(a >= a.max() - band)[0])
    ref = float(np.median(x[i0: i0 + 5]))
    moving = np.flatnonzero(np.abs(x[i0:] - ref) > band)
    start = i0 + max(int(moving[0]) - 1, 0) if moving.size else i0
    level = float(np.median(x[i0: i0 + max((start - i0 + 1) // 2, 1)]))
    return i0, start, level


def find_release(x, band, offset=None) -> int:
    """Index of the last sample of the pre-release hold (0 when the log starts moving at once).

    With the rest ``offset`` the hold is found by :func:`find_hold` (it may follow a rest and pull
    phase); without it, it is the leading run of samples within ``band`` of the first sample.
    """
    if offset is not None:
        return find_hold(x, band, offset)[1]
    x0 = np.median(x[: min(5, x.size)])
    moving = np.flatnonzero(np.abs(x - x0) > band)
    if moving.size == 0:
        return 0
    return max(int(moving[0]) - 1, 0)


def check_clipping(path, t, x, resolution, period, start):
    """Raise :class:`LaunchError` when the trace has flat tops at its extreme values (a saturated sensor).

    A run of identical samples at the global maximum or minimum after the release is accepted only
    as long as a quantised smooth peak can stay on one level: ``2 sqrt(2 q / (A w^2))`` s for a peak of
    amplitude A, step q and frequency w, tripled, plus three samples.
    """
    y = x[start + 1:]
    if y.size < 3:
        return
    dt = float(np.median(np.diff(t)))
    amp = 0.5 * float(np.ptp(x))
    w = 2 * math.pi / period if period and period > 0 else 0.0
    if resolution > 0 and w > 0 and amp > 0:
        plateau = 2 * math.sqrt(2 * resolution / (amp * w * w))
        limit = int(3 * plateau / dt) + 3
    else:
        limit = 4
    for extreme, name in ((np.max(y), "maximum"), (np.min(y), "minimum")):
        at = np.abs(y - extreme) <= 1e-12 * max(1.0, abs(extreme))
        # longest run of consecutive samples at the extreme
        run, best, best_end = 0, 0, 0
        for i, flag in enumerate(at):
            run = run + 1 if flag else 0
            if run > best:
                best, best_end = run, i
        if best > limit:
            row = start + 1 + best_end - best + 1 + 2
            raise LaunchError(path, f"sensor clipped: {best} consecutive samples flat at the {name} {extreme:.6g} "
                              f"(at most {limit} expected for a smooth peak)", row=row)


@dataclass
class Extrema:
    """Turning points of a decay (relative to the final offset)."""

    t: np.ndarray
    x: np.ndarray
    offset: float
    hold_level: float | None = None  # held launch position (absolute), see find_hold

    @property
    def count(self) -> int:
        return int(self.t.size)


def find_extrema(t, x, start, offset, threshold) -> Extrema:
    """Turning points after the release, the release itself included as the first one.

    Peak times and values are refined by a parabola through the samples around each detected
    extremum (important for quantised signals whose peaks are flat for several samples).
    """
    y = x[start:] - offset
    tt = t[start:]
    ext_i = [0]
    hi, _ = signal.find_peaks(y, prominence=threshold)
    lo, _ = signal.find_peaks(-y, prominence=threshold)
    cand = sorted([(i, 1) for i in hi] + [(i, -1) for i in lo])
    sign0 = 1 if y[0] >= 0 else -1
    last_sign = sign0
    for i, s in cand:
        if i == 0:
            continue
        if s == last_sign:  # keep the larger of two same-sign candidates
            if abs(y[i]) > abs(y[ext_i[-1]]) and len(ext_i) > 1:
                ext_i[-1] = i
            continue
        ext_i.append(i)
        last_sign = s
    ts, xs = [tt[0]], [y[0]]
    for k in range(1, len(ext_i)):
        i = ext_i[k]
        half = max(2, (ext_i[k] - ext_i[k - 1]) // 5)
        lo_i, hi_i = max(i - half, 0), min(i + half + 1, y.size)
        tc = tt[lo_i:hi_i] - tt[i]
        if tc.size >= 3:
            c = np.polyfit(tc, y[lo_i:hi_i], 2)
            if c[0] != 0 and abs(-c[1] / (2 * c[0])) <= (tc[-1] - tc[0]) / 2:
                tv = -c[1] / (2 * c[0])
                ts.append(tt[i] + tv)
                xs.append(np.polyval(c, tv))
                continue
        ts.append(tt[i])
        xs.append(y[i])
    return Extrema(np.array(ts), np.array(xs), offset)


def refine_offset(ext: Extrema) -> Extrema:
    """Rest position from successive turning points (Shanks' estimate, exact for a geometric decay).

    For extrema e_k = c + A (-r)^k, c = (e_0 e_2 - e_1^2) / (e_0 + e_2 - 2 e_1); the median over all
    triples after the release is used. Needed because a lightly damped launch is not at rest at the
    end of the log.
    """
    e = ext.x + ext.offset
    est = []
    for k in range(1, e.size - 2):
        den = e[k] + e[k + 2] - 2 * e[k + 1]
        if abs(den) > 0:
            est.append((e[k] * e[k + 2] - e[k + 1] ** 2) / den)
    if not est:
        return ext
    off = float(np.median(est))
    return Extrema(ext.t, e - off, off, ext.hold_level)


def launch_amplitude(x, start, ext: Extrema) -> float:
    """Launch amplitude from rest: the held release position minus the rest offset.

    The release is detected when the trace has left the hold by a few per cent of the swing, a few
    samples after the true release (the position changes as A (1 - cos w t) ~ A w^2 t^2 / 2 at first),
    so the sample at the detected release understates the amplitude (by ~2 % for a slow pendulum).
    The hold's own level (:func:`find_hold`) does not.
    """
    if ext.hold_level is not None and start >= 1:
        return float(abs(ext.hold_level - ext.offset))
    return float(abs(ext.x[0]))


def peak_speed(t, x, start, period) -> float:
    """Largest |dx/dt| after the release from a Savitzky-Golay derivative (cubic over a sixth of the period).

    Raw sample differences of a quantised, noisy log overstate the peak speed badly (one encoder step
    over one sample is 0.04 m/s at 100 Hz for the LX-EP-40: a 20-80 % excess on the protocol's launches,
    about 2 % left with this window); the smoothed derivative's own error on a sinusoid is 0.4 %.
    Irregular time stamps (e.g. serial logs stamped on arrival) are first interpolated onto a uniform
    grid at the median step. Falls back to ``numpy.gradient`` for records shorter than the window.
    """
    tt, y = t[start:], x[start:]
    dt = np.diff(tt)
    h = float(np.median(dt))
    if np.max(np.abs(dt - h)) > 0.05 * h:
        grid = np.arange(tt[0], tt[-1] + 0.5 * h, h)
        tt, y = grid[grid <= tt[-1]], np.interp(grid[grid <= tt[-1]], tt, y)
    w = int(round(period / 6.0 / h)) | 1 if period > 0 else 0
    if 5 <= w < y.size:
        return float(np.max(np.abs(signal.savgol_filter(y, w, 3, deriv=1, delta=h))))
    return float(np.max(np.abs(np.gradient(y, tt))))


def tail_offset(x, fraction=0.2) -> float:
    """Rest position: median of the last ``fraction`` of the log."""
    n = max(int(fraction * x.size), 3)
    return float(np.median(x[-n:]))


def prepare(launch: Launch, min_extrema=MIN_EXTREMA):
    """Validate a launch and locate its release and turning points.

    Returns
    -------
    start : int
        Release index.
    ext : Extrema
        Turning points (release first).
    noise : float
        Estimated white-noise level.
    """
    t, x, path = launch.t, launch.x, launch.path
    noise = noise_level(x)
    q = launch.resolution
    offset = tail_offset(x)
    span = float(np.max(np.abs(x - offset)))
    floor = max(6 * noise, 3 * q)
    if span <= floor:
        raise LaunchError(path, f"the log does not oscillate: largest excursion {span:.3g} from rest is within the "
                          f"noise/resolution floor {floor:.3g}")
    band = max(4 * noise, 1.5 * q, 0.02 * span)
    _, start, hold = find_hold(x, band, offset)
    threshold = max(6 * noise, 2.5 * q, 0.01 * span)
    ext = find_extrema(t, x, start, offset, threshold)
    ext.hold_level = hold
    if ext.count >= 4:
        ext = refine_offset(ext)
    if ext.count < 2:
        raise LaunchError(path, "the log does not oscillate: no turning point after the release "
                          "(overdamped or not a free-decay launch)")
    if ext.count < min_extrema:
        raise LaunchError(path, f"fewer than {min_extrema} peaks: found {ext.count} turning points above the noise "
                          f"floor {threshold:.3g} (release included)")
    period = 2 * float(np.mean(np.diff(ext.t)))
    check_clipping(path, t, x, q, period, start)
    return start, ext, noise


# ----------------------------------------------------------------------------- simulation
@njit(cache=True)
def _accel(x, v, a0, aL, aQ, sine):
    g = math.sin(x) if sine else x
    return -a0 * g - aL * v - aQ * abs(v) * v


@njit(cache=True)
def simulate_decay(t, x0, v0, a0, aL, aQ, sine, max_step):
    """RK4 solution of x'' = -a0 g(x) - aL x' - aQ |x'| x' sampled at ``t`` (x(t[0]) = x0).

    Each sample interval is split into steps no longer than ``max_step`` (s). Returns NaNs after a
    non-finite state.
    """
    n = t.size
    out = np.empty(n)
    x = x0
    v = v0
    out[0] = x
    for i in range(n - 1):
        dt = t[i + 1] - t[i]
        k = int(math.ceil(dt / max_step - 1e-9))
        if k < 1:
            k = 1
        h = dt / k
        for _ in range(k):
            k1x = v
            k1v = _accel(x, v, a0, aL, aQ, sine)
            k2x = v + 0.5 * h * k1v
            k2v = _accel(x + 0.5 * h * k1x, k2x, a0, aL, aQ, sine)
            k3x = v + 0.5 * h * k2v
            k3v = _accel(x + 0.5 * h * k2x, k3x, a0, aL, aQ, sine)
            k4x = v + h * k3v
            k4v = _accel(x + h * k3x, k4x, a0, aL, aQ, sine)
            x = x + h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
            v = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if not (math.isfinite(x) and math.isfinite(v)):
            for j in range(i + 1, n):
                out[j] = np.nan
            return out
        out[i + 1] = x
    return out


# ----------------------------------------------------------------------------- covariance
def hac_covariance(J, r, n_params=None, max_ar=0.97):
    """Prewhitened Newey-West (Bartlett) sandwich covariance of least-squares parameters.

    The scores g_t = J_t r_t are prewhitened with a VAR(1) fit g_t = A g_{t-1} + e_t (Andrews and
    Monahan 1992; singular values of A capped at ``max_ar``), the long-run covariance of e is taken
    with Bartlett weights, and recoloured: S = (I - A)^-1 S_e (I - A)^-T; then
    cov = (J^T J)^-1 S (J^T J)^-1 n / (n - p). Without prewhitening a Bartlett window cannot
    follow strongly persistent errors: with AR(1) noise of coefficient 0.9 (an IMU attitude from a
    Kalman filter) single-launch 95 % intervals covered the truth only 65-75 % of the time,
    92-99 % with it; for white noise both give the nominal coverage.

    Parameters
    ----------
    J : (n, p) ndarray
        Jacobian of the residuals at the solution.
    r : (n,) ndarray
        Residuals.
    n_params : int, optional
        Parameters for the small-sample factor (default p).
    max_ar : float
        Cap on the singular values of the VAR(1) matrix (keeps (I - A)^-1 bounded).

    Returns
    -------
    cov : (p, p) ndarray
    lag : int
        Bartlett window used on the prewhitened scores.
    """
    n, p = J.shape
    n_params = p if n_params is None else n_params
    r = r - np.mean(r)
    g = J * r[:, None]
    A = np.zeros((p, p))
    if n > 4 * p:
        A = np.linalg.lstsq(g[:-1], g[1:], rcond=None)[0].T
        if not np.all(np.isfinite(A)):
            A = np.zeros((p, p))
        u, sv, vt = np.linalg.svd(A)
        if sv.size and sv.max() > max_ar:
            A = u @ np.diag(np.minimum(sv, max_ar)) @ vt
    e = g[1:] - g[:-1] @ A.T
    # Bartlett window: Newey-West rule, or longer if the prewhitened residual stays correlated
    lag = int(4 * (n / 100.0) ** (2.0 / 9.0))
    rho1 = float(r[1:] @ r[:-1]) / float(r @ r) if float(r @ r) > 0 else 0.0
    w_r = r[1:] - min(max(rho1, -max_ar), max_ar) * r[:-1]
    var = float(w_r @ w_r) / w_r.size
    m = w_r.size
    if var > 0 and m > 8:
        w_r = w_r - w_r.mean()
        f = np.fft.rfft(w_r, 2 * m)
        acf = np.fft.irfft(f * np.conj(f))[:m] / (m * var)
        below = np.flatnonzero(np.abs(acf[1:]) < 2 / math.sqrt(m))
        lag = max(lag, int(below[0]) + 1 if below.size else m // 4)
    lag = max(min(lag, e.shape[0] // 4), 0)
    S = e.T @ e
    for k in range(1, lag + 1):
        w = 1.0 - k / (lag + 1.0)
        G = e[k:].T @ e[:-k]
        S += w * (G + G.T)
    B = np.linalg.inv(np.eye(p) - A)
    S = B @ S @ B.T
    JtJ_inv = np.linalg.pinv(J.T @ J)
    cov = JtJ_inv @ S @ JtJ_inv * n / max(n - n_params, 1)
    return cov, lag


def central_jacobian(fun, p, rel=1e-5, scale=None):
    """Central-difference Jacobian of the residual function ``fun`` at ``p``."""
    p = np.asarray(p, float)
    scale = np.maximum(np.abs(p), 1e-8) if scale is None else np.asarray(scale, float)
    cols = []
    for j in range(p.size):
        h = rel * scale[j]
        pp, pm = p.copy(), p.copy()
        pp[j] += h
        pm[j] -= h
        cols.append((fun(pp) - fun(pm)) / (2 * h))
    return np.column_stack(cols)


# ----------------------------------------------------------------------------- output-error fit
@dataclass
class DecayFit:
    """Output-error fit of one decay.

    Attributes
    ----------
    params : dict
        ``a0`` (1/s^2), ``aL`` (1/s), ``aQ`` (1/unit of x), ``x0``, ``v0``, ``offset``.
    names : tuple
        Order of ``cov`` rows.
    cov : ndarray
        HAC covariance of the fitted parameters.
    t, x, model : ndarray
        Fitted samples, measurement and model response (absolute, offset included).
    rms : float
        Residual RMS.
    lag : int
        HAC window.
    """

    params: dict
    names: tuple
    cov: np.ndarray
    t: np.ndarray
    x: np.ndarray
    model: np.ndarray
    rms: float
    lag: int
    nfev: int = 0


def fit_decay(t, x, start, ext: Extrema, sine: bool, linear=True, quadratic=True) -> DecayFit:
    """Fit x'' = -a0 g(x) - aL x' - aQ |x'| x' to ``x[start:]`` by output error.

    Parameters
    ----------
    t, x : ndarray
        Whole launch (s; m or rad).
    start : int
        Release index.
    ext : Extrema
        Turning points (initial guess).
    sine : bool
        Pendulum restoring term sin(x) instead of x.
    linear, quadratic : bool
        Which damping terms to estimate (Morison form: ``linear=False``).
    """
    tt = np.ascontiguousarray(t[start:] - t[start])
    y = np.ascontiguousarray(x[start:])
    dt = float(np.median(np.diff(tt)))
    period = 2 * float(np.mean(np.diff(ext.t)))
    wd = 2 * math.pi / period
    # initial guess from the first log decrement
    xs = np.abs(ext.x)
    delta = math.log(max(xs[0], 1e-12) / max(xs[2], 1e-12)) if ext.count >= 3 else 0.3
    delta = min(max(delta, 1e-3), 6.0)
    zeta = delta / math.sqrt(4 * math.pi ** 2 + delta ** 2)
    wn = wd / math.sqrt(1 - zeta ** 2)
    amp = float(np.sqrt(xs[0] * xs[min(2, xs.size - 1)]))
    a0 = wn ** 2
    share = (0.5 if linear else 0.0, 0.5 if quadratic else 0.0)
    if not quadratic:
        share = (1.0, 0.0)
    if not linear:
        share = (0.0, 1.0)
    aL = 2 * zeta * wn * share[0]
    aQ = zeta * 3 * math.pi / (8 * max(amp, 1e-9)) * 2 * share[1]
    names = ["a0"] + (["aL"] if linear else []) + (["aQ"] if quadratic else []) + ["x0", "v0", "offset"]
    p0 = [a0] + ([aL] if linear else []) + ([aQ] if quadratic else []) + [float(y[0] - ext.offset), 0.0, ext.offset]
    lb = [1e-9] + ([0.0] if linear else []) + ([0.0] if quadratic else []) + [-np.inf, -np.inf, -np.inf]
    max_step = min(dt, 0.05 / wn) if wn > 0 else dt

    def unpack(p):
        d = dict(zip(names, p))
        return d["a0"], d.get("aL", 0.0), d.get("aQ", 0.0), d["x0"], d["v0"], d["offset"]

    def resid(p):
        a0_, aL_, aQ_, x0_, v0_, off_ = unpack(p)
        m = simulate_decay(tt, x0_, v0_, a0_, aL_, aQ_, sine, max_step)
        r = m + off_ - y
        return np.where(np.isfinite(r), r, 1e3 * (np.abs(y).max() + 1.0))

    xscale = np.array([a0] + ([max(aL, 0.1 * zeta * wn)] if linear else [])
                      + ([max(aQ, 0.1 / max(amp, 1e-9))] if quadratic else [])
                      + [max(amp, 1e-6), max(amp * wn, 1e-6), max(amp, 1e-6)])
    p0 = np.maximum(np.array(p0, float), np.array(lb) + 1e-12 * xscale)
    sol = optimize.least_squares(resid, p0, jac="2-point", bounds=(lb, np.inf), x_scale=xscale,
                                 method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=400)
    p = sol.x
    r = resid(p)
    J = central_jacobian(resid, p, rel=1e-5, scale=xscale)
    cov, lag = hac_covariance(J, r)
    model = y + r
    return DecayFit(dict(zip(names, p)), tuple(names), cov, tt + t[start], y, model,
                    float(np.sqrt(np.mean(r ** 2))), lag, int(sol.nfev))


def propagate(fun, p, cov):
    """Delta-method covariance of ``fun(p)`` (vector) given the covariance of ``p``."""
    p = np.asarray(p, float)
    f0 = np.atleast_1d(fun(p))
    G = np.zeros((f0.size, p.size))
    for j in range(p.size):
        h = 1e-6 * max(abs(p[j]), 1e-9)
        pp, pm = p.copy(), p.copy()
        pp[j] += h
        pm[j] -= h
        G[:, j] = (np.atleast_1d(fun(pp)) - np.atleast_1d(fun(pm))) / (2 * h)
    return f0, G @ cov @ G.T


def ci95(value, se, dof):
    """Two-sided 95 % interval ``value +- t_{0.975,dof} se``."""
    q = float(stats.t.ppf(0.975, max(dof, 1)))
    return [float(value - q * se), float(value + q * se)]


#: Coefficients a passive body in still water cannot have negative: added mass (kg) and its coefficient
#: C_m, linear and quadratic damping K_L, K_Q and drag coefficients C_D (a negative one feeds energy in).
NONNEGATIVE = {"added_mass_kg": "added mass (kg)", "Cm": "C_m", "KL": "K_L", "KQ": "K_Q", "CD": "C_D",
               "CD_chin": "C_D (Chin fit)"}


#: Standard errors a value must lie below zero to be called impossible: 3.29 (99.9 % two-sided), so that a
#: coefficient whose true value is 0 (a linear damping of a Morison-like body) is rejected in < 0.1 % of
#: launches; at 1.96 (the 95 % interval) a protocol of 37 spring launches with K_L = 0 lost two good ones.
IMPOSSIBLE_SIGMAS = 3.29


@dataclass(frozen=True)
class PhysicalCheck:
    """Sign check of identified coefficients.

    Attributes
    ----------
    impossible : tuple of str
        Reasons for values more than :data:`IMPOSSIBLE_SIGMAS` standard errors below zero (or negative without a
        standard error): physically impossible, the launch must not be reported as ``ok``.
    doubtful : tuple of str
        Negative values within that many standard errors of zero: consistent with zero, read as 0.
    """

    impossible: tuple
    doubtful: tuple


def physical_check(res: dict, where: str = "") -> PhysicalCheck:
    """Check the signs of :data:`NONNEGATIVE` coefficients in a launch result (nested ``morison`` /
    ``graphical`` results included, named in the reason)."""
    bad, doubt = [], []
    for key, label in NONNEGATIVE.items():
        v = res.get(key)
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v >= 0:
            continue
        se = res.get(key + "_se")
        ci = res.get(key + "_ci95")
        name = f"{where}{label}"
        interval = f", 95 % interval [{ci[0]:.4g}, {ci[1]:.4g}]" if ci is not None and len(ci) == 2 else ""
        if isinstance(se, (int, float)) and math.isfinite(se) and v + IMPOSSIBLE_SIGMAS * se >= 0:
            doubt.append(f"{name} = {v:.4g} +- {se:.2g} (s.e.){interval}: within {IMPOSSIBLE_SIGMAS} s.e. of 0, "
                         "read as 0")
            continue
        what = "damping/drag that feeds energy into the motion" if key in ("KL", "KQ", "CD", "CD_chin") \
            else "negative added mass"
        sig = f" ({-v / se:.1f} s.e. below 0)" if isinstance(se, (int, float)) and se > 0 else ""
        bad.append(f"{name} = {v:.4g}{interval}{sig} < 0 ({what}: physically impossible; check that the vehicle "
                   "was free, the angle unwrapped and the rig values)")
    for sub in ("morison", "graphical"):
        if isinstance(res.get(sub), dict):
            c = physical_check(res[sub], f"{sub} fit: ")
            bad.extend(c.impossible)
            doubt.extend(c.doubtful)
    return PhysicalCheck(tuple(bad), tuple(doubt))
