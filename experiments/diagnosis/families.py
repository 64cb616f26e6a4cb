"""The candidate families of the diagnosis: one object per kind of cause, in one registry.

A family knows everything the diagnosis needs about its cause: its name and the effect class of
:mod:`clm_sim.effects` it extends the model with, how many parameters an explanation of its kind
has (the parsimony rule counts them), how its nonlinear parameters are searched on the current
residual (:meth:`Family.propose`), which physical and structural checks a fitted candidate must
pass to carry its name (:meth:`Family.admissible`), whether it may be named more than once, whether
its force is tied to the encoder origin (``periodic``), and how a fitted term becomes a
:class:`~experiments.diagnosis.finding.Finding` and a correction of the model
(:meth:`Family.finding`). The selection loop (:mod:`experiments.diagnosis.search`), the joint fit
(:mod:`experiments.diagnosis.extend`) and the origin registration
(:mod:`experiments.diagnosis.origin`) read only this registry.

The columns of a candidate are a :class:`~experiments.diagnosis.terms.Term`, its nonlinear
parameters are searched in :mod:`experiments.diagnosis.parameter_search`, and it is proposed and
checked in a :class:`~experiments.diagnosis.context.Context`.

Identifiability: during motion an asymmetric Coulomb friction is a symmetric one plus a constant
force ``(c_pos - c_neg)/2``, and the diagnosis leaves standstill out (the direction of motion is
unknown there). A constant force is therefore reported as ``force_offset``;
``friction_asymmetry`` is the direction-odd viscous part (its ``|v|`` signature), with the
Coulomb part reported as 0.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from clm_sim.effects.base import Effect
from clm_sim.effects.friction import FrictionAsymmetry, Presliding, Stribeck
from clm_sim.effects.position import CableSlab, Cogging, ForceOffset, ForceRipple
from clm_sim.plant import THETA_NAMES
from experiments.diagnosis.context import Candidate, Context, Rejection
from experiments.diagnosis.finding import Estimate, Finding
from experiments.diagnosis.fitting import (coefficient_cov, coefficient_std, disagrees, fit_cv,
                                           reportable, significance, solve)
from experiments.diagnosis.parameter_search import (approx_periodic, best_smooth_cv,
                                                    search_period, search_presliding,
                                                    search_smooth, search_stribeck)
from experiments.diagnosis.residual import Residual
from experiments.diagnosis.terms import (SupportTerm, Term, periodic_term, presliding_term,
                                         smooth_term, stribeck_term)


# ---------------------------------------------------------------- families
class Family:
    """One kind of cause. Subclasses set ``name`` and override what differs.

    ``effect_type``: the :class:`Effect` class it extends the model with (None: it corrects the
    model instead). ``repeatable``: may be named more than once (other periods, other pre-sliding
    lengths). ``periodic``: a position-periodic force, tied to the encoder origin
    (:mod:`experiments.diagnosis.origin`). ``searched``: nonlinear parameters found by search,
    counted by :meth:`n_params` beside the linear coefficients. ``units``: SI unit per reported
    parameter.
    """

    name: ClassVar[str] = ""
    effect_type: ClassVar[type[Effect] | None] = None
    repeatable: ClassVar[bool] = False
    periodic: ClassVar[bool] = False
    searched: ClassVar[tuple[str, ...]] = ()
    units: ClassVar[dict[str, str]] = {}
    # The linear coefficient behind a reported parameter (its standard error is reported).
    std_of: ClassVar[dict[str, str]] = {}

    def n_params(self, term: Term) -> int:
        """Parameters of an explanation by ``term``: its coefficients and searched parameters."""
        return len(term.keys) + len(self.searched)

    def available(self, ctx: Context) -> bool:
        return self.repeatable or not ctx.used(self.name)

    def propose(self, ctx: Context) -> list[Candidate]:
        """Candidates of this family on the current residual (nonlinear parameters searched)."""
        raise NotImplementedError

    def refine(self, ctx: Context, cand: Candidate) -> Candidate:
        """The candidate with its parameters searched exactly (ranking used cheap columns)."""
        return cand

    def admissible(self, ctx: Context, term: Term, cols: np.ndarray) -> Rejection | None:
        """None if the fitted candidate may carry the family's name, else why it may not (a
        physical bound, or a check of the family's law the data fails)."""
        return None

    def splits(self, res: Residual) -> list[tuple[np.ndarray, str]]:
        """Pairs of regimes of the record in which the family's law says the same coefficients
        hold: per pair, the full-rate mask of one regime and what the law is."""
        return []

    def law_holds(self, ctx: Context, term: Term, cols: np.ndarray) -> Rejection | None:
        """The family's law checked on the data: the term fitted with separate coefficients in
        the two regimes of each of :meth:`splits` (jointly with the accepted terms); the law
        fails where the two sets disagree by the rule of :func:`disagrees` (their force differs
        by more than half the jointly fitted force, beyond the noise of the split fit). A force
        that differs so between the regimes has another cause: that part of the residual stays
        unexplained."""
        res = ctx.res
        full = term.regressors(res.y, res.v, res.a, res.u)
        n, k = ctx.x_s.shape[1], cols.shape[1]
        a, b = slice(n, n + k), slice(n + k, n + 2 * k)
        joint = ctx.coef_with(cols)[n:]
        for mask, law in self.splits(res):
            split = {**{f"{key}+": c * mask for key, c in full.items()},
                     **{f"{key}-": c * ~mask for key, c in full.items()}}
            split_cols = res.columns(split)
            x = np.column_stack([ctx.x_s, split_cols])
            coef = solve(x.T @ x, x.T @ res.z)
            cov = coefficient_cov(res, x, coef)
            delta = coef[a] - coef[b]
            cov_d = cov[a, a] + cov[b, b] - cov[a, b] - cov[b, a]
            if disagrees(res, delta, cov_d, cols, joint):
                return Rejection(f"{law}; fitted apart they differ", split_cols)
        return None

    def finding(self, res: Residual, term: Term, coef: dict[str, float], sd: dict[str, float],
                cols: np.ndarray, stats: dict, correction: dict) -> Finding:
        """The finding of a term fitted jointly with the others (``coef``, standard errors
        ``sd`` by regressor key); adds the model's correction to ``correction``."""
        effect = term.effect_from(coef)
        params = {}
        for k, v in effect.parameters().items():
            if isinstance(v, (int, float)):
                std = sd.get(self.std_of.get(k, ""))
                params[k] = Estimate(float(v), None if std is None else float(std),
                                     self.units.get(k, ""))
        return Finding(self.name, params, effect_object=effect, n_params=self.n_params(term),
                       **stats)


class FixedFamily(Family):
    """A family without nonlinear parameters: its columns are fixed."""

    template: ClassVar[Effect | None] = None
    keys: ClassVar[tuple[str, ...]] = ()

    def term(self) -> Term:
        return Term(self.name, self.template, self.keys)

    def propose(self, ctx):
        cache = ctx.res.cache.setdefault("fixed", {})
        if self.name not in cache:
            cache[self.name] = self.term().columns(ctx.res)
        cols = cache[self.name]
        return [Candidate(self.term(), cols, cols)]


class ParameterMismatch(FixedFamily):
    """Corrections of the model's mass, viscous and Coulomb friction and stiffness (the LIP
    columns). Named when at least one correction is reportable (:func:`reportable`)."""

    name = "parameter_mismatch"
    keys = THETA_NAMES

    units = {"mass": "kg", "viscous": "N·s/m", "coulomb": "N", "stiffness": "N/m"}

    def admissible(self, ctx, term, cols):
        x = np.column_stack([ctx.x_s, cols])
        coef = ctx.coef_with(cols)
        std = coefficient_std(ctx.res, x, coef)
        n = ctx.x_s.shape[1]
        if any(reportable(ctx.res, coef[n + j], std[n + j], cols[:, j])
               for j in range(cols.shape[1])):
            return None
        return Rejection("no correction is both significant and practically relevant")

    def finding(self, res, term, coef, sd, cols, stats, correction):
        params = {}
        for j, name in enumerate(term.keys):
            delta = float(coef[name])
            correction[name] = correction.get(name, 0.0) + delta
            if reportable(res, delta, sd[name], cols[:, j]):
                model = float(getattr(res.plant, name))
                params[name] = Estimate(model + delta, float(sd[name]), self.units[name], model)
        return Finding(self.name, params, n_params=self.n_params(term), **stats)


class ForceOffsetFamily(FixedFamily):
    name = "force_offset"
    effect_type = ForceOffset
    template = ForceOffset()
    keys = ("offset",)
    units = {"force": "N"}
    std_of = {"force": "offset"}


class FrictionAsymmetryFamily(FixedFamily):
    name = "friction_asymmetry"
    effect_type = FrictionAsymmetry
    template = FrictionAsymmetry()
    keys = ("asym_viscous",)
    units = {"coulomb_pos": "N", "coulomb_neg": "N", "viscous_pos": "N·s/m",
             "viscous_neg": "N·s/m"}
    std_of = {"viscous_pos": "asym_viscous", "viscous_neg": "asym_viscous"}


class PeriodicFamily(Family):
    """A position-periodic force (period searched). Named only where it explains more than a
    smooth force in its place (:func:`beats_smooth`) and is a force of the position: the
    same while the speed rises and while it falls (:meth:`splits`)."""

    repeatable = True
    periodic = True
    searched = ("period",)

    def propose(self, ctx):
        avoid = [t.template.period for t in ctx.used(self.name)]
        period = search_period(ctx.res, self.name, ctx.x_s, ctx.e, avoid)
        if period is None:
            return []
        return [Candidate(periodic_term(self.name, period),
                          approx_periodic(ctx.res, self.name, 2 * math.pi / period))]

    def splits(self, res):
        return position_law(res)

    def admissible(self, ctx, term, cols):
        if not beats_smooth(ctx, cols):
            return Rejection("a smooth force in position explains it as well")
        return self.law_holds(ctx, term, cols)

    def finding(self, res, term, coef, sd, cols, stats, correction):
        f = super().finding(res, term, coef, sd, cols, stats, correction)
        # The amplitude's standard error: that of the sine and cosine coefficients (about equal).
        std = float(np.sqrt(np.mean([sd[k] ** 2 for k in term.keys])))
        params = dict(f.parameters)
        params["amplitude"] = Estimate(params["amplitude"].value, std, self.units["amplitude"])
        return Finding(self.name, params, effect_object=f.effect_object, n_params=f.n_params,
                       **stats)


class CoggingFamily(PeriodicFamily):
    name = "cogging"
    effect_type = Cogging
    units = {"amplitude": "N", "period": "m", "phase": "rad"}


class ForceRippleFamily(PeriodicFamily):
    name = "force_ripple"
    effect_type = ForceRipple
    units = {"amplitude": "", "period": "m", "phase": "rad"}


class StribeckFamily(Family):
    """A low-speed friction curve on top of Coulomb (velocity searched, exponent 2).

    A curve of the velocity alone is the same force while the speed rises (after a reversal or a
    start) and while it falls (before a stop): the law checked on the data (:meth:`splits`). A
    force that appears only after reversals has memory (pre-sliding, bristle damping) and is no
    Stribeck curve. A peak (> 0) is named as such; a dip (< 0) only where it beats pre-sliding
    friction in its place (:func:`dip_beats_presliding`)."""

    name = "stribeck"
    effect_type = Stribeck
    searched = ("velocity",)
    units = {"peak": "N", "velocity": "m/s", "exponent": ""}
    std_of = {"peak": "stribeck"}

    def propose(self, ctx):
        vel = search_stribeck(ctx.res, ctx.x_s, exact=False)
        term = stribeck_term(vel)
        return [Candidate(term, term.columns(ctx.res))]

    def refine(self, ctx, cand):
        term = stribeck_term(search_stribeck(ctx.res, ctx.x_s, exact=True))
        return Candidate(term, cand.approx, term.columns(ctx.res))

    def splits(self, res):
        return [(speed_rising(res), "a friction curve of the velocity is the same force while "
                 "the speed rises and while it falls")]

    def admissible(self, ctx, term, cols):
        peak = float(ctx.coef_with(cols)[-1])
        if peak < 0 and not dip_beats_presliding(ctx, cols, peak):
            return Rejection("a friction dip that pre-sliding friction explains as well")
        return self.law_holds(ctx, term, cols)


class PreslidingFamily(Family):
    """Dahl pre-sliding friction taking over part of the model's Coulomb friction (length
    searched). Positive, and all elements together at most the model's Coulomb friction."""

    name = "presliding"
    effect_type = Presliding
    repeatable = True
    searched = ("length",)
    units = {"sliding": "N", "stiffness": "N/m", "length": "m", "coulomb_in_model": "N"}
    std_of = {"sliding": "presliding"}

    def propose(self, ctx):
        avoid = [t.template.length for t in ctx.used(self.name)]
        length = search_presliding(ctx.res, ctx.x_s, avoid)
        if length is None:
            return []
        term = presliding_term(length)
        cols = term.columns(ctx.res)
        return [Candidate(term, cols, cols)]

    def admissible(self, ctx, term, cols):
        coef = ctx.coef_with(cols)
        mask = ctx.columns_of(self.name)
        n = ctx.x_s.shape[1]
        # It takes friction over from the model's Coulomb friction: at most all of it (5 %
        # slack for its uncertainty), shared among the accepted elements.
        moved = float(coef[n:].sum() + coef[:n][mask].sum())
        if coef[-1] <= 0:
            # Friction above the Coulomb level after a reversal (bristle damping, a lag): Dahl
            # friction can only lie below it there.
            return Rejection("negative pre-sliding friction: friction above the Coulomb level "
                             "after a reversal", cols)
        if moved > 1.05 * ctx.res.plant.coulomb:
            return Rejection("more pre-sliding friction than the model's Coulomb friction", cols)
        return None

    def finding(self, res, term, coef, sd, cols, stats, correction):
        f = super().finding(res, term, coef, sd, cols, stats, correction)
        effect = f.effect_object
        params = dict(f.parameters)
        params["length"] = Estimate(float(effect.length), None, "m")
        shift = sum(float(v) for v in coef.values())  # this much Coulomb friction is pre-sliding
        correction["coulomb"] = correction.get("coulomb", 0.0) - shift
        params["coulomb_in_model"] = Estimate(float(res.plant.coulomb), None, "N")
        return Finding(self.name, params, effect_object=effect, n_params=f.n_params, **stats)


class CableSlabFamily(Family):
    """A smooth force in position (cable carrier, slab attraction): a Legendre polynomial whose
    order is chosen on held-out data. To carry the name it must explain more than its constant
    and linear part (an offset and a stiffness), by the significance rule, and be a force of
    the position alone: the same while the speed rises and while it falls (:meth:`splits`)."""

    name = "cable_slab"
    effect_type = CableSlab
    units = {"center": "m", "order": "", "force_min": "N", "force_max": "N"}

    def propose(self, ctx):
        term, cols, _ = search_smooth(ctx.res, ctx.x_s)
        return [Candidate(term, cols, cols)]

    def splits(self, res):
        return position_law(res)

    def admissible(self, ctx, term, cols):
        res = ctx.res
        x_lin = np.column_stack([ctx.x_s, cols[:, :2]])
        fit_lin = fit_cv(x_lin, res.z, res.fold, res.settings.folds)
        if not significance(res, x_lin, fit_lin, cols[:, 2:], ctx.base).passes(res):
            return Rejection("no more than an offset and a stiffness")
        return self.law_holds(ctx, term, cols)

    def finding(self, res, term, coef, sd, cols, stats, correction):
        effect = term.effect_from(coef)
        f = effect.force(res.y[res.idx], 0.0, 0.0)
        params = {"center": Estimate(float(effect.center), None, "m"),
                  "order": Estimate(float(term.order)),
                  "force_min": Estimate(float(np.min(f)), None, "N"),
                  "force_max": Estimate(float(np.max(f)), None, "N")}
        return Finding(self.name, params, effect_object=effect, n_params=self.n_params(term),
                       **stats)


class NotSupported(Family):
    """``not_supported``: a free scale ``c`` on the force of an effect the *model* holds; named
    when the data supports less than half of it (``1 + c < 0.5``). One candidate per model
    effect, each named at most once."""

    name = "not_supported"
    repeatable = True

    units = {"support": ""}

    def propose(self, ctx):
        out = []
        for effect in ctx.res.plant.effects:
            if not any(t.template is effect for t in ctx.used(self.name)):
                term = SupportTerm(self.name, effect, ("support",))
                cols = term.columns(ctx.res)
                if np.any(cols) and not _in_fixed_span(ctx, cols):
                    out.append(Candidate(term, cols, cols))
        return out

    def admissible(self, ctx, term, cols):
        if ctx.coef_with(cols)[-1] < -0.5:
            return None
        return Rejection("the data holds more than half of the model's effect")

    def finding(self, res, term, coef, sd, cols, stats, correction):
        correction.setdefault("drop", []).append(term.template)
        params = {"support": Estimate(1.0 + float(coef["support"]), float(sd["support"]))}
        return Finding(self.name, params, model_effect=term.template, n_params=1, **stats)


def _in_fixed_span(ctx: Context, cols: np.ndarray) -> bool:
    """Whether a model effect's force lies in the span of a fixed family's columns (the model's
    constant force is a ``force_offset`` column): that family corrects it, keeping the part the
    data holds, where ``not_supported`` would drop all of it for the same fit."""
    for family in REGISTRY.values():
        if isinstance(family, FixedFamily):
            x = family.propose(ctx)[0].approx
            coef = np.linalg.lstsq(x, cols, rcond=None)[0]
            if np.linalg.norm(cols - x @ coef) <= 1e-9 * np.linalg.norm(cols):
                return True
    return False


# The registry, in the order candidates are ranked (ties keep it).
REGISTRY: dict[str, Family] = {f.name: f for f in (
    NotSupported(), ParameterMismatch(), PreslidingFamily(), CableSlabFamily(), CoggingFamily(),
    ForceRippleFamily(), StribeckFamily(), FrictionAsymmetryFamily(), ForceOffsetFamily())}


def periodic_effect_types() -> tuple[type[Effect], ...]:
    """Effect classes whose force is tied to the encoder origin."""
    return tuple(f.effect_type for f in REGISTRY.values() if f.periodic)


# ---------------------------------------------------------------- checks shared by families
def speed_rising(res: Residual) -> np.ndarray:
    """Full-rate mask of the samples where the speed rises (after a reversal or a start)."""
    if "speed_rising" not in res.cache:
        acc = res.features.regression_filter(res.a, res.ts)
        res.cache["speed_rising"] = res.v_filtered * acc > 0
    return res.cache["speed_rising"]


def position_law(res: Residual) -> list[tuple[np.ndarray, str]]:
    """The regimes a force of the position must not tell apart: whether the speed rises or
    falls. (The direction of motion is not used: EMPS's 2.5 mm periodic force differs between
    the directions by more than half of itself (a friction that depends on the position would
    do that; not checked further), and would be left unexplained.)"""
    return [(speed_rising(res), "a force of the position is the same while the speed rises "
             "and while it falls")]


def beats_smooth(ctx: Context, cols: np.ndarray) -> bool:
    """A periodic term is named only if it explains more than a smooth position force in its
    place. Without an accepted ``cable_slab``: a lower held-out MSE than the polynomial of the
    best held-out order. With one: a lower in-sample SSE than raising its order by two (the same
    number of columns; held-out folds would favour the sinusoid, which does not blow up where a
    fold's positions lie outside the others')."""
    res, st = ctx.res, ctx.res.settings
    fit_p = fit_cv(np.column_stack([ctx.x_s, cols]), res.z, res.fold, st.folds)
    rest = [s.cols for s in ctx.steps if s.term.effect != "cable_slab"] + [ctx.nuisance]
    x_rest = np.column_stack([np.zeros((len(res.z), 0))] + rest)
    have = [s.term.order for s in ctx.steps if s.term.effect == "cable_slab"]
    if not have:
        return fit_p.cv_mse < best_smooth_cv(res, x_rest)
    smooth = smooth_term(res, max(have) + 2).columns(res)
    return fit_p.sse < fit_cv(np.column_stack([x_rest, smooth]), res.z, res.fold, st.folds).sse




def dip_beats_presliding(ctx: Context, cols: np.ndarray, peak: float) -> bool:
    """A Stribeck *dip* (friction below Coulomb at low speed, peak < 0) is what pre-sliding
    friction looks like in the velocity domain: after a reversal at acceleration ``a`` the Dahl
    transition of length ``L`` ends at ``v = sqrt(2 a L)``. It is named only when it explains the
    record better than the best pre-sliding element in its place (lower held-out MSE), which a
    record tells apart where the encoder resolves the pre-sliding length and the reversals are
    passed at more than one acceleration; and at most the model's Coulomb friction. Where the
    model holds a Stribeck peak of its own, a dip must also beat, by ``min_gain`` of the held-out
    MSE, that peak being ``not_supported`` (a dip that only cancels the model's peak is that)."""
    res = ctx.res
    if -peak > res.plant.coulomb:
        return False
    st = res.settings

    def cv(extra: np.ndarray) -> float:
        return fit_cv(np.column_stack([ctx.x_s, extra]), res.z, res.fold, st.folds).cv_mse

    dip = cv(cols)
    dropped = [t.template for t in ctx.used("not_supported")]
    current = ctx.fit_s.cv_mse
    for effect in res.plant.effects:
        if isinstance(effect, Stribeck) and not any(effect is d for d in dropped):
            absent = SupportTerm("not_supported", effect, ("support",)).columns(res)
            if dip > cv(absent) - st.min_gain * current:
                return False
    avoid = [t.template.length for t in ctx.used("presliding")]
    length = search_presliding(res, ctx.x_s, avoid)
    return length is None or dip < cv(presliding_term(length).columns(res))
