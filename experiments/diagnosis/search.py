"""Name the cause: candidate effects from the library, their nonlinear parameters found in the data,
and forward selection on held-out data.

Candidates (``FAMILIES``) are the effect vocabulary of :mod:`clm_sim.effects` plus
``parameter_mismatch`` (corrections of mass, viscous, coulomb, stiffness: the LIP columns) and, for
every effect the model holds, ``not_supported`` (a free scale on its force). Nonlinear parameters
are searched, never assumed:

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
* the ``cable_slab`` order: Legendre polynomials ``P_0..P_n`` of the position, ``n`` = 2..9 chosen
  by the blocked cross-validation below.

Significance rule (decided per step of a forward selection): with the accepted terms ``S``, a
candidate ``c`` is accepted when, in a blocked ``folds``-fold cross-validation over contiguous
blocks of the record, (1) it lowers the held-out MSE by at least ``min_gain`` of the current
held-out MSE and by at least ``min_explained`` of the held-out MSE of the model's own residual (the
noise floor: once the large causes are removed, ``min_gain`` alone would name model bias), (2) the
held-out MSE drops in at least ``min_folds`` of ``folds`` folds (counted among the
folds whose held-out SSE it changes by more than 1 %, at least two), and (3) an F-test of ``S + c``
against ``S`` on all fitted samples, with the effective sample count of the filtered data, has
p < ``p_value``, and (4) the force it explains (RMS of the held-out MSE drop) is at least
``min_force_fraction`` of the measured force's RMS; a Stribeck term must also be a peak
(peak > 0) or a dip that beats pre-sliding friction in its place (peak < 0, friction below
Coulomb at low speed, at most the model's Coulomb friction), pre-sliding friction positive and
at most the model's Coulomb friction, a
``not_supported`` scale below -0.5, a parameter mismatch reportable (:func:`reportable`), a
``cable_slab`` more than its constant and linear part, and a periodic term better than a smooth
force in its place (:func:`_beats_smooth`). Each step takes
the candidate with the largest held-out gain that passes; the search stops when none does, so a
model that already explains the data yields no finding. A backward pass then drops any term
whose removal from the final model raises the held-out MSE by less than these thresholds (made
redundant by later terms).

Identifiability: during motion an asymmetric Coulomb friction is a symmetric one plus a constant
force ``(c_pos - c_neg)/2``, and the diagnosis leaves standstill out (the direction of motion is
unknown there). A constant force is therefore reported as ``force_offset`` (or as the constant of
a ``cable_slab``); ``friction_asymmetry`` is the direction-odd viscous part (its ``|v|``
signature), with the Coulomb part reported as 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.stats

from clm_sim.effects import (CableSlab, Cogging, Effect, ForceOffset, ForceRipple,
                             FrictionAsymmetry, Presliding, Stribeck)
from clm_sim.plant import THETA_NAMES
from experiments.diagnosis.residual import Residual

PERIODIC = ("cogging", "force_ripple")
REPEATABLE = (*PERIODIC, "presliding")


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


FIXED = {
    "parameter_mismatch": Term("parameter_mismatch", None, THETA_NAMES),
    "force_offset": Term("force_offset", ForceOffset(), ("offset",)),
    "friction_asymmetry": Term("friction_asymmetry", FrictionAsymmetry(), ("asym_viscous",)),
}
FAMILIES = ("parameter_mismatch", "presliding", "cable_slab", "cogging", "force_ripple", "stribeck",
            "friction_asymmetry", "force_offset")
MAX_SMOOTH_ORDER = 9


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


# ---------------------------------------------------------------- least squares and validation
def _solve(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.clip(np.diag(g), 1e-300, None))
    gs = g / np.outer(d, d) + 1e-12 * np.eye(len(d))
    return np.linalg.solve(gs, b / d) / d


@dataclass
class Fit:
    """Least-squares fit with its blocked cross-validation: coefficients, in-sample SSE, held-out
    SSE per fold."""

    coef: np.ndarray
    sse: float
    cv_sse: np.ndarray

    @property
    def cv_mse(self) -> float:
        return float(np.sum(self.cv_sse))


def fit_cv(x: np.ndarray, z: np.ndarray, fold: np.ndarray, folds: int) -> Fit:
    """Fit ``z ~ x`` on all samples and, per fold, on the other folds (held-out SSE per fold)."""
    zz = np.array([z[fold == f] @ z[fold == f] for f in range(folds)])
    if x.shape[1] == 0:
        return Fit(np.zeros(0), float(zz.sum()), zz)
    gs = np.stack([x[fold == f].T @ x[fold == f] for f in range(folds)])
    bs = np.stack([x[fold == f].T @ z[fold == f] for f in range(folds)])
    g, b = gs.sum(0), bs.sum(0)
    coef = _solve(g, b)
    sse = float(z @ z - 2 * coef @ b + coef @ g @ coef)
    cv = np.empty(folds)
    for f in range(folds):
        # A fold whose columns the others do not determine (a high polynomial order where the
        # fold's positions lie outside the others') predicts nothing: its held-out SSE is inf.
        with np.errstate(over="ignore", invalid="ignore"):
            c = _solve(g - gs[f], b - bs[f])
            cv[f] = zz[f] - 2 * c @ bs[f] + c @ gs[f] @ c
    cv[~np.isfinite(cv)] = np.inf
    return Fit(coef, max(sse, 0.0), np.maximum(cv, 0.0))


class Projector:
    """In-sample SSE of ``z ~ [base, c]`` for many candidate columns ``c``, with ``base``
    projected out once (QR), so each evaluation costs O(n*(p+k))."""

    def __init__(self, base: np.ndarray, z: np.ndarray):
        self.q = np.linalg.qr(base)[0] if base.shape[1] else np.zeros((len(z), 0))
        self.e = z - self.q @ (self.q.T @ z)

    def sse(self, c: np.ndarray) -> float:
        c = c - self.q @ (self.q.T @ c)
        g, b = c.T @ c, c.T @ self.e
        try:
            coef = _solve(g, b)
        except np.linalg.LinAlgError:
            return float(self.e @ self.e)
        return float(self.e @ self.e - b @ coef)


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

    def col(logv):
        if exact:
            return stribeck_term(math.exp(logv)).columns(res)
        shape = np.sign(vf) * np.exp(-((np.abs(vf) / math.exp(logv)) ** 2))
        return (res.coverage[res.idx] * shape)[:, None]

    proj = Projector(base, res.z)

    def cost(logv):
        return proj.sse(col(logv))

    return math.exp(_grid_then_refine(cost, np.linspace(lo, hi, 16), xatol=2e-3, maxiter=25))


def _grid_then_refine(cost, grid, *, xatol: float, maxiter: int) -> float:
    """The minimizer of a 1-D ``cost``: the best ``grid`` point, then a bounded scalar search
    between its neighbours."""
    j = int(np.argmin([cost(g) for g in grid]))
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    r = scipy.optimize.minimize_scalar(cost, bounds=(a, b), method="bounded",
                                       options={"xatol": xatol, "maxiter": maxiter})
    return float(r.x)


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
    return math.exp(_grid_then_refine(cost, grid, xatol=1e-2, maxiter=12))


def search_smooth(res: Residual, base: np.ndarray, max_order: int = MAX_SMOOTH_ORDER
                  ) -> tuple[SmoothTerm, np.ndarray, float]:
    """The ``cable_slab`` polynomial order chosen on held-out data (blocked CV of ``base`` plus
    ``P_0..P_order``, order 2..``max_order``); returns the term, its columns and its CV MSE."""
    st = res.settings
    cache = res.cache.setdefault("smooth", {})
    if max_order not in cache:
        cache[max_order] = smooth_term(res, max_order).columns(res)
    cols = cache[max_order]
    best = None
    for order in range(2, max_order + 1):
        x = np.column_stack([base, cols[:, :order + 1]])
        cv = fit_cv(x, res.z, res.fold, st.folds).cv_mse
        if best is None or cv < best[2]:
            best = (smooth_term(res, order), cols[:, :order + 1], cv)
    return best


# ---------------------------------------------------------------- forward selection
@dataclass
class Step:
    """One accepted term and the statistics that accepted it."""

    term: Term
    cols: np.ndarray
    gain: float
    folds_improved: int
    p_value: float


def _test(res: Residual, x_s: np.ndarray, fit_s: Fit, cols: np.ndarray,
          base: float) -> tuple[float, float, int, float]:
    st = res.settings
    x1 = np.column_stack([x_s, cols])
    fit1 = fit_cv(x1, res.z, res.fold, st.folds)
    gain = (fit_s.cv_mse - fit1.cv_mse) / max(fit_s.cv_mse, 1e-300)
    explained = (fit_s.cv_mse - fit1.cv_mse) / max(base, 1e-300)
    # Folds where the candidate changes nothing (e.g. no slow motion for a Stribeck term) are
    # not counted; the drop is required in min_folds of the folds out of ``folds``, scaled down.
    changed = np.abs(fit1.cv_sse - fit_s.cv_sse) > 1e-2 * fit_s.cv_sse
    improved = int(np.sum(fit1.cv_sse[changed] < fit_s.cv_sse[changed]))
    if changed.sum() >= 2:
        improved = int(np.floor(improved * st.folds / int(changed.sum())))
    k = cols.shape[1]
    dof = max(res.n_eff - x1.shape[1], 1.0)
    n = len(res.z)
    # SSEs of the decimated samples, scaled to the effective count of independent samples.
    drop = max(fit_s.sse - fit1.sse, 0.0) * res.n_eff / n
    rest = max(fit1.sse, 1e-300) * res.n_eff / n
    p = float(scipy.stats.f.sf((drop / k) / (rest / dof), k, dof))
    return gain, explained, improved, p


def forward_select(res: Residual) -> list[Step]:
    """Forward selection of causes on ``res`` by the significance rule of this module."""
    st = res.settings
    steps: list[Step] = []
    fixed_cols = {name: term.columns(res) for name, term in FIXED.items()}
    base = fit_cv(np.zeros((len(res.z), 0)), res.z, res.fold, st.folds).cv_mse
    while len(steps) < st.max_findings:
        used = [s.term for s in steps]
        x_s = np.column_stack([np.zeros((len(res.z), 0))] + [s.cols for s in steps])
        fit_s = fit_cv(x_s, res.z, res.fold, st.folds)
        e = res.z - x_s @ fit_s.coef
        ranked = []
        for effect in res.plant.effects:
            if not any(t.template is effect for t in used if t.effect == "not_supported"):
                term = SupportTerm("not_supported", effect, ("support",))
                cols = term.columns(res)
                if np.any(cols):
                    ranked.append((term, cols, cols))
        for name in FAMILIES:
            if name not in REPEATABLE and any(t.effect == name for t in used):
                continue
            if name in FIXED:
                ranked.append((FIXED[name], fixed_cols[name], fixed_cols[name]))
            elif name in PERIODIC:
                avoid = [t.template.period for t in used if t.effect == name]
                period = search_period(res, name, x_s, e, avoid)
                if period is not None:
                    approx = _approx_periodic(res, name, 2 * math.pi / period)
                    ranked.append((periodic_term(name, period), approx, None))
            elif name == "cable_slab":
                term, cols, _ = search_smooth(res, x_s)
                ranked.append((term, cols, cols))
            elif name == "presliding":
                avoid = [t.template.length for t in used if t.effect == name]
                length = search_presliding(res, x_s, avoid)
                if length is not None:
                    term = presliding_term(length)
                    cols = term.columns(res)
                    ranked.append((term, cols, cols))
            else:
                vel = search_stribeck(res, x_s, exact=False)
                approx = stribeck_term(vel).columns(res)
                ranked.append((stribeck_term(vel), approx, None))
        scored = []
        for term, approx, exact in ranked:
            fit1 = fit_cv(np.column_stack([x_s, approx]), res.z, res.fold, st.folds)
            scored.append(((fit_s.cv_mse - fit1.cv_mse), term, exact))
        scored.sort(key=lambda s: -s[0])
        accepted = None
        for gain0, term, exact in scored:
            if gain0 <= 0:
                break
            if term.effect == "stribeck":
                term = stribeck_term(search_stribeck(res, x_s, exact=True))
            cols = exact if exact is not None else term.columns(res)
            gain, explained, improved, p = _test(res, x_s, fit_s, cols, base)
            if not _physical(res, term, x_s, cols, steps):
                continue
            if term.effect in PERIODIC and not _beats_smooth(res, steps, x_s, cols):
                continue
            if term.effect == "cable_slab":  # more than an offset and a stiffness
                x_lin = np.column_stack([x_s, cols[:, :2]])
                g2, e2, i2, p2 = _test(res, x_lin, fit_cv(x_lin, res.z, res.fold, st.folds),
                                       cols[:, 2:], base)
                if not (g2 >= st.min_gain and e2 >= st.min_explained and i2 >= st.min_folds
                        and p2 < st.p_value):
                    continue
            force = math.sqrt(max(explained * base, 0.0) / len(res.z))
            if gain >= st.min_gain and explained >= st.min_explained and \
                    improved >= st.min_folds and p < st.p_value and \
                    force >= st.min_force_fraction * res.force_rms:
                accepted = Step(term, cols, gain, improved, p)
                break
        if accepted is None:
            break
        steps.append(accepted)
    return prune(res, _stiffness_in_cable(steps))


def _stiffness_in_cable(steps: list[Step]) -> list[Step]:
    """With a ``cable_slab`` accepted, a parameter mismatch's stiffness column lies in the span
    of the polynomial (its linear part): their split is arbitrary, so the stiffness correction
    is left to the polynomial and not reported as a mismatch."""
    if not any(s.term.effect == "cable_slab" for s in steps):
        return steps
    out = []
    for s in steps:
        if s.term.effect == "parameter_mismatch" and "stiffness" in s.term.keys:
            keep = [j for j, k in enumerate(s.term.keys) if k != "stiffness"]
            term = Term("parameter_mismatch", None, tuple(s.term.keys[j] for j in keep))
            s = Step(term, s.cols[:, keep], s.gain, s.folds_improved, s.p_value)
        out.append(s)
    return out


def _beats_smooth(res: Residual, steps: list[Step], x_s: np.ndarray, cols: np.ndarray) -> bool:
    """A periodic term is named only if it explains more than a smooth position force in its
    place. Without an accepted ``cable_slab``: a lower held-out MSE than the polynomial of the
    best held-out order. With one: a lower in-sample SSE than raising its order by two (the same
    number of columns; held-out folds would favour the sinusoid, which does not blow up where a
    fold's positions lie outside the others')."""
    st = res.settings
    fit_p = fit_cv(np.column_stack([x_s, cols]), res.z, res.fold, st.folds)
    rest = [s.cols for s in steps if s.term.effect != "cable_slab"]
    x_rest = np.column_stack([np.zeros((len(res.z), 0))] + rest)
    have = [s.term.order for s in steps if s.term.effect == "cable_slab"]
    if not have:
        return fit_p.cv_mse < search_smooth(res, x_rest)[2]
    smooth = smooth_term(res, max(have) + 2).columns(res)
    return fit_p.sse < fit_cv(np.column_stack([x_rest, smooth]), res.z, res.fold, st.folds).sse


def _physical(res: Residual, term: Term, x_s: np.ndarray, cols: np.ndarray,
              steps: list[Step]) -> bool:
    """A Stribeck term must be a friction peak (peak > 0), or a dip that beats pre-sliding in its
    place (:func:`_dip_beats_presliding`), and pre-sliding friction a positive force to carry
    their names; a model effect is ``not_supported`` when the data holds less than
    half of it; a parameter mismatch must correct at least one parameter by
    the rule of :func:`reportable` (a joint fit whose every part is within its uncertainty
    names nothing)."""
    if term.effect not in ("stribeck", "presliding", "parameter_mismatch", "not_supported"):
        return True
    x = np.column_stack([x_s, cols])
    coef = _solve(x.T @ x, x.T @ res.z)
    if term.effect == "not_supported":
        return bool(coef[-1] < -0.5)
    if term.effect == "presliding":
        # It takes friction over from the model's Coulomb friction: at most all of it (5 %
        # slack for its uncertainty), shared among the accepted elements.
        mask = np.concatenate([np.zeros(0, bool)] + [np.full(s.cols.shape[1], s.term.effect ==
                                                             "presliding") for s in steps])
        moved = float(coef[x_s.shape[1]:].sum() + coef[:x_s.shape[1]][mask].sum())
        return bool(coef[-1] > 0 and moved <= 1.05 * res.plant.coulomb)
    if term.effect == "stribeck" and coef[-1] < 0:
        return _dip_beats_presliding(res, x_s, cols, steps, float(coef[-1]))
    if term.effect != "parameter_mismatch":
        return bool(coef[-1] > 0)
    std = coefficient_std(res, x, coef)
    k = cols.shape[1]
    return any(reportable(res, coef[x_s.shape[1] + j], std[x_s.shape[1] + j], cols[:, j])
               for j in range(k))


def _dip_beats_presliding(res: Residual, x_s: np.ndarray, cols: np.ndarray, steps: list[Step],
                          peak: float) -> bool:
    """A Stribeck *dip* (friction below Coulomb at low speed, peak < 0) is what pre-sliding
    friction looks like in the velocity domain: after a reversal at acceleration ``a`` the Dahl
    transition of length ``L`` ends at ``v = sqrt(2 a L)``. It is named only when it explains the
    record better than the best pre-sliding element in its place (lower held-out MSE), which a
    record tells apart where the encoder resolves the pre-sliding length and the reversals are
    passed at more than one acceleration; and at most the model's Coulomb friction. Where the
    model holds a Stribeck peak of its own, a dip must also beat, by ``min_gain`` of the held-out
    MSE, that peak being ``not_supported`` (a dip that only cancels the model's peak is that)."""
    if -peak > res.plant.coulomb:
        return False
    st = res.settings

    def cv(extra: np.ndarray) -> float:
        return fit_cv(np.column_stack([x_s, extra]), res.z, res.fold, st.folds).cv_mse

    dip = cv(cols)
    dropped = [s.term.template for s in steps if s.term.effect == "not_supported"]
    current = fit_cv(x_s, res.z, res.fold, st.folds).cv_mse
    for effect in res.plant.effects:
        if isinstance(effect, Stribeck) and not any(effect is d for d in dropped):
            absent = SupportTerm("not_supported", effect, ("support",)).columns(res)
            if dip > cv(absent) - st.min_gain * current:
                return False
    avoid = [s.term.template.length for s in steps if s.term.effect == "presliding"]
    length = search_presliding(res, x_s, avoid)
    return length is None or dip < cv(presliding_term(length).columns(res))


# A corrected parameter is reported when it is this many standard errors from the model's value
# and its column explains this fraction of the residual RMS (a practical, not only statistical,
# difference).
MISMATCH_T = 5.0
MISMATCH_RMS_FRACTION = 0.05


def coefficient_std(res: Residual, x: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Standard errors of least-squares coefficients from the decimated samples, inflated to the
    effective sample count."""
    e = res.z - x @ coef
    sigma2 = float(e @ e) / max(res.n_eff - x.shape[1], 1.0)
    cov = np.linalg.pinv(x.T @ x) * sigma2 * len(res.z) / res.n_eff
    return np.sqrt(np.clip(np.diag(cov), 0, None))


def reportable(res: Residual, delta: float, std: float, col: np.ndarray) -> bool:
    """Whether a parameter correction ``delta`` is both significant and practically relevant."""
    contrib = abs(delta) * float(np.sqrt(np.mean(col**2)))
    return abs(delta) > MISMATCH_T * std and contrib > MISMATCH_RMS_FRACTION * res.rms()


def prune(res: Residual, steps: list[Step]) -> list[Step]:
    """Backward pass: drop the weakest term while leaving it out of the final model costs less
    than ``min_gain`` of the held-out MSE (a term that later ones made redundant)."""
    st = res.settings
    steps = list(steps)
    base = fit_cv(np.zeros((len(res.z), 0)), res.z, res.fold, st.folds).cv_mse
    while steps:
        x = np.column_stack([s.cols for s in steps])
        full = fit_cv(x, res.z, res.fold, st.folds).cv_mse
        losses = []
        for i in range(len(steps)):
            rest = [s.cols for j, s in enumerate(steps) if j != i]
            x_r = np.column_stack([np.zeros((len(res.z), 0))] + rest)
            loss = fit_cv(x_r, res.z, res.fold, st.folds).cv_mse - full
            losses.append(min(loss / full / max(st.min_gain, 1e-12),
                              loss / base / max(st.min_explained, 1e-12)))
        worst = int(np.argmin(losses))
        if losses[worst] >= 1.0:
            break
        del steps[worst]
    return steps
