"""The selection's state: the accepted steps, the context a family proposes and checks
candidates in, a candidate and why one may not carry its name."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from experiments.diagnosis.fitting import Fit, fit_cv, solve
from experiments.diagnosis.residual import Residual
from experiments.diagnosis.terms import Term


@dataclass
class Step:
    """One accepted term and the statistics that accepted it."""

    term: Term
    cols: np.ndarray
    gain: float
    folds_improved: int
    p_value: float


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
