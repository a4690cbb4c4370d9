"""Pilot inputs of a QGroundControl tlog from the joystick itself: MANUAL_CONTROL through ArduSub's conversion.

QGroundControl logs the MANUAL_CONTROL messages it sends (since QGC PR #7714, 2019) at the joystick rate (~24 Hz
on the shared BlueROV2 tlog), while ArduSub reports the resulting RC overrides in RC_CHANNELS at the telemetry
rate (2 Hz by QGC's default). ArduSub turns each MANUAL_CONTROL into RC overrides in
``Sub::transform_manual_control_to_rc_override`` (ArduSub/joystick.cpp, the same arithmetic in Sub-4.1 .. 4.5)::

    rpyScale      = 0.4 * gain                         (float)
    throttleScale = 0.8 * gain * JS_THR_GAIN           (float)
    throttleBase  = (int16) (1500 - 500 * throttleScale)
    ch3 throttle  = constrain_int16((z + zTrim) * throttleScale + throttleBase, 1100, 1900)
    ch4 yaw       = constrain_int16(r * rpyScale + 1500, 1100, 1900)
    ch5 forward   = constrain_int16((x + xTrim) * rpyScale + 1500, 1100, 1900)
    ch6 lateral   = constrain_int16((y + yTrim) * rpyScale + 1500, 1100, 1900)

(the float is truncated to int16 when passed to ``constrain_int16``). The pilot ``gain`` is not in MANUAL_CONTROL:
it starts at JS_GAIN_DEFAULT and the pilot changes it with joystick buttons in flight. It is therefore calibrated
on the log itself: every RC_CHANNELS sample is compared with the MANUAL_CONTROL messages sent shortly before it,
the gains (on a grid over ArduSub's range 0.1 .. 1.0, plus its reachable gain settings) that reproduce it exactly
are kept, and consecutive samples are grouped into stretches of one gain. The input-hold trims (xTrim, yTrim,
zTrim) and the roll/pitch mode are set by buttons and not modelled: RC_CHANNELS samples no gain explains (those,
an RC receiver, overrides timed out) and stretches the fit does not support fall back to RC_CHANNELS alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.ardusub.params import RC_MAP
from udrobot_ctrl.io.runlog import hold_previous
from udrobot_ctrl.io.streams import Stream

RC_FIELDS = tuple(f"chan{n}_raw" for n in range(1, 9))
# the RC overrides MANUAL_CONTROL z, r, x, y drive (ArduSub's channel map)
JOYSTICK_CHANNELS = tuple(RC_MAP[n] for n in ("throttle", "yaw", "forward", "lateral"))
TRIM_CHANNELS = (RC_MAP["pitch"], RC_MAP["roll"])  # 1500 + pitch / roll trim (joystick buttons, zero at boot)
PWM_CENTER = 1500  # us, rpyCenter
PWM_LIMITS = (1100, 1900)  # us, the clamps of transform_manual_control_to_rc_override
GAIN_RANGE = (0.1, 1.0)  # ArduSub constrains the pilot gain to this range (init_joystick)
GAIN_STEP = 0.001  # grid step of the gain search (a full-stick sample pins the gain to 1/400 = 0.0025)
ARDUSUB_DEFAULTS = {"JS_GAIN_DEFAULT": 0.5, "JS_GAIN_MIN": 0.25, "JS_GAIN_MAX": 1.0, "JS_GAIN_STEPS": 4.0,
                    "JS_THR_GAIN": 1.0, "RC_OVERRIDE_TIME": 3.0}  # ArduSub's documented parameter defaults
MATCH_WINDOW_S = 0.3  # s, assumed: an RC_CHANNELS sample reflects a MANUAL_CONTROL sent at most this long before it
# (measured on the shared BlueROV2 tlogs: the latest matching message 0 .. 82 ms before, median 20-22 ms)
PAIR_CHUNK = 512  # (RC sample, candidate) pairs evaluated at once (512 x G x 4 float32: ~7 MB on the default grid)
MIN_SUPPORT = 2  # RC_CHANNELS samples that must pin a stretch's gain (one odd sample does not make a gain change)


@dataclass(frozen=True)
class JoystickParams:
    """ArduSub's joystick parameters as the log gives them (or ArduSub's defaults, named in ``assumed``).

    Attributes
    ----------
    default_gain : float
        JS_GAIN_DEFAULT, the gain at boot.
    settings : tuple of float
        Gains the pilot can reach: JS_GAIN_MIN + k (JS_GAIN_MAX - JS_GAIN_MIN) / (JS_GAIN_STEPS - 1), the default,
        and the 0.5 / 1.0 of the gain-toggle button.
    throttle_gain : float
        JS_THR_GAIN.
    override_time : float
        RC_OVERRIDE_TIME, s: how long ArduSub holds an override without a new MANUAL_CONTROL.
    assumed : tuple of str
        Parameters not in the log (ArduSub's default used).
    """

    default_gain: float
    settings: tuple
    throttle_gain: float
    override_time: float
    assumed: tuple


def joystick_params(params: dict) -> JoystickParams:
    """:class:`JoystickParams` from the log's parameters, ArduSub's defaults for the missing ones."""
    value, assumed = {}, []
    for name, default in ARDUSUB_DEFAULTS.items():
        v = params.get(name)
        if v is None or not np.isfinite(v):
            v = default
            assumed.append(name)
        value[name] = float(v)
    lo = min(max(value["JS_GAIN_MIN"], 0.1), 0.8)
    hi = min(max(value["JS_GAIN_MAX"], lo), 1.0)
    steps = int(min(max(value["JS_GAIN_STEPS"], 1), 10))
    default = float(np.clip(value["JS_GAIN_DEFAULT"], *GAIN_RANGE))
    ladder = [lo + k * (hi - lo) / (steps - 1) for k in range(steps)] if steps > 1 else []
    settings = tuple(sorted({round(g, 6) for g in [*ladder, default, 0.5, 1.0]}))
    return JoystickParams(default, settings, value["JS_THR_GAIN"], value["RC_OVERRIDE_TIME"], tuple(assumed))


def rc_override(x, y, z, r, gain, throttle_gain=1.0) -> np.ndarray:
    """ArduSub's RC overrides (us) for MANUAL_CONTROL axes, in its float32 arithmetic, trims zero.

    Parameters
    ----------
    x, y, r : array_like
        MANUAL_CONTROL forward, lateral, yaw (-1000 .. 1000).
    z : array_like
        MANUAL_CONTROL throttle (0 .. 1000, 500 neutral).
    gain : float or array_like
        Pilot gain (broadcast against the axes, e.g. shape (G, 1) for a grid of gains).
    throttle_gain : float
        JS_THR_GAIN.

    Returns
    -------
    ndarray, shape (..., 4)
        Channels 3 (throttle), 4 (yaw), 5 (forward), 6 (lateral), integer us as float.
    """
    f32 = np.float32
    g = np.asarray(gain, dtype=f32)
    rpy = (0.4 * g.astype(np.float64)).astype(f32)
    thr = ((0.8 * g.astype(np.float64)).astype(f32) * f32(throttle_gain)).astype(f32)
    base = np.trunc(f32(PWM_CENTER) - f32(500) * thr).astype(f32)

    def out(v):
        return np.clip(np.trunc(v), *PWM_LIMITS).astype(float)

    ax = [np.asarray(a, dtype=f32) for a in (z, r, x, y)]
    return np.stack([out(ax[0] * thr + base), out(ax[1] * rpy + f32(PWM_CENTER)), out(ax[2] * rpy + f32(PWM_CENTER)),
                     out(ax[3] * rpy + f32(PWM_CENTER))], axis=-1)


def gain_grid(settings) -> np.ndarray:
    """Gains searched: ArduSub's range on a :data:`GAIN_STEP` grid plus the reachable ``settings``."""
    grid = np.arange(GAIN_RANGE[0], GAIN_RANGE[1] + GAIN_STEP / 2, GAIN_STEP)
    return np.unique(np.round(np.r_[grid, list(settings)], 6))


def consistent_gains(mc_t, mc_axes, rc_t, rc_joy, grid, throttle_gain, window=MATCH_WINDOW_S) -> np.ndarray:
    """For each RC_CHANNELS sample, the gains of ``grid`` at which a MANUAL_CONTROL sent within ``window`` s before it
    reproduces its channels 3..6 exactly.

    Parameters
    ----------
    mc_t : (n,) ndarray
        MANUAL_CONTROL times, s (sorted).
    mc_axes : (n, 4) ndarray
        x, y, z, r.
    rc_t : (m,) ndarray
        RC_CHANNELS times, s.
    rc_joy : (m, 4) ndarray
        RC_CHANNELS channels 3, 4, 5, 6, us.
    grid : (G,) ndarray
    throttle_gain : float
    window : float
        s.

    Returns
    -------
    (m, G) bool ndarray
    """
    out = np.zeros((rc_t.size, grid.size), bool)
    hi = np.searchsorted(mc_t, rc_t, side="right")
    lo = np.searchsorted(mc_t, rc_t - window, side="left")
    count = hi - lo
    k_of = np.repeat(np.arange(rc_t.size), count)  # (RC sample, MANUAL_CONTROL candidate) pairs
    j_of = np.arange(k_of.size) - np.repeat(np.cumsum(count) - count, count) + np.repeat(lo, count)
    for a in range(0, k_of.size, PAIR_CHUNK):
        k, j = k_of[a:a + PAIR_CHUNK], j_of[a:a + PAIR_CHUNK]
        cand = mc_axes[j][:, :, None]  # (c, 4, 1) against the (G,) grid
        pred = rc_override(cand[:, 0], cand[:, 1], cand[:, 2], cand[:, 3], grid, throttle_gain)  # (c, G, 4)
        np.logical_or.at(out, k, np.all(pred == rc_joy[k][:, None, :], axis=-1))
    return out


@dataclass(frozen=True)
class GainStretch:
    """RC_CHANNELS samples ``first`` .. ``last`` (indices) explained by one gain.

    Attributes
    ----------
    first, last : int
        Indices of the stretch's first and last RC_CHANNELS samples.
    pinned : tuple of int
        Indices of the samples that constrain the gain (the others fit every gain: sticks at neutral).
    lo, hi : float
        Range of the gains that reproduce every sample of the stretch.
    gain : float
        The gain used: the one reachable setting in [lo, hi] nearest its middle, else the middle.
    setting : bool
        ``gain`` is one of ArduSub's reachable gain settings.
    """

    first: int
    last: int
    pinned: tuple
    lo: float
    hi: float
    gain: float
    setting: bool


def _stretch(first, last, pinned, allowed, grid, settings) -> GainStretch:
    ok = grid[allowed]
    lo, hi = float(ok.min()), float(ok.max())
    inside = [s for s in settings if allowed[np.searchsorted(grid, round(s, 6))]]
    mid = 0.5 * (lo + hi)
    if inside:
        return GainStretch(first, last, tuple(pinned), lo, hi, min(inside, key=lambda s: abs(s - mid)), True)
    return GainStretch(first, last, tuple(pinned), lo, hi, float(ok[np.argmin(np.abs(ok - mid))]), False)


def gain_stretches(consistent, grid, settings) -> tuple:
    """Group RC_CHANNELS samples into stretches of one gain (greedy, in time order).

    A sample no gain explains is left out (returned in ``unexplained``); a sample that fits no gain of the current
    stretch starts a new one. A stretch pinned by fewer than :data:`MIN_SUPPORT` samples is not supported.

    Returns
    -------
    (list of GainStretch, list of GainStretch, (k,) int ndarray)
        Supported stretches, unsupported ones, unexplained sample indices.
    """
    explained = consistent.any(axis=1)
    pinning = explained & ~consistent.all(axis=1)
    stretches, current, first, last, pinned = [], None, None, None, []
    for k in np.flatnonzero(explained):
        if current is None:
            current, first, last, pinned = consistent[k].copy(), k, k, []
        elif not (current & consistent[k]).any():
            stretches.append(_stretch(first, last, pinned, current, grid, settings))
            current, first, pinned = consistent[k].copy(), k, []
        current &= consistent[k]
        last = k
        if pinning[k]:
            pinned.append(int(k))
    if current is not None:
        stretches.append(_stretch(first, last, pinned, current, grid, settings))
    supported = [s for s in stretches if len(s.pinned) >= MIN_SUPPORT or not s.pinned]
    unsupported = [s for s in stretches if 0 < len(s.pinned) < MIN_SUPPORT]
    return supported, unsupported, np.flatnonzero(~explained)


def _merge(spans) -> list:
    out = []
    for a, b in sorted(spans):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


def _inside(t, spans) -> np.ndarray:
    mask = np.zeros(t.shape, bool)
    for a, b in spans:
        mask |= (t >= a) & (t < b)
    return mask


@dataclass(frozen=True)
class JoystickRC:
    """The pilot-input stream (RC_CHANNELS field names, us), the notes saying how it was made, the gain stretches
    found (indices into RC_CHANNELS; empty without it) and the gain changes (s, log clock: the last sample of the
    old gain and the first of the new one)."""

    stream: Stream
    notes: list
    stretches: tuple = ()
    changes: tuple = ()


def _senders(mc: Stream) -> tuple:
    """(keep mask, note) of the most frequent MANUAL_CONTROL sender (system, component)."""
    pairs = np.stack([mc.fields["src_system"], mc.fields["src_component"]], axis=1)
    uniq, counts = np.unique(pairs, axis=0, return_counts=True)
    best = uniq[np.argmax(counts)]
    keep = np.all(pairs == best, axis=1)
    note = f"system {best[0]:.0f}, component {best[1]:.0f}"
    if not keep.all():
        note += (f"; {int((~keep).sum())} MANUAL_CONTROL from other senders ("
                 + ", ".join(f"{s:.0f}/{c:.0f}" for s, c in uniq if not (s == best[0] and c == best[1])) + ") dropped")
    return keep, note


def report_lags(mc_t, pwm, rc_t, rc_joy, window=MATCH_WINDOW_S) -> np.ndarray:
    """For each RC_CHANNELS sample, how long (s) before it the latest MANUAL_CONTROL whose converted channels
    ``pwm`` equal its channels 3..6 was sent (nan when none within ``window``)."""
    lags = np.full(rc_t.size, np.nan)
    hi = np.searchsorted(mc_t, rc_t, side="right")
    lo = np.searchsorted(mc_t, rc_t - window, side="left")
    for k in range(rc_t.size):
        match = np.flatnonzero(np.all(pwm[lo[k]:hi[k]] == rc_joy[k], axis=1))
        if match.size:
            lags[k] = rc_t[k] - mc_t[lo[k] + match[-1]]
    return lags


def _agreement_notes(mc_t, pwm, rc_t, rc_joy) -> list:
    """``pilot input: check:`` lines: how the converted joystick agrees with the RC_CHANNELS samples it explains."""
    if rc_t.size == 0:
        return []
    lags = report_lags(mc_t, pwm, rc_t, rc_joy)
    hit = np.isfinite(lags)
    held = hold_previous(mc_t, pwm, rc_t)
    dev = np.abs(held - rc_joy)
    fin = np.isfinite(dev).all(axis=1)
    out = [f"pilot input: check: {int(hit.sum())} of {rc_t.size} RC_CHANNELS samples equal (0 us, channels 3..6) the "
           f"converted joystick of a MANUAL_CONTROL sent before them at the gain used"
           + (f", {lags[hit].min() * 1e3:.0f} .. {lags[hit].max() * 1e3:.0f} ms before (median "
              f"{np.median(lags[hit]) * 1e3:.0f} ms: uplink, ArduSub's report slot, downlink)" if hit.any() else "")]
    if fin.any():
        out.append(f"pilot input: check: the converted joystick held to each RC_CHANNELS receive time differs from it "
                   f"by median {np.median(dev[fin]):.0f} us, max {dev[fin].max():.0f} us (where the stick moved within "
                   f"that delay)")
    return out


def _reported_gain_notes(mc_t, gain_at, reported) -> list:
    """``pilot input: check:`` line comparing the gain used with ArduSub's own NAMED_VALUE_FLOAT ``PilotGain``
    reports ((times, values); none -> no line)."""
    if reported is None or len(reported[0]) == 0:
        return []
    rt, rv = np.asarray(reported[0], float), np.asarray(reported[1], float)
    used = hold_previous(mc_t, gain_at, rt)
    inside = np.isfinite(used)
    if not inside.any():
        return []
    same = np.abs(used[inside] - rv[inside]) < GAIN_STEP
    line = (f"pilot input: check: ArduSub's own NAMED_VALUE_FLOAT PilotGain (values "
            f"{', '.join(f'{v:g}' for v in np.unique(rv[inside]))}) equals the gain used at {int(same.sum())} of "
            f"{int(inside.sum())} reports")
    if not same.all():
        first = rt[inside][~same][:5] - mc_t[0]
        line += f"; differs at {', '.join(f'{x:.1f}' for x in first)}{' ...' if (~same).sum() > 5 else ''} s"
    return [line]


def override_fallback(t, rc_t, override_time) -> tuple:
    """Spans (s) where ArduSub's overrides are not the joystick's: before the first MANUAL_CONTROL, from
    ``override_time`` (RC_OVERRIDE_TIME) after the last, and inside silences longer than it; with their notes."""
    gaps = np.flatnonzero(np.diff(t) > override_time)
    spans = [(-np.inf, t[0]), (t[-1] + override_time, np.inf)] + [(t[k] + override_time, t[k + 1]) for k in gaps]
    notes = []
    if gaps.size:
        notes.append(f"pilot input: {gaps.size} MANUAL_CONTROL silence(s) longer than RC_OVERRIDE_TIME = "
                     f"{override_time:g} s (the overrides expire): RC_CHANNELS alone there")
    if rc_t is not None and rc_t.size:
        before, after = int((rc_t < t[0]).sum()), int((rc_t >= t[-1] + override_time).sum())
        if before or after:
            notes.append(f"pilot input: RC_CHANNELS alone for its {before} sample(s) before the first MANUAL_CONTROL "
                         f"and {after} from RC_OVERRIDE_TIME = {override_time:g} s after the last (the overrides "
                         f"are not the joystick's there)")
    return spans, notes


@dataclass(frozen=True)
class GainFit:
    """The pilot gain over a log (:func:`fit_gains`).

    Attributes
    ----------
    stretches : tuple of GainStretch
        Supported stretches (indices into RC_CHANNELS), in time order.
    changes : tuple of (float, float)
        For each pair of consecutive stretches, the times (s) of the last sample pinning the old gain and the first
        pinning the new one.
    bad : tuple of int
        RC_CHANNELS samples the joystick does not reproduce at one supported gain.
    """

    stretches: tuple
    changes: tuple
    bad: tuple

    def gain_at(self, t, default: float) -> np.ndarray:
        """The gain at times ``t`` (s): each stretch's from half-way through the change before it; ``default`` for a
        stretch that never pins its gain."""
        out = np.full(np.shape(t), default, dtype=float)
        for k, s in enumerate(self.stretches):
            start = -np.inf if k == 0 else 0.5 * sum(self.changes[k - 1])
            out[np.asarray(t) >= start] = s.gain if s.pinned else default
        return out


def _joystick_channels(rc: Stream) -> np.ndarray:
    """RC_CHANNELS channels 3, 4, 5, 6 (us), shape (m, 4)."""
    return np.stack([rc.fields[RC_FIELDS[ch - 1]] for ch in JOYSTICK_CHANNELS], axis=1)


def fit_gains(t, axes, rc: Stream, jp: JoystickParams, live_rc) -> GainFit:
    """Fit the pilot gain on the RC_CHANNELS samples ``live_rc`` (mask) from MANUAL_CONTROL times ``t`` and axes
    (x, y, z, r) by ArduSub's conversion (:func:`consistent_gains`, :func:`gain_stretches`)."""
    rc_joy = _joystick_channels(rc)
    idx = np.flatnonzero(live_rc)
    grid = gain_grid(jp.settings)
    sub = consistent_gains(t, axes, rc.t[idx], rc_joy[idx], grid, jp.throttle_gain)
    supported, unsupported, unexplained = gain_stretches(sub, grid, jp.settings)
    stretches = tuple(GainStretch(int(idx[s.first]), int(idx[s.last]), tuple(int(idx[p]) for p in s.pinned), s.lo,
                                  s.hi, s.gain, s.setting) for s in supported)
    bad = [int(idx[k]) for k in unexplained]
    bad += [int(idx[k]) for s in unsupported for k in range(s.first, s.last + 1)]
    changes = tuple((rc.t[a.pinned[-1]] if a.pinned else rc.t[a.last], rc.t[b.pinned[0]] if b.pinned else rc.t[b.first])
                    for a, b in zip(stretches[:-1], stretches[1:]))
    return GainFit(stretches, changes, tuple(sorted(bad)))


def _fit_notes(fit: GainFit, rc_t, t0, default: float, default_src: str) -> list:
    """``pilot input:`` lines for each gain stretch, gain change and unexplained sample (times s after ``t0``)."""
    notes = []
    for s in fit.stretches:
        what = (f"gain {s.gain:g} ({'an ArduSub gain setting' if s.setting else 'not one of ArduSub gain settings'}; "
                f"gains reproducing every sample: {s.lo:.3f}..{s.hi:.3f} on a {GAIN_STEP:g} grid)" if s.pinned else
                f"gain not pinned (the sticks sat at neutral at every RC_CHANNELS sample): {default:g} "
                f"ASSUMED ({default_src})")
        notes.append(f"pilot input: {what}, fitted on RC_CHANNELS samples {s.first + 1}..{s.last + 1} "
                     f"({rc_t[s.first] - t0:.1f}..{rc_t[s.last] - t0:.1f} s; {len(s.pinned)} of them pin the gain), "
                     f"each reproduced exactly by a MANUAL_CONTROL sent up to {MATCH_WINDOW_S:g} s before it")
    for (a, b), s, prev in zip(fit.changes, fit.stretches[1:], fit.stretches[:-1]):
        if s.gain != prev.gain:
            notes.append(f"pilot input: gain changed from {prev.gain:g} to {s.gain:g} between {a - t0:.2f} and "
                         f"{b - t0:.2f} s (a joystick button), placed at {0.5 * (a + b) - t0:.2f} s")
    if fit.bad:
        shown = ", ".join(f"{rc_t[k] - t0:.1f}" for k in fit.bad[:8]) + (" ..." if len(fit.bad) > 8 else "")
        notes.append(f"pilot input: {len(fit.bad)} RC_CHANNELS sample(s) (at {shown} s) not reproduced by the joystick "
                     f"at one gain (input hold, roll/pitch mode, a lone odd sample, an RC receiver): RC_CHANNELS alone "
                     f"from the sample before each to the one after it")
    return notes


def _merged_fields(t, pwm, rc: Stream, fallback) -> tuple:
    """(times, fields, note): channels 3..6 from the converted joystick ``pwm`` (held) outside ``fallback``, from
    RC_CHANNELS (held) inside it; channels 1, 2, 7, 8 from RC_CHANNELS (held); at the joystick times outside the
    fallback, every RC_CHANNELS time and each fallback start."""
    live = ~_inside(t, fallback)
    starts = np.array([a for a, _ in fallback if np.isfinite(a)])
    times = np.unique(np.r_[t[live], rc.t, starts])
    from_rc = _inside(times, fallback)
    fields = {}
    for n, f in enumerate(RC_FIELDS, start=1):
        fields[f] = hold_previous(rc.t, rc.fields[f], times)
        if n in JOYSTICK_CHANNELS:
            joy = hold_previous(t, pwm[:, JOYSTICK_CHANNELS.index(n)], times)
            fields[f][~from_rc] = joy[~from_rc]
    note = (f"pilot input: rcin_1, rcin_2, rcin_7, rcin_8 (pitch, roll, camera) from RC_CHANNELS held; channels 3..6 "
            f"at {int((~from_rc).sum())} sample times from MANUAL_CONTROL, at {int(from_rc.sum())} from RC_CHANNELS")
    return times, fields, note


def _joystick_only(t, pwm, fallback) -> tuple:
    """(times, fields) without RC_CHANNELS: channels 3..6 from ``pwm``, 1 and 2 at 1500 us (trims zero, assumed),
    7 and 8 nan; joystick times outside ``fallback``."""
    live = ~_inside(t, fallback)
    fields = {f: np.full(int(live.sum()), np.nan) for f in RC_FIELDS}
    for ch in TRIM_CHANNELS:
        fields[RC_FIELDS[ch - 1]][:] = PWM_CENTER
    for c, ch in enumerate(JOYSTICK_CHANNELS):
        fields[RC_FIELDS[ch - 1]] = pwm[live, c]
    return t[live], fields


def pilot_input(mc: Stream, rc: Stream | None, params: dict, reported_gain=None) -> JoystickRC:
    """rcin channels 1..8 from MANUAL_CONTROL (channels 3..6) with the gain calibrated on RC_CHANNELS.

    Parameters
    ----------
    mc : Stream
        MANUAL_CONTROL as the ground station sent it: fields x, y, z, r, src_system, src_component.
    rc : Stream or None
        RC_CHANNELS (fields chan1_raw .. chan8_raw), the overrides ArduSub reports.
    params : dict
        The log's parameters (JS_GAIN_*, JS_THR_GAIN, RC_OVERRIDE_TIME).
    reported_gain : (times, values) or None
        ArduSub's NAMED_VALUE_FLOAT ``PilotGain`` reports, compared with the gain used (a check in the notes only).

    Returns
    -------
    JoystickRC
        A stream named ``PILOT_RC`` with fields chan1_raw .. chan8_raw, us: channels 3..6 by ArduSub's conversion of
        the joystick, except where it does not explain RC_CHANNELS (and outside the overrides' span: RC_CHANNELS
        there); 1, 2, 7, 8 held from RC_CHANNELS (without RC_CHANNELS: 1, 2 at 1500 us assumed, 7, 8 nan).
    """
    keep, sender = _senders(mc)
    t = mc.t[keep]
    axes = np.stack([mc.fields[f][keep] for f in ("x", "y", "z", "r")], axis=1)
    jp = joystick_params(params)
    rate = (t.size - 1) / (t[-1] - t[0]) if t.size > 1 else float("nan")
    notes = [f"pilot input: rcin_3..rcin_6 (throttle, yaw, forward, lateral) from MANUAL_CONTROL z, r, x, y as the "
             f"ground station sent it ({sender}; {t.size} messages, {rate:.1f} Hz; times below are s after the first "
             f"one) through ArduSub's conversion (joystick.cpp transform_manual_control_to_rc_override: ch5 = 1500 + "
             f"0.4 gain x, ch6 = 1500 + 0.4 gain y, ch4 = 1500 + 0.4 gain r, ch3 = int(1500 - 400 gain JS_THR_GAIN) "
             f"+ 0.8 gain JS_THR_GAIN z, truncated to whole us and clamped to 1100..1900; input-hold trims zero); "
             f"stamped at the ground station's send time (the uplink delay is not in the log)"] + list(mc.notes)
    if jp.assumed:
        notes.append(f"pilot input: {', '.join(jp.assumed)} not in the log: ArduSub's defaults assumed ("
                     + ", ".join(f"{n} = {ARDUSUB_DEFAULTS[n]:g}" for n in jp.assumed) + ")")
    has_rc = rc is not None and rc.t.size > 0
    fallback, span_notes = override_fallback(t, rc.t if has_rc else None, jp.override_time)
    notes += span_notes
    default_src = "JS_GAIN_DEFAULT from the log" if "JS_GAIN_DEFAULT" not in jp.assumed else \
        "ArduSub's default JS_GAIN_DEFAULT"
    if not has_rc:
        notes.append(f"pilot input: no RC_CHANNELS to calibrate the pilot gain on: gain {jp.default_gain:g} ASSUMED "
                     f"({default_src}; the pilot may have changed it with buttons); rcin_1, rcin_2 (pitch, roll) "
                     f"1500 us ASSUMED (ArduSub's 1500 + trim, the trims zero as at boot); rcin_7, rcin_8 not in the "
                     f"log (nan)")
        gain_at = np.full(t.size, jp.default_gain)
        times, fields = _joystick_only(t, rc_override(*axes.T, gain_at, jp.throttle_gain), fallback)
        notes += _reported_gain_notes(t, gain_at, reported_gain)
        return JoystickRC(Stream("PILOT_RC", times, fields, mc.time_source), notes)
    live_rc = ~_inside(rc.t, fallback)
    fit = fit_gains(t, axes, rc, jp, live_rc)
    notes += _fit_notes(fit, rc.t, t[0], jp.default_gain, default_src)
    if not fit.stretches:
        notes.append(f"pilot input: no RC_CHANNELS sample the joystick explains: gain {jp.default_gain:g} ASSUMED "
                     f"({default_src})")
    spans = [(rc.t[k - 1] if k > 0 else -np.inf, rc.t[k + 1] if k + 1 < rc.t.size else np.inf) for k in fit.bad]
    fallback = _merge(fallback + spans)
    gain_at = fit.gain_at(t, jp.default_gain)
    pwm = rc_override(*axes.T, gain_at, jp.throttle_gain)
    times, fields, note = _merged_fields(t, pwm, rc, fallback)
    notes.append(note)
    ok = live_rc.copy()
    ok[list(fit.bad)] = False
    rc_joy = _joystick_channels(rc)
    notes += _agreement_notes(t, pwm, rc.t[ok], rc_joy[ok]) + _reported_gain_notes(t, gain_at, reported_gain)
    return JoystickRC(Stream("PILOT_RC", times, fields, mc.time_source), notes, fit.stretches, fit.changes)
