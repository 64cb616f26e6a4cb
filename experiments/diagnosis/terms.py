"""The terms of the diagnosis: the regressor columns of one candidate cause.

A :class:`Term` names its finding and the effect template of :mod:`clm_sim.effects` whose
regressors it contributes; the constructors below build the terms whose nonlinear parameter
(a period, a Stribeck velocity, a pre-sliding length, a polynomial order) a search of
:mod:`experiments.diagnosis.parameter_search` has chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.effects.base import Effect
from clm_sim.effects.friction import Presliding, Stribeck
from clm_sim.effects.position import CableSlab, Cogging, ForceRipple
from experiments.diagnosis.residual import Residual

MAX_SMOOTH_ORDER = 9


@dataclass(frozen=True)
class Term:
    """One candidate cause: finding name, effect template (None: parameter mismatch), the
    regressor keys it uses from the template.

    ``replaces_coulomb``: the columns are the template's minus ``sign(v)``, i.e. the candidate
    says that this much of the model's Coulomb friction is really the template's effect (the
    coefficient moves from ``coulomb`` to the effect; pre-sliding friction)."""

    effect: str
    template: Effect | None
    keys: tuple[str, ...]
    replaces_coulomb: bool = False

    def regressors(self, y, v, a, u) -> dict[str, np.ndarray]:
        """Full-rate regressor columns (N per unit coefficient)."""
        if self.template is None:
            cols = {"mass": a, "viscous": v, "coulomb": np.sign(v), "stiffness": y}
        else:
            cols = self.template.regressors(y, v, u)
        if self.replaces_coulomb:
            cols = {k: c - np.sign(v) for k, c in cols.items()}
        return {k: cols[k] for k in self.keys}

    def columns(self, res: Residual) -> np.ndarray:
        return res.columns(self.regressors(res.y, res.v, res.a, res.u))

    def effect_from(self, coef: dict[str, float]) -> Effect | None:
        return None if self.template is None else self.template.from_coefficients(coef)


def periodic_term(kind: str, period: float) -> Term:
    if kind == "cogging":
        return Term(kind, Cogging(amplitude=0.0, period=period), ("cogging_sin", "cogging_cos"))
    return Term(kind, ForceRipple(amplitude=0.0, period=period), ("ripple_sin", "ripple_cos"))


def stribeck_term(velocity: float) -> Term:
    return Term("stribeck", Stribeck(peak=0.0, velocity=velocity, exponent=2.0), ("stribeck",))


@dataclass(frozen=True)
class SupportTerm(Term):
    """``not_supported``: a free scale ``c`` on the force of an effect the *model* holds. The
    data supports ``1 + c`` of it; the finding is named when ``1 + c < 0.5`` (the model's effect
    is mostly not there)."""

    def regressors(self, y, v, a, u):
        return {"support": self.template.force(y, v, u)}

    def effect_from(self, coef):
        return None


def presliding_term(length: float) -> Term:
    """Dahl friction of pre-sliding length ``length`` (m) in place of Coulomb friction."""
    return Term("presliding", Presliding.with_length(0.0, length), ("presliding",),
                replaces_coulomb=True)


@dataclass(frozen=True)
class SmoothTerm(Term):
    """``cable_slab``: a smooth force in position, Legendre polynomials ``P_0..P_order`` of
    ``(y - center)/half`` (m); returned as a :class:`CableSlab` power series about ``center``.
    To carry the name it must explain more than its constant and linear part (an offset and a
    stiffness), by the significance rule (:func:`forward_select`)."""

    center: float = 0.0
    half: float = 1.0
    order: int = 2

    def regressors(self, y, v, a, u):
        xi = (np.asarray(y, dtype=float) - self.center) / self.half
        eye = np.eye(self.order + 1)
        return {k: np.polynomial.legendre.legval(xi, eye[i]) for i, k in enumerate(self.keys)}

    def effect_from(self, coef):
        leg = np.array([coef[k] for k in self.keys])
        power = np.polynomial.legendre.leg2poly(leg)
        scaled = [float(c) / self.half**i for i, c in enumerate(power)]
        return CableSlab(coefficients=tuple(scaled), center=self.center)


def smooth_term(res: Residual, order: int) -> SmoothTerm:
    y = res.y[res.idx]
    lo, hi = float(np.min(y)), float(np.max(y))
    return SmoothTerm("cable_slab", None, tuple(f"cable_P{i}" for i in range(order + 1)),
                      center=0.5 * (lo + hi), half=max(0.5 * (hi - lo), 1e-12), order=order)
