"""A confirmed effect that may stand in for the untested part of a partly identified effect (report.stand_ins).

The rule compares fit-run BICs and holdout likelihood ratios of sets of effects; here an attributor of tables stands
in for the equation-error fits, so that each branch of the rule is checked on the numbers a diagnosis printed.
"""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap import report
from udrobot_ctrl.gap.attribute import BIC_STRONG, HOLDOUT_CHI2, Fit
from udrobot_ctrl.gap.identifiability import StandIn
from udrobot_ctrl.gap.report import FreedPart, stand_ins

CG, DB, AM = "cg_cb_offset", "thruster_deadband", "added_mass_error"


class _Tables:
    """Fits of sets of effects (shapes ``()``), their BIC read from ``bic`` (frozenset of names -> BIC)."""

    def __init__(self, bic):
        self.table = bic

    @staticmethod
    def fit(names):
        return Fit(tuple(names), dict.fromkeys(names, ()), {}, None, 0, 0.0)

    def best_shape(self, name, fixed, refine=False):
        return self.fit([n for n, _ in fixed] + [name])

    def bic(self, fit):
        return self.table[frozenset(fit.names)]


def _stand_ins(monkeypatch, bic, lr):
    """``stand_ins`` of the confirmed set (cg_cb_offset, thruster_deadband) against the added-mass error with its
    untested part freed; ``lr``: frozenset of the larger set -> holdout likelihood ratio of the addition."""
    monkeypatch.setattr(report, "holdout_lr", lambda att_h, base, with_: lr[frozenset(with_.names)])
    att = _Tables(bic)
    elim = SimpleNamespace(kept=(CG, DB), combination=SimpleNamespace(fit=att.fit((CG, DB))))
    part = FreedPart(AM, att, att, None)
    return stand_ins([part], elim, att, SimpleNamespace(effects={}), fx.catalogue(), "80% of the gap left")


# the numbers of a stock diagnosis: a dead band confirmed beside a CG-CB offset, on runs whose truth is an added-mass
# error (surge, heave, yaw) and a moved ballast
BIC = {frozenset((CG, DB)): -2456.1, frozenset((CG, AM)): -2659.6, frozenset((CG, AM, DB)): -2648.6,
       frozenset((DB, AM)): -2241.7, frozenset((DB, AM, CG)): -2648.6}
LR = {frozenset((CG, AM, DB)): 7.4}


def test_a_member_that_adds_nothing_beside_the_freed_effect_alone_may_stand_in_for_it(monkeypatch):
    """Replaced by the added-mass error with its surge and sway parts fitted, the dead band's set fits better (BIC
    -204) and the dead band added back fails the forward-selection test (dBIC +11): it may stand in for that part,
    with no look-alike beside. The CG-CB offset is not one: replaced, the BIC rises."""
    found = _stand_ins(monkeypatch, BIC, LR)
    assert set(found) == {DB}
    st = found[DB]
    assert isinstance(st, StandIn) and st.on == AM and st.partner == "" and st.partner_support is None
    assert st.delta_bic == pytest.approx(-203.5) and st.member_delta_bic == pytest.approx(11.0)


def test_a_member_still_supported_beside_the_freed_effect_is_not_a_stand_in(monkeypatch):
    """The same, but the dead band added back lowers the BIC by more than BIC_STRONG with a holdout ratio above
    HOLDOUT_CHI2: it explains something the freed effect does not, and stays."""
    bic = dict(BIC)
    bic[frozenset((CG, AM, DB))] = BIC[frozenset((CG, AM))] - 2 * BIC_STRONG
    assert _stand_ins(monkeypatch, bic, {frozenset((CG, AM, DB)): 3 * HOLDOUT_CHI2}) == {}
    # a lower BIC back but no holdout support: the fit runs alone do not keep it
    assert set(_stand_ins(monkeypatch, bic, {frozenset((CG, AM, DB)): 0.5 * HOLDOUT_CHI2})) == {DB}


def test_a_freed_effect_that_fits_worse_than_the_member_does_not_replace_it(monkeypatch):
    bic = dict(BIC)
    bic[frozenset((CG, AM))] = BIC[frozenset((CG, DB))] + 1.0
    assert _stand_ins(monkeypatch, bic, LR) == {}
