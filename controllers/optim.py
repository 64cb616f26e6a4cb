"""Full-batch optimizers for small nonlinear least-squares problems (~100 parameters).

Both minimize ``V(p) = ||r(p)||**2`` given ``fun(p, jacobian)`` that returns the residual vector
``r`` (and its Jacobian ``J = dr/dp`` when ``jacobian`` is true), in float64:

* :func:`levenberg_marquardt`: Gauss-Newton steps damped by ``mu * diag(J'J)`` (Marquardt's scaling,
  so the step does not depend on the units of the parameters), gain-ratio damping update of
  Nielsen (1999). Only cost decreases are accepted, so the last iterate is the best one.
* :func:`adam`: plain full-batch Adam on the gradient ``2 J'r`` (for comparison).

``callback(iteration, p, cost)`` is called on the initial point and on every accepted iterate.

The PGNN runs them inside :func:`clm_sim.numerics.single_threaded` (one BLAS thread): the
products here are tall and thin (26k x 101), and on a 2-core machine that also runs simulations, OpenBLAS's spinning threads
made ``J.T @ J`` nine times slower (0.37 s against 0.04 s, measured) and the small forward
products twenty times slower.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg


@dataclass(frozen=True)
class OptimResult:
    """Best parameters found, their cost, accepted iterations, residual evaluations, why the
    optimizer stopped (``converged``: the first-order test held; ``resolved``: the absolute
    test held (the Gauss-Newton model predicts, and the last iterations show, a decrease of at
    most ``atol``); ``max_iter``: the cap; ``stalled``: no step decreased the cost although the
    test did not hold; ``small_decrease``: the relative decrease fell below ``rtol``), the
    first-order measure, ``||grad V||`` and the
    damping ``mu`` of the last iteration (relative to Marquardt's scaling; a walk that continues
    from ``p`` may start from it)."""

    p: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    stop: str = "max_iter"
    first_order: float = float("nan")
    grad_norm: float = float("nan")
    mu: float = float("nan")


def first_order_measure(r: np.ndarray, J: np.ndarray, normal: np.ndarray | None = None,
                        g: np.ndarray | None = None) -> float:
    """Relative decrease of ``V = ||r||**2`` that the Gauss-Newton model predicts for its full step,
    ``r' J (J'J)^+ J' r / r'r`` (in [0, 1]; 0 at a stationary point). It is the squared cosine of
    the angle between ``r`` and the range of ``J``, so it does not depend on how the parameters
    are scaled; directions whose curvature is below 1e-12 of the largest (after Marquardt scaling)
    count as flat and are left out. ``normal`` (``J'J``) and ``g`` (``J'r``): these products when
    the caller has them already."""
    if normal is None:
        normal = J.T @ J
    if g is None:
        g = J.T @ r
    return first_order_from_normal(normal, g, float(r @ r),
                                   np.sqrt(np.einsum("ij,ij->j", J, J)))


def first_order_from_normal(normal: np.ndarray, g: np.ndarray, rr: float,
                            d: np.ndarray | None = None) -> float:
    """:func:`first_order_measure` from ``J'J``, ``J'r`` and ``r'r`` alone; ``d``: the column
    norms of ``J`` (default ``sqrt(diag(J'J))``)."""
    if d is None:
        d = np.sqrt(np.maximum(np.diag(normal), 0.0))
    # A column below 1e-12 of the largest is flat too; left in, its denormal-sized entries can
    # make LAPACK's eigensolver fail to converge (seen with saturated neurons).
    live = d > 1e-12 * d.max() if d.max() > 0 else np.zeros(d.shape, bool)
    if not live.any():
        return 0.0
    if not live.all():
        normal, g, d = normal[np.ix_(live, live)], g[live], d[live]
    w, V = _symmetric_eigen(normal / np.outer(d, d))
    keep = w > w[-1] * 1e-12
    proj = V[:, keep].T @ (g / d)
    return float(proj @ (proj / w[keep]) / max(rr, 1e-300))


def _symmetric_eigen(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors of the symmetric ``a``. LAPACK's divide and
    conquer (numpy's ``eigh``) can fail to converge on a Gauss-Newton matrix with entries some
    1e-40 of the others (seen: an n_l = 16 PGNN on a one-pass training run, where it failed with
    OpenBLAS's kernels pinned or not); the QL/QR iteration (``dsyev``) is slower and does not."""
    try:
        return np.linalg.eigh(a)
    except np.linalg.LinAlgError:
        return scipy.linalg.eigh(a, driver="ev")


def levenberg_marquardt(fun, p0: np.ndarray, *, max_iter: int = 100, mu0: float = 1e-3,
                        rtol: float = 0.0, ftol: float | None = None,
                        atol: float | None = None, atol_window: int = 10,
                        callback=None) -> OptimResult:
    """Minimize ``||r(p)||**2``; ``max_iter`` bounds the Jacobian evaluations.

    Converged when :func:`first_order_measure` is at most ``ftol`` (the Gauss-Newton model
    predicts less than that relative decrease: a stationary point to that accuracy); ``rtol``
    (off by default) also stops when an accepted step decreases the cost by less than that
    relative amount, the rule of the earlier fits. ``atol`` (off by default; the cost's units)
    also stops, as ``resolved``, when the predicted absolute decrease ``V * first_order`` is at
    most ``atol`` and the cost fell by at most ``atol`` over the last ``atol_window`` accepted
    iterations (so never before ``atol_window`` iterations: a point is not resolved on the
    prediction alone; ``atol_window=0`` is the prediction alone): the cost is then known to that
    resolution as far as the local model and the recent pace tell (a caller that states a
    resolution should check it by continuing some such points).
    """
    p = np.array(p0, dtype=np.float64)

    def products(p):
        """``r``, ``J'J`` and ``J'r`` at ``p`` (the Gauss-Newton matrix from ``J`` itself,
        never as a difference of larger products: it is the Gram matrix of a computed ``J``,
        so its small eigenvalues, the flat directions, are those of a nearby problem)."""
        r, J = fun(p, True)
        return r, J.T @ J, J.T @ r

    r, A, g = products(p)
    cost = float(r @ r)
    if callback is not None:
        callback(0, p, cost)
    mu, nu, evals, it = mu0, 2.0, 1, 0
    recent = [cost]  # the accepted costs (the resolution test's window)
    stop = "max_iter"
    d = np.zeros(len(p))
    while True:
        if ftol is not None or atol is not None:
            measure = first_order_from_normal(A, g, cost)
            if ftol is not None and measure <= ftol:
                stop = "converged"
                break
            if (atol is not None and measure * cost <= atol and len(recent) > atol_window
                    and recent[-1 - atol_window] - cost <= atol):
                stop = "resolved"
                break
        if it >= max_iter:
            break
        # Marquardt scaling by the largest column norm seen so far (as MINPACK): a column that
        # shrinks (a saturating neuron) keeps its damping instead of inviting a huge step.
        d = np.maximum(d, np.sqrt(np.maximum(np.diag(A), 1e-300)))
        As = A / np.outer(d, d)
        gs = g / d
        accepted = False
        while mu < 1e16:
            try:
                step = -scipy.linalg.cho_solve(
                    scipy.linalg.cho_factor(As + mu * np.eye(len(p))), gs) / d
            except np.linalg.LinAlgError:
                mu *= nu
                nu *= 2.0
                continue
            r_new = fun(p + step, False)
            evals += 1
            cost_new = float(r_new @ r_new)
            # Predicted decrease of the damped Gauss-Newton model (always > 0).
            predicted = float(step @ (mu * d * d * step - g))
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if rho > 0 and np.isfinite(cost_new):
                accepted = True
                break
            mu *= nu
            nu *= 2.0
        if not accepted:
            stop = "stalled"
            break
        it += 1
        p = p + step
        decrease = (cost - cost_new) / max(cost, 1e-300)
        mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        nu = 2.0
        r, A, g = products(p)
        evals += 1
        cost = float(r @ r)
        recent.append(cost)
        if callback is not None:
            callback(it, p, cost)
        if decrease < rtol:
            stop = "small_decrease"
            break
    return OptimResult(p=p, cost=cost, iterations=it, evaluations=evals, stop=stop,
                       first_order=first_order_from_normal(A, g, cost),
                       grad_norm=float(np.linalg.norm(2.0 * g)), mu=float(mu))


def adam(fun, p0: np.ndarray, *, max_iter: int = 1000, lr: float = 1e-3, betas=(0.9, 0.999),
         eps: float = 1e-8, callback=None) -> OptimResult:
    """Full-batch Adam on ``||r(p)||**2``; returns the best iterate seen (Adam is not monotone)."""
    p = np.array(p0, dtype=np.float64)
    m = np.zeros_like(p)
    v = np.zeros_like(p)
    best_p, best_cost = p.copy(), np.inf
    for it in range(max_iter + 1):
        r, J = fun(p, True)
        cost = float(r @ r)
        if callback is not None:
            callback(it, p, cost)
        if cost < best_cost:
            best_p, best_cost = p.copy(), cost
        if it == max_iter:
            break
        g = 2.0 * (J.T @ r)
        m = betas[0] * m + (1 - betas[0]) * g
        v = betas[1] * v + (1 - betas[1]) * g * g
        mhat = m / (1 - betas[0] ** (it + 1))
        vhat = v / (1 - betas[1] ** (it + 1))
        p = p - lr * mhat / (np.sqrt(vhat) + eps)
    return OptimResult(p=best_p, cost=best_cost, iterations=max_iter, evaluations=max_iter + 1)
