"""The PGNN training cost as a separable least-squares problem (variable projection).

The model output ``theta . T + H(beta) w + b`` is linear in ``x = (theta, w, b)`` (theta only when
it is trained) for fixed nonlinear parameters ``beta`` (the hidden layers). Every cost term below is
quadratic in ``x``, so the cost is ``||A(beta) x - c||**2 + ||d(beta)||**2``: for each ``beta`` the
best ``x`` is a linear least-squares solution, and the optimizer works on ``beta`` alone
(Golub & Pereyra's variable projection, with Kaufman's Jacobian ``(I - P_A) d(A x)/d beta``, whose
``J' r`` is the exact gradient of the reduced cost). Terms (``N`` samples, means over samples):

* ``data``: ``mean((u_hat - u)**2)``, the mean squared error (N**2);
* ``deviation``: ``(theta - theta_LIP)' Lambda (theta - theta_LIP)`` (regularized cost of the PGNN
  paper; Lambda diagonal, physical units);
* ``pinn``: ``w * mean((u_hat - theta_LIP . T)**2)``, the PINN-style pull toward the LIP output;
* ``orthogonal``: ``lambda_perp * mean((P f_NN)**2)`` with ``P`` the orthogonal projector onto the
  span of the physical regressor columns on the training data (Kon et al. 2022): the network is
  penalized for what the physical model could explain, which needs no theta_LIP;
* ``weight_decay``: ``alpha * ||W||**2`` over every weight matrix of the network (not the biases),
  the L2 regularization of the authors' toolbox.

The data term alone fixes only the sum of physics and network; every other term says which of the
two should carry what.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from controllers.pgnn.network import PGNNNetwork

TERMS = ("data", "deviation", "pinn", "orthogonal", "weight_decay")


@dataclass(frozen=True)
class Weights:
    """Weights of the cost terms (see the module docstring); ``lam_diag`` in THETA order."""

    lam_diag: np.ndarray
    pinn: float = 0.0
    orthogonal: float = 0.0
    weight_decay: float = 0.0


class SeparableCost:
    """``cost(beta, jacobian)`` -> reduced residual ``r`` (and Jacobian) for
    :func:`controllers.optim.levenberg_marquardt`; ``||r||**2`` is the training cost at the best
    linear parameters for ``beta``, which :meth:`linear` returns. ``pinned``: physical
    parameters held at given values (index in THETA order -> value) while the rest is fitted
    (the profile of the cost over those parameters, :mod:`controllers.pgnn.profile`)."""

    def __init__(self, net: PGNNNetwork, phi: np.ndarray, target: np.ndarray,
                 theta_lip: np.ndarray, weights: Weights, fit_theta: bool,
                 pinned: dict[int, float] | None = None):
        self.net, self.phi, self.t = net, phi, target
        self.z = torch.from_numpy(np.ascontiguousarray(phi))
        self.theta_lip, self.w, self.fit_theta = theta_lip, weights, fit_theta
        self.n = len(target)
        self.sq = 1.0 / np.sqrt(self.n)
        self.n_hidden = net.mlp.out.in_features
        self.pinned = dict(pinned or {}) if fit_theta else {}
        self.free = [k for k in range(4) if k not in self.pinned]
        self.pinned_force = phi @ np.array([self.pinned.get(k, 0.0) for k in range(4)])
        self.n_theta = len(self.free) if fit_theta else 0
        self.lip_pred = phi @ theta_lip
        self.q_phi = np.linalg.qr(phi)[0] if weights.orthogonal > 0 else None
        # Entries of beta that are weights (decayed), not biases.
        self.decayed = np.concatenate([
            np.full(net.mlp.get_parameter(k).numel(), k.endswith("weight"))
            for k in net.nonlinear_names()])
        self._cache = (None, None)

    # -- the linear problem for fixed beta ---------------------------------------------------
    def _system(self, h: np.ndarray):
        """Blocks ``(name, A, c)`` of the linear least-squares problem in ``x`` for hidden
        outputs ``h``; ``x = (theta?, w, b)``."""
        n, w = self.n, self.w
        ones = np.ones((n, 1))
        cols = (np.hstack([self.phi[:, self.free], h, ones]) if self.fit_theta
                else np.hstack([h, ones]))
        base = self.t - self.pinned_force if self.fit_theta else self.t - self.lip_pred
        k = cols.shape[1]
        blocks = [("data", cols * self.sq, base * self.sq)]
        if w.pinn > 0:
            s = np.sqrt(w.pinn) * self.sq
            blocks.append(("pinn", cols * s,
                           (self.lip_pred - self.pinned_force if self.fit_theta
                            else np.zeros(n)) * s))
        if self.fit_theta and np.any(w.lam_diag > 0):
            lam, free = w.lam_diag[self.free], self.free
            R = np.zeros((len(free), k))
            R[:, :len(free)] = np.diag(np.sqrt(lam))
            blocks.append(("deviation", R, np.sqrt(lam) * self.theta_lip[free]))
        if w.orthogonal > 0:
            net_cols = np.hstack([h, ones])
            R = np.zeros((4, k))
            R[:, self.n_theta:] = np.sqrt(w.orthogonal) * self.sq * (self.q_phi.T @ net_cols)
            blocks.append(("orthogonal", R, np.zeros(4)))
        if w.weight_decay > 0:
            R = np.zeros((self.n_hidden, k))
            R[:, self.n_theta:self.n_theta + self.n_hidden] = np.sqrt(w.weight_decay) * \
                np.eye(self.n_hidden)
            blocks.append(("weight_decay", R, np.zeros(self.n_hidden)))
        return blocks

    def _solve(self, beta: np.ndarray):
        key = beta.tobytes()
        if self._cache[0] == key:
            return self._cache[1]
        h = self.net.hidden_outputs(beta, self.z)
        blocks = self._system(h)
        A = np.vstack([b[1] for b in blocks])
        c = np.concatenate([b[2] for b in blocks])
        # Column scaling, then an SVD: the minimum-norm solution in scaled coordinates when
        # columns are (nearly) dependent, e.g. a network that mimics a physical regressor.
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        U, s, Vt = np.linalg.svd(A / scale, full_matrices=False)
        keep = s > s[0] * 1e-12
        U, s, Vt = U[:, keep], s[keep], Vt[keep]
        x = (Vt.T @ ((U.T @ c) / s)) / scale
        r_lin = A @ x - c
        out = {"h": h, "blocks": blocks, "x": x, "U": U, "r_lin": r_lin}
        self._cache = (key, out)
        return out

    def linear(self, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(theta, w_out, b_out)`` minimizing the cost for nonlinear parameters ``beta``."""
        x = self._solve(beta)["x"]
        if self.fit_theta:
            theta = np.array([self.pinned.get(k, 0.0) for k in range(4)])
            theta[self.free] = x[:self.n_theta]
        else:
            theta = self.theta_lip.copy()
        return theta, x[self.n_theta:self.n_theta + self.n_hidden], float(x[-1])

    def _decay_rows(self, beta):
        return np.sqrt(self.w.weight_decay) * beta[self.decayed]

    def terms(self, beta: np.ndarray) -> dict[str, float]:
        """Each cost term (N**2) at ``beta`` and its best linear parameters."""
        sol = self._solve(beta)
        out, i = dict.fromkeys(TERMS, 0.0), 0
        for name, A, _ in sol["blocks"]:
            part = sol["r_lin"][i:i + len(A)]
            out[name] += float(part @ part)
            i += len(A)
        if self.w.weight_decay > 0:
            d = self._decay_rows(beta)
            out["weight_decay"] += float(d @ d)
        return out

    def __call__(self, beta: np.ndarray, jacobian: bool):
        sol = self._solve(beta)
        parts = [sol["r_lin"]]
        if self.w.weight_decay > 0:
            parts.append(self._decay_rows(beta))
        r = np.concatenate(parts)
        if not jacobian:
            return r
        _, w_out, _ = self.linear(beta)
        J = self._beta_rows(sol["blocks"], beta, w_out)
        J = J - sol["U"] @ (sol["U"].T @ J)  # Kaufman: project out the range of A
        return r, self._with_decay(J, beta)

    def _beta_rows(self, blocks, beta, w_out) -> np.ndarray:
        """``d (A(beta) x) / d beta`` for the linear-system rows, at output weights ``w_out``."""
        jf = self.net.network_jacobian(beta, w_out, self.z)  # d f_NN / d beta, (N, p)
        rows = []
        for name, A, _ in blocks:
            if name == "data":
                rows.append(jf * self.sq)
            elif name == "pinn":
                rows.append(jf * (np.sqrt(self.w.pinn) * self.sq))
            elif name == "orthogonal":
                rows.append(np.sqrt(self.w.orthogonal) * self.sq * (self.q_phi.T @ jf))
            else:  # deviation and output-weight decay rows do not depend on beta
                rows.append(np.zeros((len(A), len(beta))))
        return np.vstack(rows)

    def _with_decay(self, J: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """``J`` with the rows of the hidden-weight decay (which depend on beta only)."""
        if not self.w.weight_decay > 0:
            return J
        Jd = np.zeros((int(self.decayed.sum()), J.shape[1]))
        Jd[np.arange(len(Jd)), J.shape[1] - len(beta) + np.flatnonzero(self.decayed)] = \
            np.sqrt(self.w.weight_decay)
        return np.vstack([J, Jd])

    @property
    def n_linear(self) -> int:
        return self.n_theta + self.n_hidden + 1

    def full(self, p: np.ndarray, jacobian: bool):
        """The same cost over all parameters ``p = (x, beta)`` (no elimination): the problem
        the earlier fits solved, for comparison. Jacobian ``[A, d(A x)/d beta]``."""
        x, beta = p[:self.n_linear], p[self.n_linear:]
        h = self.net.hidden_outputs(beta, self.z)
        blocks = self._system(h)
        A = np.vstack([b[1] for b in blocks])
        r = A @ x - np.concatenate([b[2] for b in blocks])
        if self.w.weight_decay > 0:
            r = np.concatenate([r, self._decay_rows(beta)])
        if not jacobian:
            return r
        J = np.hstack([A, self._beta_rows(blocks, beta, x[self.n_theta:-1])])
        return r, self._with_decay(J, beta)
