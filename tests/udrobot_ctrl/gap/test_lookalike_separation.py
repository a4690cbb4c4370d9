"""A look-alike sets a confirmed effect aside only when the holdout cannot tell the two apart (issue 41).

The swap of a member for its look-alike is judged by the same materiality rule as a dropped member
(:attr:`udrobot_ctrl.gap.confirm.MemberTest.passed_replay`); the report's reason gives both holdout scores.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from udrobot_ctrl.gap import report
from udrobot_ctrl.gap.confirm import REPLAY_LARGE, REPLAY_MATERIAL, REPLAY_P, Separation
from udrobot_ctrl.gap.identifiability import EffectCheck, Identifiability, ParameterCheck


def _sep(rise, p=0.5, worse=0.5, member="cg_cb_offset", rival="added_mass_error"):
    return Separation(member, rival, 1.0, 1.0 + rise, rise, p, worse)


def test_separation_follows_the_materiality_rule_of_the_backward_check():
    # below materiality: equal on the holdout, however consistent
    assert not _sep(0.5 * REPLAY_MATERIAL, p=1e-6, worse=1.0).separated
    # material but small: needs a consistent rise over the windows
    mid = 0.5 * (REPLAY_MATERIAL + REPLAY_LARGE)
    assert not _sep(mid, p=2 * REPLAY_P, worse=0.9).separated
    assert not _sep(mid, p=0.5 * REPLAY_P, worse=0.5).separated  # half the windows: a coin flip
    assert _sep(mid, p=0.5 * REPLAY_P, worse=0.6).separated
    # large: material however it is spread
    assert _sep(2 * REPLAY_LARGE, p=0.9, worse=0.3).separated
    # the rival better on the holdout: never separated in favour of the member
    assert not _sep(-REPLAY_LARGE, p=1e-6, worse=0.0).separated


def _ident():
    ok = ParameterCheck("a", 1.0, 0.0, True, (), (0, 0, 0, 0.5, 0.5, 0))
    effects = {n: EffectCheck(n, [ok]) for n in ("cg_cb_offset", "added_mass_error", "thruster_lag")}
    return Identifiability(effects, np.array([0, 0, 1, 1, 1, 1], bool), np.array([1, 1, 1, 0, 0, 0], bool))


def test_reason_of_an_unseparated_lookalike_gives_both_holdout_scores():
    sp = _sep(0.005, p=0.4, worse=0.45)
    ident = _ident().with_ambiguous({"cg_cb_offset": ("added_mass_error",)}).with_separations(
        {"cg_cb_offset": (sp,)})
    for name in ("cg_cb_offset", "added_mass_error"):  # the relation is symmetric, and so is the evidence
        why = ident.reason(name)
        assert "cannot say which acts" in why
        assert "not separated on the holdout" in why and ": equal" in why
        assert f"{sp.gap_member:.4g}" in why and f"{sp.gap_rival:.4g}" in why


def test_a_rival_that_scores_better_is_said_so():
    assert _sep(-2 * REPLAY_LARGE, p=1.0, worse=0.1).verdict == "rival better"
    assert _sep(-0.5 * REPLAY_MATERIAL, p=1.0, worse=0.4).verdict == "equal"
    assert _sep(2 * REPLAY_LARGE, p=1e-4, worse=0.9).verdict == "separated"
    ident = _ident().with_ambiguous({"cg_cb_offset": ("added_mass_error",)}).with_separations(
        {"cg_cb_offset": (_sep(-2 * REPLAY_LARGE, p=1.0, worse=0.1),)})
    assert "better with added_mass_error" in ident.reason("cg_cb_offset")


def test_holdout_separated_keeps_only_the_lookalikes_the_holdout_cannot_tell_apart(monkeypatch):
    calls = {}

    def fake_separations(att, members, pairs, full, before, replayer, window_s, preps, shapes=None):
        calls["pairs"] = list(pairs)
        return [_sep(0.3, p=1e-3, worse=0.9, rival="added_mass_error"),  # separated
                _sep(0.001, p=0.6, worse=0.4, rival="thruster_lag")]  # equal

    monkeypatch.setattr(report, "separations", fake_separations)
    inp = SimpleNamespace(window_s=8.0, holdout=[], catalogue={}, fit=[], p=None)
    stacks = SimpleNamespace(fit=None, actuation=None)
    where = SimpleNamespace(before=SimpleNamespace(value=1.0, scored=["p", "q"]))
    elim = SimpleNamespace(kept=("cg_cb_offset",), after=None, combination=SimpleNamespace(fit=SimpleNamespace(
        shapes={})))
    amb = {"cg_cb_offset": ["added_mass_error", "thruster_lag", "tether_drag"]}
    lines = []
    out, seps = report._holdout_separated(inp, stacks, where, elim, amb, hidden={"tether_drag"}, prior={},
                                          log=lines.append)
    # the unidentifiable look-alike (tether without a DVL) is not swapped in: its fit hinges on what is not measured
    assert calls["pairs"] == [("cg_cb_offset", "added_mass_error"), ("cg_cb_offset", "thruster_lag")]
    assert out == {"cg_cb_offset": ["thruster_lag", "tether_drag"]}
    assert [s.rival for s in seps["cg_cb_offset"]] == ["added_mass_error", "thruster_lag"]
    assert any("the holdout separates them" in ln for ln in lines)
    # every look-alike separated: nothing left to set the member aside
    monkeypatch.setattr(report, "separations", lambda *a, **k: [_sep(0.3, p=1e-3, worse=0.9)])
    out, _ = report._holdout_separated(inp, stacks, where, elim, {"cg_cb_offset": ["added_mass_error"]},
                                       hidden=set(), prior={}, log=None)
    assert out == {}
