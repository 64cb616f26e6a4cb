"""Autocorrelation-robust (Newey-West) standard errors of a least-squares fit.

The white-noise standard errors of a least-squares fit, ``s**2 (X'X)^-1``, assume independent
residuals. The residuals of a filtered, decimated identification record are not: neighbouring
samples share the low-pass filter's memory and the unmodelled forces of one stroke (lag-1
autocorrelations around 0.5 are measured on the default training run). Newey and West (1987)
estimate the covariance of ``X'e`` from the residual autocovariances up to ``lags`` with
Bartlett weights ``1 - l / (lags + 1)``, which keeps the estimate positive semi-definite:

    cov(theta) = (X'X)^-1 [ sum_l w_l sum_t x_t e_t e_{t-l} x_{t-l}' (both signs of l) ] (X'X)^-1
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NeweyWest:
    """A least-squares fit with its standard errors: ``theta`` (p,), ``std_white`` and
    ``std_newey_west`` (p,, units of the coefficients), the residuals' lag-1 autocorrelation and
    the Bartlett lags used."""

    theta: np.ndarray
    std_white: np.ndarray
    std_newey_west: np.ndarray
    lag1_autocorr: float
    lags: int


def default_lags(n: int) -> int:
    """Newey and West's rule of thumb, ``floor(4 (n / 100)^(2/9))``."""
    return int(np.floor(4 * (n / 100.0) ** (2.0 / 9.0)))


def newey_west(cols: np.ndarray, target: np.ndarray, lags: int | None = None) -> NeweyWest:
    """Least squares of ``target`` (N,) on ``cols`` (N, p) with white-noise and Newey-West
    standard errors (units of the coefficients), the residuals' lag-1 autocorrelation and the
    lags used (``None``: :func:`default_lags`)."""
    x = np.asarray(cols, dtype=float)
    y = np.asarray(target, dtype=float)
    n, p = x.shape
    lags = default_lags(n) if lags is None else int(lags)
    theta, *_ = np.linalg.lstsq(x, y, rcond=None)
    e = y - x @ theta
    bread = np.linalg.inv(x.T @ x)
    white = np.sqrt(np.diag(bread) * (e @ e) / (n - p))
    xe = x * e[:, None]
    meat = xe.T @ xe
    for lag in range(1, lags + 1):
        gamma = xe[lag:].T @ xe[:-lag]
        meat += (1 - lag / (lags + 1)) * (gamma + gamma.T)
    hac = np.sqrt(np.diag(bread @ meat @ bread) * n / (n - p))
    rho1 = float(np.corrcoef(e[1:], e[:-1])[0, 1]) if n > 2 else 0.0
    return NeweyWest(theta, white, hac, rho1, lags)
