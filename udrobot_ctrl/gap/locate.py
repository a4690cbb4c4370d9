"""Locate the gap: which channels, which operating regime, which time windows and frequency band hold it.

Inputs are the nominal model's multiple-shooting errors (:mod:`udrobot_ctrl.gap.shrink`) and equation-error
residuals.

Noise floor. A channel's NRMSE is never zero, even for a perfect model: its measurement noise, the error of the
measured start state of each window and the passive modes (an unactuated roll oscillation, say) that this error
excites in an open-loop replay all count. A channel whose motion is small against its noise (roll rate of a
vehicle that barely rolls) shows a large NRMSE with no unmodelled effect at all. :func:`noise_floor` estimates
that floor per channel by replaying the nominal model under the logged noise: the nominal multiple-shooting replay
is taken as a synthetic truth, each logged channel gets noise of its own measured level and logging rate (white
at its own samples, interpolated onto the grid as the log is: :func:`udrobot_ctrl.gap.smoother.noise_model`), the
windows restart from the synthetic measurement (pose) and its Savitzky-Golay smoothed value (velocities: truth, the
smoother's estimated bias and the filtered noise) as the real replay does, and the NRMSE of that replay against the
noisy synthetic measurement is the floor (``FLOOR_DRAWS`` seeded Monte Carlo draws).

Ranking. A replay spreads an unmodelled force through the dynamics' coupling: a surge/heave disturbance also
disturbs the replayed roll rate (through the centripetal terms), and relative to the roll rate's small spread that
error looks large. Where the model's force balance fails is read from the equation error instead: the residual
generalised force of each DOF (:func:`udrobot_ctrl.gap.attribute.residual`, measured velocities, no propagation)
against its own floor, the residual that the runs' measurement noise alone produces (:func:`force_floor`: the
residual's change when each logged channel gets one more draw of its own noise). The *excess* of DOF i is
``rms_i^2 / floor_i^2 - 1 - 3 s_i`` (at least 0; in units of the floor, so that forces and moments compare), with
``s_i`` the relative standard error of that ratio: ``sqrt(s_rms^2 + s_floor^2)``, each ``sqrt(2 tau / N_i)`` for a
mean square over N_i samples of integrated autocorrelation time tau (so that noise alone stays below it). DOFs are
ranked by their share of the summed excess and named by their velocity channel (X: u, Y: v, Z: w, K: p, M: q,
N: r). When no DOF's velocity is measured, channels are ranked by the replay excess ``max(NRMSE^2 - floor^2, 0)``.
Within a channel, each regime family (horizontal speed, thrust level, distance to the nearest surface,
depth) is binned and the bin whose error share most exceeds its share of the time is reported as the condition.
Windows are the stretches where the error energy (2 s moving average) exceeds twice its mean.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import savgol_coeffs

from udrobot_ctrl.constants import DOF_NAMES as DOF
from udrobot_ctrl.dynamics.plant import PlantParameters
from udrobot_ctrl.gap.attribute import residual, tau_int
from udrobot_ctrl.gap.data import OBSERVING, POSE, VEL, Prepared, smooth_derivative
from udrobot_ctrl.gap.shrink import ACCEL, accel_bias, errors, simulate_windows_each, window_starts
from udrobot_ctrl.gap.smoother import logged_noise_model, noise_draw

FLOOR_DRAWS = 2
#: a DOF holding at least this share of the located gap is where the gap lies (:meth:`Located.gap_dofs`): a partly
#: identified effect whose non-identified parameters act there cannot be excluded while the gap stays unexplained
GAP_SHARE = 0.2
FLOOR_SEED = 0
SPEED_BINS = (0.0, 0.1, 0.25, 0.5, 1.0, np.inf)
THRUST_BINS = (0.0, 0.1, 0.3, 0.6, np.inf)
DIST_BINS = (0.0, 0.3, 0.6, 1.0, 2.0, np.inf)
FREQ_BANDS = ((0.0, 0.05), (0.05, 0.5), (0.5, np.inf))


def _regimes(prep):
    nu = np.where(np.isfinite(prep.nu), prep.nu, np.nan)
    out = {"horizontal speed": (np.hypot(nu[:, 0], np.nan_to_num(nu[:, 1])), SPEED_BINS, "m/s"),
           "thrust level (fraction of maximum)": (np.max(np.abs(prep.f) / prep.f_ref, axis=1), THRUST_BINS, ""),
           "depth": (prep.eta[:, 2], (-np.inf, 0.5, 1.0, 2.0, 4.0, np.inf), "m")}
    if prep.surfaces:
        d = np.min(np.column_stack([s[0] for s in prep.surfaces]), axis=1)
        out["distance to the nearest wall/seabed"] = (d, DIST_BINS, "m")
    return out


def bin_label(lo, hi, unit):
    """A bin's label: ``lo-hi unit``, ``below hi unit`` or ``above lo unit`` for an infinite end."""
    if not np.isfinite(lo):
        return f"below {hi:g} {unit}".strip()
    if not np.isfinite(hi):
        return f"above {lo:g} {unit}".strip()
    return f"{lo:g}-{hi:g} {unit}".strip()


def _windows(t, e2, dt, max_windows=5):
    k = max(1, int(round(2.0 / dt)))
    y = np.convolve(np.nan_to_num(e2), np.ones(k) / k, mode="same")
    mean = np.nanmean(y) if np.isfinite(y).any() else 0
    hot = y > 2 * mean
    d = np.diff(np.concatenate([[0], hot.astype(int), [0]]))
    segs = [(a, b) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)) if b - a > 1]
    segs.sort(key=lambda ab: -np.nansum(e2[ab[0]:ab[1]]))
    return sorted([[round(float(t[a]), 2), round(float(t[b - 1]), 2)] for a, b in segs[:max_windows]])


def frequency_shares(res, dt):
    """Share of the residual power (per DOF column) in the bands of FREQ_BANDS (Hz)."""
    out = {}
    seen = np.isfinite(res).any(axis=0)  # a DOF no sensor observes has no residual (all nan): zero power
    mean = np.zeros(res.shape[1])
    mean[seen] = np.nanmean(res[:, seen], axis=0)
    r = np.nan_to_num(res - mean)
    P = np.abs(np.fft.rfft(r, axis=0)) ** 2
    fr = np.fft.rfftfreq(r.shape[0], dt)
    tot = P.sum(axis=0) + 1e-300
    for lo, hi in FREQ_BANDS:
        sel = (fr >= lo) & (fr < hi)
        out[bin_label(lo, hi, "Hz")] = (P[sel].sum(axis=0) / tot)
    return out


def _sg_kernels(prep: Prepared):
    """Centre weights of the run's Savitzky-Golay smoother and differentiator (prep.window_s, order 2)."""
    win = max(5, int(round(prep.window_s / prep.dt)) | 1)
    return savgol_coeffs(win, 2, use="conv"), savgol_coeffs(win, 2, deriv=1, delta=prep.dt, use="conv")


def _filtered(noise, kernel):
    """Noise (n,) passed through a centred FIR kernel (nan -> 0), as the smoother does to a logged channel."""
    return np.convolve(np.nan_to_num(noise), kernel, mode="same")


def smoothing_bias(prep: Prepared) -> np.ndarray:
    """(n, 6) estimated bias of the smoothed velocities ``prep.nu`` (the smoother's error on the true signal).

    Twicing estimate: the smoother S applied to the smoothed signal, S(S y) - S y, approximates S x - x for the
    underlying signal x (exact for a signal S leaves unchanged). A lightly damped mode (a roll oscillation) is what
    the smoother flattens, and what a window started from the smoothed rate then replays wrongly.
    """
    out = np.zeros((prep.n, 6))
    for i in range(6):
        if prep.dof_ok[i]:
            again, _ = smooth_derivative(prep.nu[:, i], prep.dt, prep.window_s)
            out[:, i] = np.nan_to_num(again - prep.nu[:, i])
    return out


def synthetic_run(prep: Prepared, sim, window_s, rng) -> Prepared:
    """One draw of the floor replay's run: the nominal replay ``sim`` as a synthetic truth, measured with the run's
    noise (replayed by :func:`noise_floor`).

    Parameters
    ----------
    prep : Prepared
        The real run (its noise levels, logged channels, commands and windows).
    sim : (n, 15) ndarray
        The nominal multiple-shooting replay of ``prep`` (state and specific force,
        :func:`udrobot_ctrl.gap.shrink.simulate_windows`: the synthetic truth; nan outside windows).
    window_s : float
        Multiple-shooting window, s.
    rng : numpy.random.Generator

    Returns
    -------
    Prepared
        The synthetic run: ``meas`` = truth + white noise of each channel's measured level (the accelerometer: the
        replay's specific force plus the run's estimated bias and its noise); the window start states
        are the synthetic measurement (pose) and truth plus the smoother's bias (:func:`smoothing_bias`) and the
        Savitzky-Golay filtered noise (velocities; body rates derived from the attitude get the differentiated
        attitude noise).
    """
    starts, _ = window_starts(prep, window_s)
    smooth, deriv = _sg_kernels(prep)
    # each logged channel's synthetic truth: the state, and the accelerometer's reading of the replay's specific force
    # (plus the run's estimated bias) where it is scored
    truth = [(c, sim[:, i]) for i, c in enumerate(POSE + VEL)]
    b_acc = accel_bias(prep)
    if b_acc is not None:
        truth += [(c, sim[:, 12 + j] + b_acc[j]) for j, c in enumerate(ACCEL)]
    meas, noise = {}, {}
    for c, y in truth:
        m = prep.meas.get(c)
        if m is None or not np.isfinite(m).any():
            continue
        noise[c] = noise_draw(logged_noise_model(m), prep.n, rng)
        meas[c] = np.where(np.isfinite(m), y + noise[c], np.nan)
    eta, nu, bias = prep.eta.copy(), prep.nu.copy(), smoothing_bias(prep)
    for i, c in enumerate(POSE):
        if c in meas:
            eta[starts, i] = np.where(np.isfinite(meas[c][starts]), meas[c][starts], sim[starts, i])
    for i, c in enumerate(VEL):
        if prep.reconstructed[i] and prep.smoothed is not None:
            # the smoother's reconstruction error at each window start, drawn from its posterior std
            d = rng.normal(0.0, 1.0, prep.n) * np.nan_to_num(prep.smoothed.sigma_nu[:, i])
            nu[starts, i] = sim[starts, 6 + i] + d[starts]
            continue
        if not prep.dof_ok[i]:
            continue
        if c in noise:
            d = _filtered(noise[c], smooth)
        elif i >= 3 and POSE[i] in noise:  # body rate derived from the Euler-angle rate
            d = _filtered(noise[POSE[i]], deriv)
        else:
            d = np.zeros(prep.n)
        nu[starts, i] = sim[starts, 6 + i] + bias[starts, i] + d[starts]
    return replace(prep, meas={**prep.meas, **meas}, eta=eta, nu=nu)


def noise_floor(preps, sims, p: PlantParameters, window_s, scale, draws=FLOOR_DRAWS, seed=FLOOR_SEED) -> dict:
    """NRMSE per channel that the nominal model shows on these runs with no unmodelled effect (module docstring).

    Parameters
    ----------
    preps, sims : lists
        Prepared runs and their nominal multiple-shooting replays.
    p : PlantParameters
    window_s : float
        Multiple-shooting window, s.
    scale : dict
        Channel -> normalising scale (std of the real measurement), as in the real gap.
    draws, seed : int
        Monte Carlo draws (their squared errors are pooled) and the generator's seed.

    Returns
    -------
    dict channel -> floor NRMSE (dimensionless).
    """
    rng = np.random.default_rng(seed)
    syns = [synthetic_run(prep, sim, window_s, rng) for _ in range(draws) for prep, sim in zip(preps, sims)]
    se, cnt = {}, {}
    for syn, sim_syn in zip(syns, simulate_windows_each(syns, p, (), window_s)):
        for c, e in errors(syn, sim_syn).items():
            ok = np.isfinite(e)
            se[c] = se.get(c, 0.0) + float(np.sum(e[ok] ** 2))
            cnt[c] = cnt.get(c, 0) + int(ok.sum())
    return {c: float(np.sqrt(se[c] / cnt[c]) / scale[c]) for c in se
            if cnt[c] and c in scale and scale[c] > 0}


def _renoised(prep: Prepared, rng) -> Prepared:
    """The run with one more draw of each logged channel's own noise, smoothed and differentiated again (body rates
    derived from the attitude get the derivative of the attitude noise, Euler-rate transform neglected)."""
    meas, eta, nu, nu_dot = dict(prep.meas), prep.eta.copy(), prep.nu.copy(), prep.nu_dot.copy()
    added = {}
    for i, c in enumerate(POSE + VEL):
        m = prep.meas.get(c)
        if m is None or not np.isfinite(m).any():
            continue
        added[c] = e = noise_draw(logged_noise_model(m), prep.n, rng)
        meas[c] = m + e
        if i < 6:
            eta[:, i] += e
        else:
            nu[:, i - 6], nu_dot[:, i - 6] = smooth_derivative(meas[c], prep.dt, prep.window_s)
    for i in (3, 4, 5):  # a rate derived from the attitude carries the attitude's noise, differentiated
        if prep.dof_ok[i] and VEL[i] not in added and POSE[i] in added:
            _, de = smooth_derivative(added[POSE[i]], prep.dt, prep.window_s)
            dn, dnd = smooth_derivative(de, prep.dt, prep.window_s)
            nu[:, i] += np.nan_to_num(dn)
            nu_dot[:, i] += np.nan_to_num(dnd)
    return replace(prep, meas=meas, eta=eta, nu=nu, nu_dot=nu_dot)


@dataclass(frozen=True)
class ForceFloor:
    """Equation-error residual of each DOF against the part the measurement noise alone produces."""

    rms: np.ndarray  # (6,) RMS residual force per DOF, N / N m (nan: DOF not scored)
    floor: np.ndarray  # (6,) RMS of the noise-only residual, N / N m
    rel_se: np.ndarray  # (6,) relative standard error of rms^2 / floor^2 (each mean square: sqrt(2 tau / N))

    def excess(self) -> np.ndarray:
        """(6,) excess in units of the floor: rms^2 / floor^2 - 1 - 3 rel_se, at least 0 (0 for unscored DOFs)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            ex = self.rms ** 2 / self.floor ** 2 - 1.0 - 3.0 * self.rel_se
        return np.where(np.isfinite(ex), np.maximum(ex, 0.0), 0.0)


def force_floor(preps, p: PlantParameters, residuals, seed=FLOOR_SEED) -> ForceFloor:
    """RMS equation-error residual per DOF and its noise floor (module docstring).

    Parameters
    ----------
    preps : list of Prepared
    p : PlantParameters
        Nominal plant.
    residuals : list of (n, 6) ndarray
        The runs' nominal residuals (:func:`udrobot_ctrl.gap.attribute.residual`).
    seed : int
    """
    rng = np.random.default_rng(seed)
    real, noise = [], []
    for prep, r0 in zip(preps, residuals):
        real.append(r0)
        noise.append(residual(_renoised(prep, rng), p) - r0)
    real, noise = np.concatenate(real), np.concatenate(noise)
    ok = np.isfinite(real) & np.isfinite(noise)
    rms, floor, rel = np.full(6, np.nan), np.full(6, np.nan), np.full(6, np.nan)
    for i in range(6):
        k = ok[:, i]
        if k.sum() < 20 or not np.any(noise[k, i]):
            continue
        rms[i] = float(np.sqrt(np.mean(real[k, i] ** 2)))
        floor[i] = float(np.sqrt(np.mean(noise[k, i] ** 2)))
        rel[i] = float(np.sqrt(2.0 * (tau_int(real[k, i] ** 2) + tau_int(noise[k, i] ** 2)) / k.sum()))
    return ForceFloor(rms, floor, rel)


@dataclass(frozen=True)
class Location:
    """A channel holding part of the gap above its noise floor, and where/when it holds it."""

    channel: str
    share: float  # share of the summed excess over the floor (of its DOF's residual force; see the module docstring)
    nrmse: float  # the channel's replay NRMSE on all runs (nan when not logged)
    floor: float  # its replay noise floor (NRMSE with no unmodelled effect)
    condition: str  # operating regime that concentrates the error
    windows: list  # worst time windows [[t0, t1], ...], s, in ``run``
    run: str
    regimes: dict  # family -> bin -> {"error_share", "time_share"}
    dof: str | None = None  # the DOF whose residual force located it (None: ranked on the replay)
    force_ratio: float | None = None  # RMS residual force of that DOF / its noise floor

    def to_json(self) -> dict:
        out = {"channel": self.channel, "share": round(self.share, 3), "nrmse": self.nrmse, "floor": self.floor,
               "condition": self.condition, "windows": self.windows, "run": self.run, "regimes": self.regimes}
        if self.dof is not None:
            out["dof"], out["force_ratio"] = self.dof, self.force_ratio
        return out


@dataclass(frozen=True)
class Located:
    """Where the nominal model disagrees with the runs: located channels and the per-channel figures behind them."""

    locations: tuple  # Location, ranked by share of the excess
    nrmse: dict  # channel -> NRMSE on all runs
    floor: dict  # channel -> noise-floor NRMSE
    excess_share: dict  # channel -> share of the summed excess max(NRMSE^2 - floor^2, 0)
    channel_share: dict  # channel -> share of the summed normalised error energy (floor not removed)
    residual_frequency_share: dict  # band -> DOF -> share of the equation-error residual power
    force: ForceFloor | None = None  # residual force per DOF against its noise floor
    ranked_by: str = "force"  # "force" (equation error per DOF) or "replay" (no DOF scored)

    def replay_to_floor(self) -> float:
        """Summed replay NRMSE^2 over the summed floor NRMSE^2 of the channels with a floor (nan without one): near
        1 or below, the nominal replay is as far from the runs as their noise and reconstruction alone put it."""
        both = [c for c in self.nrmse if self.floor.get(c, 0.0) > 0]
        den = sum(self.floor[c] ** 2 for c in both)
        return sum(self.nrmse[c] ** 2 for c in both) / den if den > 0 else float("nan")

    def gap_dofs(self, min_share: float = GAP_SHARE) -> dict:
        """The DOFs holding at least ``min_share`` of the located gap (index -> summed share of their channels,
        largest first): a channel ranked by its DOF's residual force counts for that DOF, a replayed channel for the
        DOF it measures."""
        of_channel = {c: i for i, cs in OBSERVING.items() for c in cs}
        out = {}
        for x in self.locations:
            i = DOF.index(x.dof) if x.dof in DOF else of_channel.get(x.channel)
            if i is not None:
                out[i] = out.get(i, 0.0) + x.share
        return {i: v for i, v in sorted(out.items(), key=lambda kv: -kv[1]) if v >= min_share}

    def detail_json(self) -> dict:
        """The report's ``location_detail``."""
        out = {"channel_share": {c: round(v, 3) for c, v in self.channel_share.items()},
               "nrmse": {c: round(v, 4) for c, v in self.nrmse.items()},
               "floor": {c: round(v, 4) for c, v in self.floor.items()},
               "excess_share": {c: round(v, 3) for c, v in self.excess_share.items()},
               "floor_method": (f"nominal replay as synthetic truth, each channel's measured noise added, windows "
                                f"restarted from the noisy/smoothed synthetic measurement (plus the smoother's "
                                f"estimated bias; a velocity the model-based smoother reconstructed: the synthetic "
                                f"truth plus a draw of its posterior std); {FLOOR_DRAWS} seeded draws; excess = "
                                f"max(NRMSE^2 - floor^2, 0)"),
               "replay_to_floor": round(self.replay_to_floor(), 3),
               "ranked_by": self.ranked_by}
        if self.force is not None:
            ex = self.force.excess()
            tot = ex.sum()
            out["force"] = {d: {"rms": self.force.rms[i], "floor": self.force.floor[i],
                                "ratio": self.force.rms[i] / self.force.floor[i] if self.force.floor[i] > 0 else None,
                                "excess_share": ex[i] / tot if tot > 0 else 0.0}
                            for i, d in enumerate(DOF) if np.isfinite(self.force.rms[i])}
        if self.residual_frequency_share:
            out["residual_frequency_share"] = self.residual_frequency_share
        return out


def excess_shares(nrmse: dict, floor: dict) -> dict:
    """Channel -> share of the summed excess max(NRMSE^2 - floor^2, 0), ranked (all zero when none exceeds)."""
    ex = {c: max(v ** 2 - floor.get(c, 0.0) ** 2, 0.0) for c, v in nrmse.items() if np.isfinite(v)}
    total = sum(ex.values())
    return {c: (v / total if total > 0 else 0.0) for c, v in sorted(ex.items(), key=lambda kv: -kv[1])}


def _regime_condition(c, per_run):
    """Regime shares of channel c's error and the regime that concentrates it (or None).

    A family some runs do not have (the distance to a surface: a run whose altitude is valid and one whose altitude
    is not, or without sidecar walls) is binned over the runs that have it."""
    of_run = [_regimes(prep) for _s, prep, _e2 in per_run]
    regimes, cond, best_excess = {}, None, 0.0
    for fam in dict.fromkeys(f for r in of_run for f in r):
        num, den = {}, {}
        for (_s, _prep, e2), fams in zip(per_run, of_run):
            if fam not in fams:
                continue
            vals, bins, unit = fams[fam]
            ok = np.isfinite(e2) & np.isfinite(vals)
            for lo, hi in zip(bins[:-1], bins[1:]):
                sel = ok & (vals >= lo) & (vals < hi)
                lab = bin_label(lo, hi, unit)
                num[lab] = num.get(lab, 0.0) + float(np.sum(e2[sel]))
                den[lab] = den.get(lab, 0) + int(sel.sum())
        tn, td = sum(num.values()) or 1.0, sum(den.values()) or 1
        regimes[fam] = {lab: {"error_share": round(num[lab] / tn, 3), "time_share": round(den[lab] / td, 3)}
                        for lab in num if den[lab] > 0}
        for lab, v in regimes[fam].items():
            excess = v["error_share"] - v["time_share"]
            if v["error_share"] >= 0.3 and excess > best_excess:
                best_excess = excess
                cond = (f"{fam} {lab} (holds {100 * v['error_share']:.0f}% of the {c} error in "
                        f"{100 * v['time_share']:.0f}% of the time)")
    return regimes, cond


def _force_windows(preps, residuals, i) -> tuple:
    """(worst windows [[t0, t1], ...] s, run name) of DOF ``i``'s equation-error residual force, in the run where its
    squared residual sums largest; ([], "") without residuals."""
    best = None
    for prep, res in zip(preps, residuals or ()):
        if res is None or not np.isfinite(res[:, i]).any():
            continue
        e2 = np.where(np.isfinite(res[:, i]), res[:, i], 0.0) ** 2
        if best is None or e2.sum() > best[0]:
            best = (float(e2.sum()), prep, e2)
    if best is None or not best[0] > 0:
        return [], ""
    return _windows(best[1].t, best[2], best[1].dt), best[1].name


def _frequency_detail(preps, residuals):
    acc = {}
    for prep, res in zip(preps, residuals):
        for band, arr in frequency_shares(res, prep.dt).items():
            acc.setdefault(band, []).append(arr)
    return {band: {d: round(float(np.mean([a[i] for a in arrs])), 3) for i, d in enumerate(DOF)}
            for band, arrs in acc.items()}


def _ranking(force: ForceFloor | None, replay_shares: dict):
    """(channel, share, dof or None) ranked: by DOF force excess when any DOF is scored, else by replay excess."""
    if force is not None and np.isfinite(force.rms).any():
        ex = force.excess()
        tot = ex.sum()
        order = np.argsort(-ex, kind="stable")
        return [(VEL[i], float(ex[i] / tot) if tot > 0 else 0.0, DOF[i]) for i in order if np.isfinite(force.rms[i])]
    return [(c, sh, None) for c, sh in replay_shares.items()]


def locate(preps, sims, scale, floor, residuals=None, p=None, min_share=0.1) -> Located:
    """Where the nominal model disagrees with the runs, above the noise floor (module docstring).

    Parameters
    ----------
    preps, sims : lists
        Prepared runs and their nominal multiple-shooting simulations.
    scale : dict
        Channel -> normalising scale (std of the measurement).
    floor : dict
        Channel -> replay noise-floor NRMSE (:func:`noise_floor`); a channel missing from it has floor 0.
    residuals : list of (n, 6) arrays, optional
        Equation-error residuals per run (frequency bands and, with ``p``, the force ranking).
    p : PlantParameters, optional
        Nominal plant; without it (or without residuals) channels are ranked on the replay.
    min_share : float
        Channels holding at least this share of the excess are located.
    """
    energy, count, per_run = {}, {}, {}
    for prep, sim in zip(preps, sims):
        for c, e in errors(prep, sim).items():
            if c not in scale or scale[c] <= 0:
                continue
            e2 = (e / scale[c]) ** 2
            s = float(np.nansum(e2))
            energy[c] = energy.get(c, 0.0) + s
            count[c] = count.get(c, 0) + int(np.isfinite(e2).sum())
            per_run.setdefault(c, []).append((s, prep, e2))
    total = sum(energy.values()) or 1.0
    channel_share = {c: v / total for c, v in sorted(energy.items(), key=lambda kv: -kv[1])}
    nrmse = {c: float(np.sqrt(energy[c] / count[c])) for c in energy if count[c]}
    shares = excess_shares(nrmse, floor)
    force = force_floor(preps, p, residuals) if residuals is not None and p is not None else None
    ranking = _ranking(force, shares)
    locations = []
    for c, sh, dof in ranking:
        if sh < min_share or sh <= 0:
            continue
        if c in per_run:
            best_run = max(per_run[c], key=lambda x: x[0])
            regimes, cond = _regime_condition(c, per_run[c])
            windows, run = _windows(best_run[1].t, best_run[2], best_run[1].dt), best_run[1].name
        else:  # a DOF whose velocity channel is not replayed (derived or unlogged): its residual force's windows
            regimes, cond, windows, run = {}, None, *_force_windows(preps, residuals, VEL.index(c))
        i = VEL.index(c)
        locations.append(Location(
            channel=c, share=sh, nrmse=nrmse.get(c, float("nan")), floor=floor.get(c, float("nan")),
            condition=cond or "spread over all regimes (no regime concentrates it)", windows=windows, run=run,
            regimes=regimes, dof=dof,
            force_ratio=float(force.rms[i] / force.floor[i]) if dof is not None and force.floor[i] > 0 else None))
    return Located(locations=tuple(locations), nrmse=nrmse, floor={c: floor[c] for c in nrmse if c in floor},
                   excess_share=shares, channel_share=channel_share,
                   residual_frequency_share=_frequency_detail(preps, residuals) if residuals else {},
                   force=force, ranked_by="force" if ranking and ranking[0][2] is not None else "replay")
