"""Blue Robotics T-200 thruster model, actuated-DOF report and thrust allocation.

PWM <-> bollard thrust comes from ``models/t200_poly.toml``: per measured supply voltage (10..20 V) and per
direction a cubic polynomial thrust(s), s = (pwm - 1500 us) / 400 us, fitted (least squares) to Blue
Robotics' published bollard data outside the zero band; between measured voltages the coefficients,
band edges and limits are interpolated linearly in V. :func:`fit_t200` regenerates those coefficients
from ``../shared/data/t200/t200_performance_tidy.csv`` (the data itself is never copied into the repo).

Bollard data only: the model says nothing about how thrust falls with advance speed (estimated error
grows with surge speed; not modelled).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

PWM_NEUTRAL = 1500.0
PWM_MIN, PWM_MAX = 1100.0, 1900.0
PWM_SCALE = 400.0
DEGREE = 3
DOF_NAMES = ("X", "Y", "Z", "K", "M", "N")


# ----------------------------------------------------------------------------- fitting (from the CSV)
def read_t200_csv(path) -> dict:
    """Rows of the tidy T-200 CSV grouped by voltage: ``{V: (pwm_us (n,), thrust_N (n,))}``."""
    path = Path(path)
    out: dict = {}
    with path.open(newline="") as fh:
        for i, row in enumerate(csv.DictReader(fh), start=2):
            try:
                v, pwm, f = float(row["voltage_V"]), float(row["pwm_us"]), float(row["thrust_N"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"{path}: line {i}: expected numeric voltage_V, pwm_us, thrust_N ({exc})") from exc
            out.setdefault(v, ([], []))
            out[v][0].append(pwm)
            out[v][1].append(f)
    return {v: (np.array(p), np.array(f)) for v, (p, f) in sorted(out.items())}


def fit_t200(path, degree: int = DEGREE) -> dict:
    """Fit the per-voltage, per-direction polynomials; returns the ``[[voltage]]`` tables of t200.toml.

    The zero band at each voltage is [first zero PWM, last zero PWM] around 1500 us (points under 300 rpm
    were zeroed by Blue Robotics). Fits use only points outside the band.
    """
    tables = []
    for v, (pwm, f) in read_t200_csv(path).items():
        nz = pwm[f != 0]
        rev_edge, fwd_edge = nz[nz < PWM_NEUTRAL].max(), nz[nz > PWM_NEUTRAL].min()
        zeros = pwm[(pwm > rev_edge) & (pwm < fwd_edge)]
        entry = {"voltage_V": float(v), "zero_band_us": [float(zeros.min()), float(zeros.max())],
                 "max_forward_N": float(f.max()), "max_reverse_N": float(-f.min())}
        for side, sel in (("forward", pwm >= fwd_edge), ("reverse", pwm <= rev_edge)):
            s = (pwm[sel] - PWM_NEUTRAL) / PWM_SCALE
            c = np.polyfit(s, f[sel], degree)
            entry[f"{side}_coeffs"] = [float(x) for x in c]
            entry[f"{side}_rms_N"] = float(np.sqrt(np.mean((np.polyval(c, s) - f[sel]) ** 2)))
            entry[f"{side}_max_abs_err_N"] = float(np.max(np.abs(np.polyval(c, s) - f[sel])))
        tables.append(entry)
    return {"voltage": tables}


def power_law_exponent(voltages, values) -> float:
    """Exponent a of values ~ V^a (least squares in log-log)."""
    return float(np.polyfit(np.log(voltages), np.log(values), 1)[0])


# ----------------------------------------------------------------------------- the shipped curve
@dataclass(frozen=True)
class T200Curve:
    """Tabulated fit: per voltage (ascending) coefficients (highest power first), band and limits."""

    voltages: np.ndarray           # (nv,) V
    forward_coeffs: np.ndarray     # (nv, degree+1) N
    reverse_coeffs: np.ndarray     # (nv, degree+1) N
    zero_band: np.ndarray          # (nv, 2) us
    max_forward_N: np.ndarray      # (nv,)
    max_reverse_N: np.ndarray      # (nv,)
    provenance: dict

    def at(self, voltage: float):
        """(forward_coeffs, reverse_coeffs, zero_band, max_fwd, max_rev) interpolated linearly in V."""
        v = float(voltage)
        if not np.isfinite(v) or v < self.voltages[0] - 1e-9 or v > self.voltages[-1] + 1e-9:
            raise ValueError(f"T-200 voltage {voltage!r} V outside the measured range "
                             f"{self.voltages[0]:g}..{self.voltages[-1]:g} V")

        def lerp(a):
            cols = np.asarray(a).reshape(len(self.voltages), -1).T
            return np.array([np.interp(v, self.voltages, col) for col in cols])

        return (lerp(self.forward_coeffs), lerp(self.reverse_coeffs), lerp(self.zero_band),
                float(np.interp(v, self.voltages, self.max_forward_N)),
                float(np.interp(v, self.voltages, self.max_reverse_N)))


def curve_from_dict(doc: dict, source: str = "t200_poly.toml") -> T200Curve:
    """Parse the t200 model document; errors name the source and field."""
    try:
        tabs = sorted(doc["voltage"], key=lambda e: e["voltage_V"])
        return T200Curve(
            voltages=np.array([e["voltage_V"] for e in tabs], float),
            forward_coeffs=np.array([e["forward_coeffs"] for e in tabs], float),
            reverse_coeffs=np.array([e["reverse_coeffs"] for e in tabs], float),
            zero_band=np.array([e["zero_band_us"] for e in tabs], float),
            max_forward_N=np.array([e["max_forward_N"] for e in tabs], float),
            max_reverse_N=np.array([e["max_reverse_N"] for e in tabs], float),
            provenance=dict(doc.get("provenance", {})),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{source}: malformed T-200 model ({exc!r}); expected [[voltage]] tables with voltage_V, "
                         "forward_coeffs, reverse_coeffs, zero_band_us, max_forward_N, max_reverse_N") from exc


@lru_cache(maxsize=4)
def load_t200(path: str | None = None) -> T200Curve:
    """The shipped ``models/t200_poly.toml`` curve (or a TOML file at ``path``)."""
    if path is None:
        text = resources.files("udrobot_ctrl.models").joinpath("t200_poly.toml").read_text()
        return curve_from_dict(tomllib.loads(text), "models/t200_poly.toml")
    return curve_from_dict(tomllib.loads(Path(path).read_text()), str(path))


def pwm_to_thrust(pwm, voltage: float = 12.0, curve: T200Curve | None = None):
    """Bollard thrust (N, negative = reverse) for PWM pulse widths (us) at a supply voltage (V).

    Zero inside the zero band; PWM is clipped to 1100..1900 us.
    """
    c = curve or load_t200()
    fwd, rev, band, fmax, rmax = c.at(voltage)
    pwm = np.clip(np.asarray(pwm, dtype=float), PWM_MIN, PWM_MAX)
    s = (pwm - PWM_NEUTRAL) / PWM_SCALE
    out = np.where(pwm > band[1], np.polyval(fwd, s), np.where(pwm < band[0], np.polyval(rev, s), 0.0))
    out = np.clip(out, -rmax, fmax)
    return out if out.ndim else float(out)


def _grid(voltage, curve):
    c = curve or load_t200()
    _, _, band, fmax, rmax = c.at(voltage)
    pf = np.linspace(np.floor(band[1]) + 1.0, PWM_MAX, 801)
    pr = np.linspace(PWM_MIN, np.ceil(band[0]) - 1.0, 801)
    ff = np.maximum.accumulate(pwm_to_thrust(pf, voltage, c))
    fr = np.maximum.accumulate(pwm_to_thrust(pr, voltage, c))
    return pf, ff, pr, fr, fmax, rmax


def thrust_to_pwm(thrust, voltage: float = 12.0, curve: T200Curve | None = None):
    """Monotone inverse of :func:`pwm_to_thrust`: PWM (us) for a thrust (N); 1500 us for thrusts the band
    cannot produce (|f| below the first measured point), saturating at 1100/1900 us beyond the limits."""
    pf, ff, pr, fr, fmax, rmax = _grid(voltage, curve)
    f = np.asarray(thrust, dtype=float)
    out = np.full(f.shape, PWM_NEUTRAL)
    pos, neg = f >= ff[0], f <= fr[-1]
    out = np.where(pos, np.interp(np.minimum(f, fmax), ff, pf), out)
    out = np.where(neg, np.interp(np.maximum(f, -rmax), fr, pr), out)
    return out if out.ndim else float(out)


# ----------------------------------------------------------------------------- layout and allocation
@dataclass(frozen=True)
class ActuationReport:
    """Which DOFs a thruster matrix T (6 x n) controls; ``rank`` of T, ``actuated``/``passive`` DOF names."""

    rank: int
    actuated: tuple
    passive: tuple

    def __str__(self) -> str:
        return (f"rank {self.rank}: actuated {', '.join(self.actuated) or '-'}; "
                f"passive (left to damping/restoring) {', '.join(self.passive) or '-'}")


def actuated_dofs(T, tol: float = 1e-9) -> ActuationReport:
    """DOF i is actuated when the unit wrench e_i lies in the range of T (it can be produced alone)."""
    T = np.asarray(T, float)
    rank = int(np.linalg.matrix_rank(T, tol=tol * max(1.0, np.abs(T).max()))) if T.size else 0
    act, pas = [], []
    pinv = np.linalg.pinv(T) if T.size else np.zeros((0, 6))
    for i, name in enumerate(DOF_NAMES):
        e = np.zeros(6)
        e[i] = 1.0
        (act if np.linalg.norm(T @ (pinv @ e) - e) < 1e-6 else pas).append(name)
    return ActuationReport(rank, tuple(act), tuple(pas))


def thrust_allocation_pinv(T, tau):
    """Unconstrained minimum-norm allocation f = T^+ tau (N) for a wrench tau (6,) or (..., 6)."""
    return np.asarray(tau, float) @ np.linalg.pinv(np.asarray(T, float)).T


@dataclass
class AllocationResult:
    """``f`` thrusts (N), ``unachieved`` wrench tau - T f (N, N m), ``status`` (OSQP status or fallback)."""

    f: np.ndarray
    unachieved: np.ndarray
    status: str


class ThrustAllocator:
    """Constrained allocation with OSQP, warm-started between calls:

        min_f (T f - tau)^T W (T f - tau) + eps ||f||^2   s.t.  -max_reverse_i <= f_i <= max_forward_i

    Never raises on a failed solve: falls back to the clipped pseudo-inverse and says so in ``status``.

    Parameters
    ----------
    T : (6, n) array_like
        Thruster matrix.
    f_min, f_max : (n,) array_like
        Per-thruster limits in N (f_min negative).
    weights : (6,) array_like, optional
        Diagonal of W (defaults to ones).
    eps : float
        Thrust-effort regularisation (1/N^2 relative to W).
    """

    def __init__(self, T, f_min, f_max, weights=None, eps: float = 1e-6):
        import osqp
        from scipy import sparse

        self.T = np.asarray(T, float)
        self.f_min = np.asarray(f_min, float)
        self.f_max = np.asarray(f_max, float)
        n = self.T.shape[1]
        self.W = np.diag(np.ones(6) if weights is None else np.asarray(weights, float))
        self._pinv = np.linalg.pinv(self.T)
        P = 2 * (self.T.T @ self.W @ self.T + eps * np.eye(n))
        self._solver = osqp.OSQP()
        self._solver.setup(P=sparse.csc_matrix(np.triu(P)), q=np.zeros(n), A=sparse.csc_matrix(np.eye(n)),
                           l=self.f_min, u=self.f_max, verbose=False, warm_starting=True,
                           eps_abs=1e-7, eps_rel=1e-7, max_iter=4000, polishing=True)

    @classmethod
    def from_parameters(cls, p, **kw):
        """From :class:`udrobot_ctrl.plant.PlantParameters` (uses its T and limits)."""
        return cls(p.T, p.f_min, p.f_max, **kw)

    def _fallback(self, tau, why):
        f = np.clip(self._pinv @ tau, self.f_min, self.f_max)
        return AllocationResult(f, tau - self.T @ f, f"fallback clipped pinv ({why})")

    def __call__(self, tau) -> AllocationResult:
        """Allocate a wrench tau (6,) N, N m."""
        tau = np.asarray(tau, dtype=float).reshape(6)
        if not np.all(np.isfinite(tau)):
            f = np.zeros(self.T.shape[1])
            return AllocationResult(f, np.where(np.isfinite(tau), tau, np.nan), "fallback zero (non-finite tau)")
        try:
            self._solver.update(q=-2 * self.T.T @ self.W @ tau)
            res = self._solver.solve(raise_error=False)
            status = str(res.info.status)
            x = None if res.x is None else np.asarray(res.x, float)
        except Exception as exc:  # noqa: BLE001 -- the allocator must never throw in a control loop
            return self._fallback(tau, f"OSQP error {exc}")
        if x is None or not np.all(np.isfinite(x)) or not status.startswith("solved"):
            return self._fallback(tau, f"OSQP {status}")
        f = np.clip(x, self.f_min, self.f_max)
        return AllocationResult(f, tau - self.T @ f, status)


def write_fit_toml(data_path, out_path) -> dict:
    """Fit the CSV and write the coefficient TOML (no data copied), atomically; refuses to overwrite."""
    import hashlib

    import tomli_w

    out_path = Path(out_path)
    if out_path.exists():
        raise FileExistsError(f"{out_path} exists; remove it first")
    doc = fit_t200(data_path)
    tabs = doc["voltage"]
    vs = [e["voltage_V"] for e in tabs]
    rms = np.sqrt(np.mean([e[k] ** 2 for e in tabs for k in ("forward_rms_N", "reverse_rms_N")]))
    doc = {
        "format": "udrobot-thruster-poly/1", "name": "t200", "degree": DEGREE,
        "form": "thrust_N = polyval(coeffs, (pwm - 1500)/400) outside zero_band_us (0 inside), coeffs highest power "
                "first, forward_coeffs for pwm above the band, reverse_coeffs below; linear in V between tables",
        "provenance": {
            "source": "measured: Blue Robotics T200 Public Performance Data 10-20 V, Sept 2019 (bollard, Basic ESC R3);"
                      " ../shared/data/t200/t200_performance_tidy.csv, see its PROVENANCE.md",
            "data_sha256": hashlib.sha256(Path(data_path).read_bytes()).hexdigest(),
            "fit": "least squares cubic per voltage and direction on the non-zero points (points under 300 rpm were "
                   "zeroed by Blue Robotics); udrobot_ctrl.thrusters_alt.fit_t200",
            "rms_all_N": float(rms),
            "paper_34_3N": "not used: Cely 2019 states 12 V and 34.3 N without source or direction; the measured "
                           "12 V bollard figures (36.4 N forward, 28.6 N reverse) are direction-specific and sourced",
            "speed_effect": "assumed none: bollard data only, thrust loss with advance speed is not modelled",
            "forward_max_exponent": power_law_exponent(vs, [e["max_forward_N"] for e in tabs]),
            "reverse_max_exponent": power_law_exponent(vs, [e["max_reverse_N"] for e in tabs]),
        },
        "voltage": tabs,
    }
    tmp = out_path.with_name(out_path.name + ".tmp")
    tmp.write_text("# T-200 PWM -> bollard thrust fit (coefficients only; the measured data are not copied).\n"
                   "# Regenerate: python -m udrobot_ctrl.thrusters_alt DATA.csv OUT.toml\n" + tomli_w.dumps(doc))
    tmp.replace(out_path)
    return doc


if __name__ == "__main__":
    import sys

    write_fit_toml(sys.argv[1], sys.argv[2])
