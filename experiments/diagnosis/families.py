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

Nonlinear parameters are searched, never assumed:

* periods (``cogging``, ``force_ripple``): the current residual is binned on a uniform position
  grid (cogging: bin mean; ripple: per-bin least-squares gain on the motor force), its spatial
  spectrum (zero-padded FFT of 4096 bins) gives the three strongest peaks between the shortest
  period the filter passes at the typical speed (``v90 / (cutoff / 2)``, at least 16 bins) and a
  third of the stroke, and the best peak is refined by bounded least squares on the period;
* the Stribeck velocity: a logarithmic grid from 1.5 times the speed floor to half the typical
  speed, then bounded least squares on ``log(velocity)`` around the best grid point (exponent
  fixed at 2);
* the pre-sliding length (``presliding``, Dahl): a logarithmic grid from half an encoder count to
  1/50 of the stroke, refined the same way; the column is the Dahl state of the measured path
  minus ``sign(v)`` (this much of the model's Coulomb friction is pre-sliding);
* the ``cable_slab`` order: Legendre polynomials ``P_0..P_n`` of the position, ``n`` = 2..9: the
  lowest order whose held-out fit is not clearly worse than the best order's (parsimony).

Identifiability: during motion an asymmetric Coulomb friction is a symmetric one plus a constant
force ``(c_pos - c_neg)/2``, and the diagnosis leaves standstill out (the direction of motion is
unknown there). A constant force is therefore reported as ``force_offset``;
``friction_asymmetry`` is the direction-odd viscous part (its ``|v|`` signature), with the
Coulomb part reported as 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.optimize

from clm_sim.effects import (CableSlab, Cogging, Effect, ForceOffset, ForceRipple,
                             FrictionAsymmetry, Presliding, Stribeck)
from clm_sim.plant import THETA_NAMES
from experiments.diagnosis.finding import Estimate, Finding
from experiments.diagnosis.fitting import (Fit, Projector, clearly_better, coefficient_cov,
                                           coefficient_std, cv_of, disagrees, fit_cv,
                                           grid_then_refine, reportable, significance, solve)
from experiments.diagnosis.residual import Residual

MAX_SMOOTH_ORDER = 9


# ---------------------------------------------------------------- terms: columns of a candidate
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



# ---------------------------------------------------------------- nonlinear parameter searches
def spatial_peaks(y: np.ndarray, e: np.ndarray, w: np.ndarray | None, p_min: float,
                  p_max: float, count: int = 3, bins: int = 4096) -> list[float]:
    """Periods (m) of the strongest peaks of the residual's spectrum over position.

    ``e`` is binned on a uniform grid of ``y`` (mean per bin, or the least-squares gain on ``w``
    per bin when ``w`` is given: a modulation of ``w``), empty bins count as 0, and the
    zero-padded FFT's power is searched between the periods ``p_min`` and ``p_max``.
    """
    lo, hi = float(np.min(y)), float(np.max(y))
    width = (hi - lo) / bins
    k = np.clip(((y - lo) / width).astype(int), 0, bins - 1)
    if w is None:
        num, den = np.bincount(k, e, bins), np.bincount(k, None, bins).astype(float)
    else:
        num, den = np.bincount(k, e * w, bins), np.bincount(k, w * w, bins)
    have = den > 0
    g = np.zeros(bins)
    g[have] = num[have] / den[have]
    g[have] -= g[have].mean()
    pad = 8 * bins
    power = np.abs(np.fft.rfft(g, pad)) ** 2
    freq = np.fft.rfftfreq(pad, d=width)  # cycles per m
    band = (freq >= 1.0 / p_max) & (freq <= 1.0 / p_min)
    idx = np.flatnonzero(band)
    if idx.size < 3:
        return []
    p = power[idx]
    local = np.flatnonzero((p[1:-1] >= p[:-2]) & (p[1:-1] >= p[2:])) + 1
    best = local[np.argsort(p[local])[::-1][:count]]
    return [float(1.0 / freq[idx[j]]) for j in best]


def _approx_periodic(res: Residual, kind: str, k: float) -> np.ndarray:
    """Cheap columns for the period search: the position is smooth, so sin(k y) needs no filter;
    the ripple multiplies the filtered force (a slow modulation commutes with the low-pass)."""
    y = res.y[res.idx]
    s, c = np.sin(k * y), np.cos(k * y)
    w = res.coverage[res.idx] if kind == "cogging" else -res.u_filtered[res.idx]
    return np.column_stack([w * s, w * c])


def search_period(res: Residual, kind: str, base: np.ndarray, e: np.ndarray,
                  avoid: list[float]) -> float | None:
    """Period (m) of a ``cogging``/``force_ripple`` candidate on the current residual ``e``."""
    y = res.y[res.idx]
    span = float(np.ptp(y))
    v_typ = float(np.quantile(np.abs(res.v_filtered[res.idx]), 0.9))
    p_min = max(16 * span / 4096, v_typ / (0.5 * res.cutoff))
    p_max = span / 3.0
    if p_min >= p_max:
        return None
    w = None if kind == "cogging" else -res.u_filtered[res.idx]
    proj = Projector(base, res.z)
    best, best_sse = None, np.inf
    for period in spatial_peaks(y, e, w, p_min, p_max):
        if any(abs(period / a - 1) < 0.05 for a in avoid):
            continue
        k0, dk = 2 * math.pi / period, 2 * math.pi / span

        def cost(k):
            return proj.sse(_approx_periodic(res, kind, k))

        r = scipy.optimize.minimize_scalar(cost, bounds=(max(k0 - dk, 0.5 * k0), k0 + dk),
                                           method="bounded", options={"xatol": 1e-4 * k0})
        if r.fun < best_sse:
            best, best_sse = 2 * math.pi / float(r.x), float(r.fun)
    return best


def search_stribeck(res: Residual, base: np.ndarray, exact: bool) -> float:
    """Stribeck velocity (m/s): log grid, then bounded least squares on log(velocity)."""
    vf = res.v_filtered[res.idx]
    v_typ = float(np.quantile(np.abs(vf), 0.9))
    # A Stribeck velocity is identifiable only with data on both sides of it: start at 1.5 times the
    # speed floor (below it the fitted column lives on a few samples at the mask's edge).
    lo, hi = math.log(1.5 * res.v_floor), math.log(max(v_typ / 2, 4 * res.v_floor))

    cache = res.cache.setdefault("stribeck", {})  # filtered columns do not depend on base

    def col(logv):
        if exact:
            if logv not in cache:
                cache[logv] = stribeck_term(math.exp(logv)).columns(res)
            return cache[logv]
        shape = np.sign(vf) * np.exp(-((np.abs(vf) / math.exp(logv)) ** 2))
        return (res.coverage[res.idx] * shape)[:, None]

    proj = Projector(base, res.z)

    def cost(logv):
        return proj.sse(col(logv))

    return math.exp(grid_then_refine(cost, np.linspace(lo, hi, 16), xatol=2e-3, maxiter=25))


def search_presliding(res: Residual, base: np.ndarray, avoid: list[float] = ()) -> float | None:
    """Pre-sliding length (m): log grid from half an encoder count to 1/50 of the stroke (at most
    2 mm), then bounded least squares on ``log(length)``; exact (filtered) columns. Lengths
    within a factor of 2 of an accepted element (``avoid``) are not searched (a second element
    makes a generalized Maxwell-slip model of two bristle scales)."""
    q = max(res.quantum, 1e-9)
    span = float(np.ptp(res.y[res.idx]))
    lo, hi = math.log(0.5 * q), math.log(max(min(span / 50, 2e-3), 4 * q))
    proj = Projector(base, res.z)
    cache = res.cache.setdefault("presliding", {})  # filtered columns do not depend on base

    def cost(loglen):
        if loglen not in cache:
            cache[loglen] = presliding_term(math.exp(loglen)).columns(res)
        return proj.sse(cache[loglen])

    grid = np.linspace(lo, hi, 12)
    grid = [g for g in grid if all(abs(g - math.log(a)) > math.log(2.0) for a in avoid)]
    if not grid:
        return None
    # 1 % in length is far below what the data tells (the test bar is a factor of 2).
    return math.exp(grid_then_refine(cost, grid, xatol=1e-2, maxiter=12))


def search_smooth(res: Residual, base: np.ndarray, max_order: int = MAX_SMOOTH_ORDER
                  ) -> tuple[SmoothTerm, np.ndarray, float]:
    """The ``cable_slab`` polynomial on held-out data: blocked CV of ``base`` plus
    ``P_0..P_order`` for order 2..``max_order``; the lowest order that the best order does not
    fit clearly better (:func:`~experiments.diagnosis.fitting.clearly_better`: a higher order must
    earn its columns as a new term would). Returns the term, its columns and its CV MSE."""
    st = res.settings
    cache = res.cache.setdefault("smooth", {})
    if max_order not in cache:
        cache[max_order] = smooth_term(res, max_order).columns(res)
    cols = cache[max_order]
    fits = {order: fit_cv(np.column_stack([base, cols[:, :order + 1]]), res.z, res.fold,
                          st.folds) for order in range(2, max_order + 1)}
    best = min(fits, key=lambda o: fits[o].cv_mse)
    reference = cv_of(res).cv_mse  # the model's own residual, held out
    order = next(o for o in sorted(fits)
                 if o == best or not clearly_better(res, fits[o], fits[best], reference))
    return smooth_term(res, order), cols[:, :order + 1], fits[order].cv_mse


# ---------------------------------------------------------------- the selection's state
@dataclass
class Step:
    """One accepted term and the statistics that accepted it."""

    term: Term
    cols: np.ndarray
    gain: float
    folds_improved: int
    p_value: float

    @property
    def family(self) -> Family:
        return REGISTRY[self.term.effect]


@dataclass
class Context:
    """The state a family proposes and checks candidates in: the residual, the accepted steps,
    the ``nuisance`` columns (what the data holds but no family explains, :class:`Rejection`),
    the columns ``x_s`` of both (steps first) and their fit, the current residual ``e`` on the
    fitted samples, and ``base``, the held-out MSE of the model's own residual."""

    res: Residual
    steps: list[Step]
    nuisance: np.ndarray
    x_s: np.ndarray
    fit_s: Fit
    e: np.ndarray
    base: float

    @classmethod
    def of(cls, res: Residual, steps: list[Step], base: float,
           nuisance: np.ndarray | None = None) -> Context:
        if nuisance is None:
            nuisance = np.zeros((len(res.z), 0))
        x_s = np.column_stack([np.zeros((len(res.z), 0))] + [s.cols for s in steps]
                              + [nuisance])
        fit_s = fit_cv(x_s, res.z, res.fold, res.settings.folds)
        return cls(res, list(steps), nuisance, x_s, fit_s, res.z - x_s @ fit_s.coef, base)

    def used(self, name: str) -> list[Term]:
        return [s.term for s in self.steps if s.term.effect == name]

    def columns_of(self, name: str) -> np.ndarray:
        """Mask over the columns of ``x_s``: those of the accepted terms of family ``name``."""
        return np.concatenate([np.zeros(0, bool)]
                              + [np.full(s.cols.shape[1], s.term.effect == name)
                                 for s in self.steps]
                              + [np.zeros(self.nuisance.shape[1], bool)])

    def coef_with(self, cols: np.ndarray) -> np.ndarray:
        """In-sample least-squares coefficients of the accepted columns plus ``cols``."""
        x = np.column_stack([self.x_s, cols])
        return solve(x.T @ x, x.T @ self.res.z)


@dataclass(frozen=True)
class Rejection:
    """Why a significant candidate may not carry its family's name. ``nuisance``: columns that
    describe what the data holds there (the candidate's, or its law's split columns) when that
    part of the residual stays unexplained; None when the rejection only says there is nothing
    worth naming or another family names it. The selection holds the nuisance columns in every
    later test, not in the extended model: a part of the residual that is there but unexplained
    must not pass for another effect that happens to correlate with it."""

    reason: str
    nuisance: np.ndarray | None = None


@dataclass(frozen=True)
class Candidate:
    """A proposed term with cheap columns for ranking (``approx``) and, where already computed,
    its exact (filtered) columns."""

    term: Term
    approx: np.ndarray
    exact: np.ndarray | None = None

    def columns(self, res: Residual) -> np.ndarray:
        return self.exact if self.exact is not None else self.term.columns(res)


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
                          _approx_periodic(ctx.res, self.name, 2 * math.pi / period))]

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
        return fit_p.cv_mse < _best_smooth_cv(res, x_rest)
    smooth = smooth_term(res, max(have) + 2).columns(res)
    return fit_p.sse < fit_cv(np.column_stack([x_rest, smooth]), res.z, res.fold, st.folds).sse


def _best_smooth_cv(res: Residual, base: np.ndarray) -> float:
    """The lowest held-out MSE of ``base`` plus a polynomial of order 2..MAX_SMOOTH_ORDER."""
    cache = res.cache.setdefault("smooth", {})
    if MAX_SMOOTH_ORDER not in cache:
        cache[MAX_SMOOTH_ORDER] = smooth_term(res, MAX_SMOOTH_ORDER).columns(res)
    cols = cache[MAX_SMOOTH_ORDER]
    return min(fit_cv(np.column_stack([base, cols[:, :o + 1]]), res.z, res.fold,
                      res.settings.folds).cv_mse for o in range(2, MAX_SMOOTH_ORDER + 1))


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
