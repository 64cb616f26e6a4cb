"""Autocorrelation-robust (Newey-West) standard errors of a least-squares fit.

The white-noise standard errors of a least-squares fit, ``s**2 (X'X)^-1``, assume independent
residuals. The residuals of a filtered, decimated identification record are not: neighbouring
samples share the low-pass filter's memory and the unmodelled forces of one stroke (lag-1
autocorrelations around 0.5 are measured on the default training run). Newey and West (1987)
estimate the covariance of ``X'e`` from the residual autocovariances up to ``lags`` with
Bartlett weights ``1 - l / (lags + 1)``, which keeps the estimate positive semi-definite:

    cov(theta) = (X'X)^-1 [ sum_l w_l sum_t x_t e_t e_{t-l} x_{t-l}' (both signs of l) ] (X'X)^-1

The lags are the caller's, the rule of thumb ``floor(4 (n / 100)^(2/9))``, or (``"auto"``) the
data-dependent bandwidth of Newey and West (1994) for the Bartlett kernel: from the
autocovariances of ``h_t = sum_k x_tk e_t / std(x_k e)`` (each score scaled, so that no column's
units weigh more) up to the rule-of-thumb lag, ``gamma = 1.1447 (s1 / s0)^(2/3)`` with
``s0 = sum_j sigma_j`` and ``s1 = sum_j |j| sigma_j`` over both signs of ``j``, and the lags
``floor(gamma n^(1/3))``. The residual's autocorrelation at the lags chosen is returned beside
them, so a reader sees what the window leaves out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NeweyWest:
    """A least-squares fit with its standard errors: ``theta`` (p,), ``std_white`` and
    ``std_newey_west`` (p,, units of the coefficients), the residuals' lag-1 autocorrelation,
    the Bartlett lags used and the residuals' autocorrelation at that lag."""

    theta: np.ndarray
    std_white: np.ndarray
    std_newey_west: np.ndarray
    lag1_autocorr: float
    lags: int
    autocorr_at_lags: float | None = None


def default_lags(n: int) -> int:
    """Newey and West's rule of thumb, ``floor(4 (n / 100)^(2/9))``."""
    return int(np.floor(4 * (n / 100.0) ** (2.0 / 9.0)))


def automatic_lags(xe: np.ndarray) -> int:
    """Newey and West's (1994) bandwidth for the Bartlett kernel from the scores ``xe`` (N, p)
    (see the module docstring), at most N - 1."""
    n = len(xe)
    std = xe.std(axis=0)
    std[std == 0] = 1.0
    h = (xe / std).sum(axis=1)
    pre = default_lags(n)
    sigma = np.array([h[j:] @ h[:n - j] / n for j in range(pre + 1)])
    s0 = sigma[0] + 2 * sigma[1:].sum()
    s1 = 2 * (np.arange(1, pre + 1) * sigma[1:]).sum()
    if s0 <= 0:
        return pre
    gamma = 1.1447 * ((s1 / s0) ** 2) ** (1.0 / 3.0)
    return int(min(np.floor(gamma * n ** (1.0 / 3.0)), n - 1))


def autocorrelation(e: np.ndarray, lag: int) -> float:
    """The sample autocorrelation of ``e`` at ``lag`` (0 where it has no pairs)."""
    if lag <= 0:
        return 1.0
    if lag >= len(e) - 1:
        return 0.0
    return float(np.corrcoef(e[lag:], e[:-lag])[0, 1])


def newey_west(cols: np.ndarray, target: np.ndarray,
               lags: int | str | None = None) -> NeweyWest:
    """Least squares of ``target`` (N,) on ``cols`` (N, p) with white-noise and Newey-West
    standard errors (units of the coefficients), the residuals' lag-1 autocorrelation, the
    lags used (``None``: :func:`default_lags`; ``"auto"``: :func:`automatic_lags`) and the
    residuals' autocorrelation at that lag."""
    x = np.asarray(cols, dtype=float)
    y = np.asarray(target, dtype=float)
    n, p = x.shape
    theta, *_ = np.linalg.lstsq(x, y, rcond=None)
    e = y - x @ theta
    if lags == "auto":
        lags = automatic_lags(x * e[:, None])
    lags = default_lags(n) if lags is None else int(lags)
    bread = np.linalg.inv(x.T @ x)
    white = np.sqrt(np.diag(bread) * (e @ e) / (n - p))
    xe = x * e[:, None]
    meat = xe.T @ xe
    for lag in range(1, lags + 1):
        gamma = xe[lag:].T @ xe[:-lag]
        meat += (1 - lag / (lags + 1)) * (gamma + gamma.T)
    hac = np.sqrt(np.diag(bread @ meat @ bread) * n / (n - p))
    rho1 = float(np.corrcoef(e[1:], e[:-1])[0, 1]) if n > 2 else 0.0
    return NeweyWest(theta, white, hac, rho1, lags, autocorrelation(e, lags))
