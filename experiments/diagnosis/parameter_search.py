"""The searches of the diagnosis's nonlinear parameters, on the current residual.

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
"""

from __future__ import annotations

import math

import numpy as np
import scipy.optimize

from experiments.diagnosis.fitting import (Projector, clearly_better, cv_of, fit_cv,
                                           grid_then_refine)
from experiments.diagnosis.residual import Residual
from experiments.diagnosis.terms import (MAX_SMOOTH_ORDER, SmoothTerm, presliding_term,
                                         smooth_term, stribeck_term)


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


def approx_periodic(res: Residual, kind: str, k: float) -> np.ndarray:
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
            return proj.sse(approx_periodic(res, kind, k))

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


def best_smooth_cv(res: Residual, base: np.ndarray) -> float:
    """The lowest held-out MSE of ``base`` plus a polynomial of order 2..MAX_SMOOTH_ORDER."""
    cache = res.cache.setdefault("smooth", {})
    if MAX_SMOOTH_ORDER not in cache:
        cache[MAX_SMOOTH_ORDER] = smooth_term(res, MAX_SMOOTH_ORDER).columns(res)
    cols = cache[MAX_SMOOTH_ORDER]
    return min(fit_cv(np.column_stack([base, cols[:, :o + 1]]), res.z, res.fold,
                      res.settings.folds).cv_mse for o in range(2, MAX_SMOOTH_ORDER + 1))
