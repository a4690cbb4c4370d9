"""Whether what the fit runs found holds on the holdout runs fitted on their own: the parts of a diagnosis set side
by side.

The holdout confirms an effect by replaying it with the fit runs' parameters. That says the effect helps there; it
does not say the holdout runs would have given it the same parameters. Fitted on the holdout runs apart, a named
effect whose parameters come out near the fit runs' is a property of the vehicle (a drag centre found on an outbound
transect and again on the way back); one whose parameters move is fitted to each part's conditions. A world-fixed
effect (a steady current) that the parts fit with different directions is not one current at all
(:mod:`udrobot_ctrl.gap.heading`).

The measure is the share of the holdout's own fit's equation-error likelihood gain (against the nominal model) that
the fit runs' parameters reach there, both frozen (:func:`agreement`): it is scale-free, and unlike a likelihood-ratio
test of the two fits against each other it does not reject equal parameters on long runs, whose equation error holds
model error as well as noise.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from udrobot_ctrl.gap.attribute import Attributor, Fit, holdout_lr, refit

#: the share of the holdout's own fit's likelihood gain that the fit runs' parameters must reach there for the two
#: parts to agree. Assumed: parameters that do at least half of what the holdout's own do there are the same up to
#: what the parts' conditions (depth, speed, heading) change
SAME_SHARE = 0.5


@dataclass(frozen=True)
class Agreement:
    """How far the fit runs' parameters reach on the holdout runs against the holdout's own fit.

    Attributes
    ----------
    holdout_lr : float
        Holdout equation-error likelihood ratio of the holdout's own fit against the nominal model (N_eff of the
        holdout runs).
    share : float
        The fit runs' parameters' likelihood gain on the holdout (frozen) as a share of the holdout's own fit's;
        negative when they make the holdout worse than the nominal model; nan when the own fit gains nothing.
    """

    holdout_lr: float
    share: float

    @property
    def agrees(self) -> bool:
        """Whether the fit runs' parameters reach at least :data:`SAME_SHARE` of the holdout's own gain."""
        return self.share >= SAME_SHARE

    @property
    def excited(self) -> bool:
        """Whether the holdout's own fit gains anything over the nominal model (else the share is undefined: the
        holdout runs do not excite the terms, e.g. a wall effect on runs far from the wall)."""
        return math.isfinite(self.share)

    def words(self) -> str:
        """The share in words."""
        if not self.excited:
            return (f"the holdout runs' own fit gains nothing over the nominal model there (likelihood ratio "
                    f"{self.holdout_lr:.1f}): they do not excite it")
        return f"the fit runs' parameters do {100 * self.share:.0f}% of what the holdout runs' own do there"


def agreement(att_h: Attributor, fitted: Fit, own: Fit) -> Agreement:
    """The :class:`Agreement` of ``fitted`` (a fit on the fit runs) and ``own`` (the same terms fitted on the holdout
    stack ``att_h``, whose ``n_eff`` is set)."""
    none = att_h.fit([])
    lr = holdout_lr(att_h, none, own)
    return Agreement(lr, holdout_lr(att_h, none, fitted) / lr if lr > 0 else math.nan)


@dataclass(frozen=True)
class NamedParts:
    """The significant effects fitted jointly on the holdout runs apart (the report's ``parts``).

    Attributes
    ----------
    members : tuple of str
        The significant effects.
    holdout_params : dict
        Name -> the holdout runs' own joint fit's parameters (the same units as ``params``).
    holdout_lr, share : float
        See :class:`Agreement`.
    agrees : bool
        ``share`` >= :data:`SAME_SHARE`.
    text : str
        The comparison in words.
    """

    members: tuple
    holdout_params: dict
    holdout_lr: float
    share: float
    agrees: bool
    text: str

    def to_json(self) -> dict:
        return asdict(self)


def named_parts(att_h: Attributor, fitted: Fit, members) -> NamedParts | None:
    """The ``members`` of ``fitted`` (the joint fit of the significant effects on the fit runs) fitted again on the
    holdout stack ``att_h`` alone, each shape searched from the fit runs' (:func:`udrobot_ctrl.gap.attribute.refit`),
    and how far the fit runs' parameters reach there (:func:`agreement`); None without members."""
    members = tuple(members)
    if not members:
        return None
    own = refit(att_h, members, shapes={m: fitted.shapes[m] for m in members})
    ag = agreement(att_h, fitted, own)
    text = (f"fitted on the holdout runs apart, {ag.words()}" + ("" if not ag.excited else
            ": the same effect on both parts" if ag.agrees else
            ": the parts fit it differently, so its parameters follow each part's conditions"))
    return NamedParts(members, {m: own.params[m] for m in members}, ag.holdout_lr, ag.share, ag.agrees, text)
