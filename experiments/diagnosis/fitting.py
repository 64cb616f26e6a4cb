"""Least squares with blocked cross-validation, and the statistics of the significance rule
(:mod:`experiments.diagnosis.search`): shared by the families and the selection loop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.stats

from experiments.diagnosis.residual import Residual


def solve(g: np.ndarray, b: np.ndarray) -> np.ndarray:
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
    coef = solve(g, b)
    sse = float(z @ z - 2 * coef @ b + coef @ g @ coef)
    cv = np.empty(folds)
    for f in range(folds):
        # A fold whose columns the others do not determine (a high polynomial order where the
        # fold's positions lie outside the others') predicts nothing: its held-out SSE is inf.
        with np.errstate(over="ignore", invalid="ignore"):
            c = solve(g - gs[f], b - bs[f])
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
            coef = solve(g, b)
        except np.linalg.LinAlgError:
            return float(self.e @ self.e)
        return float(self.e @ self.e - b @ coef)


def grid_then_refine(cost, grid, *, xatol: float, maxiter: int) -> float:
    """The minimizer of a 1-D ``cost``: the best ``grid`` point, then a bounded scalar search
    between its neighbours."""
    j = int(np.argmin([cost(g) for g in grid]))
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    r = scipy.optimize.minimize_scalar(cost, bounds=(a, b), method="bounded",
                                       options={"xatol": xatol, "maxiter": maxiter})
    return float(r.x)



@dataclass(frozen=True)
class Significance:
    """The statistics of adding columns to a model: held-out MSE gain (fraction of the current
    held-out MSE), explained (the same drop over the held-out MSE of the model's own residual),
    folds improved (scaled to ``folds``), F-test p-value on the fitted samples, and the fit."""

    gain: float
    explained: float
    improved: int
    p: float
    fit: Fit

    def passes(self, res: Residual) -> bool:
        """The held-out part of the significance rule, and the F-test."""
        st = res.settings
        return self.gain >= st.min_gain and self.explained >= st.min_explained and \
            self.improved >= st.min_folds and self.p < st.p_value


def compare(res: Residual, old: Fit, new: Fit, base: float) -> tuple[float, float, int]:
    """Held-out comparison of two fits of the same residual: ``(gain, explained, improved)`` of
    ``new`` over ``old`` (they need not be nested)."""
    st = res.settings
    gain = (old.cv_mse - new.cv_mse) / max(old.cv_mse, 1e-300)
    explained = (old.cv_mse - new.cv_mse) / max(base, 1e-300)
    # Folds where the candidate changes nothing (e.g. no slow motion for a Stribeck term) are
    # not counted; the drop is required in min_folds of the folds out of ``folds``, scaled down.
    changed = np.abs(new.cv_sse - old.cv_sse) > 1e-2 * old.cv_sse
    improved = int(np.sum(new.cv_sse[changed] < old.cv_sse[changed]))
    if changed.sum() >= 2:
        improved = int(np.floor(improved * st.folds / int(changed.sum())))
    return gain, explained, improved


def clearly_better(res: Residual, old: Fit, new: Fit, base: float) -> bool:
    """Whether ``new`` fits the held-out data clearly better than ``old``: by the held-out part of
    the significance rule (what a term must bring to join a model). Otherwise the two fit about
    equally, and the parsimony rule names the one with fewer parameters."""
    st = res.settings
    gain, explained, improved = compare(res, old, new, base)
    return gain >= st.min_gain and explained >= st.min_explained and improved >= st.min_folds


def significance(res: Residual, x_s: np.ndarray, fit_s: Fit, cols: np.ndarray,
                 base: float) -> Significance:
    """The statistics of adding ``cols`` to the model ``x_s`` (fitted: ``fit_s``)."""
    st = res.settings
    x1 = np.column_stack([x_s, cols])
    fit1 = fit_cv(x1, res.z, res.fold, st.folds)
    gain, explained, improved = compare(res, fit_s, fit1, base)
    k = cols.shape[1]
    dof = max(res.n_eff - x1.shape[1], 1.0)
    n = len(res.z)
    # SSEs of the decimated samples, scaled to the effective count of independent samples.
    drop = max(fit_s.sse - fit1.sse, 0.0) * res.n_eff / n
    rest = max(fit1.sse, 1e-300) * res.n_eff / n
    p = float(scipy.stats.f.sf((drop / k) / (rest / dof), k, dof)) if k else 1.0
    return Significance(gain, explained, improved, p, fit1)


def cv_of(res: Residual, *blocks: np.ndarray) -> Fit:
    """Blocked cross-validated fit of the residual on the columns ``blocks``."""
    x = np.column_stack([np.zeros((len(res.z), 0)), *blocks])
    return fit_cv(x, res.z, res.fold, res.settings.folds)


# difference).
MISMATCH_T = 5.0
MISMATCH_RMS_FRACTION = 0.05


def coefficient_cov(res: Residual, x: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Covariance of least-squares coefficients from the decimated samples, inflated to the
    effective sample count."""
    e = res.z - x @ coef
    sigma2 = float(e @ e) / max(res.n_eff - x.shape[1], 1.0)
    return np.linalg.pinv(x.T @ x) * sigma2 * len(res.z) / res.n_eff


def coefficient_std(res: Residual, x: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Standard errors of least-squares coefficients (:func:`coefficient_cov`)."""
    return np.sqrt(np.clip(np.diag(coefficient_cov(res, x, coef)), 0, None))


def reportable(res: Residual, delta: float, std: float, col: np.ndarray) -> bool:
    """Whether a parameter correction ``delta`` is both significant and practically relevant."""
    contrib = abs(delta) * float(np.sqrt(np.mean(col**2)))
    return abs(delta) > MISMATCH_T * std and contrib > MISMATCH_RMS_FRACTION * res.rms()




# A family's law fails where its force, fitted apart in two regimes the law does not tell apart,
# differs between them by more than this fraction of the force fitted jointly, and the difference
# is not the noise of the split fit (Wald test p below LAW_P). Law-abiding effects on the foreign
# records differ by at most 8 % (a dip under a 1 um encoder); LuGre friction read as a Stribeck
# curve by 95 % and more, a force ripple fitted to it by 160 %.
LAW_FRACTION = 0.5
LAW_P = 0.05


def disagrees(res: Residual, delta: np.ndarray, cov: np.ndarray, cols: np.ndarray,
              joint: np.ndarray) -> bool:
    """Whether coefficients fitted apart in two regimes, differing by ``delta`` (covariance
    ``cov``), contradict one law: the force of the difference (RMS of ``cols @ delta`` over the
    fitted samples) above ``LAW_FRACTION`` of the joint force (``cols @ joint``), at Wald-test
    p < ``LAW_P`` in ``len(delta)`` degrees of freedom."""
    delta = np.atleast_1d(delta)
    wald = float(delta @ np.linalg.pinv(np.atleast_2d(cov)) @ delta)
    diff = float(np.sqrt(np.mean((cols @ delta) ** 2)))
    force = float(np.sqrt(np.mean((cols @ np.atleast_1d(joint)) ** 2)))
    return bool(diff > LAW_FRACTION * force and scipy.stats.chi2.sf(wald, len(delta)) < LAW_P)
