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

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import torch

from clm_sim.errors import UserError
from controllers.pgnn.network import PGNNNetwork

TERMS = ("data", "deviation", "pinn", "orthogonal", "weight_decay")


@dataclass(frozen=True)
class CostTerms:
    """The terms of the training cost at one point (N**2 each; see the module docstring): what
    a fitted PGNN keeps as ``cost_``. A model file stores them under ``"cost"`` through
    :meth:`to_json` (the term names are its keys)."""

    data: float
    deviation: float = 0.0
    pinn: float = 0.0
    orthogonal: float = 0.0
    weight_decay: float = 0.0

    @property
    def regularization(self) -> float:
        """Every term but the data term (N**2)."""
        return float(sum((self.deviation, self.pinn, self.orthogonal, self.weight_decay)))

    @property
    def total(self) -> float:
        """The training cost: the sum of the terms (N**2)."""
        return float(sum((self.data, self.deviation, self.pinn, self.orthogonal,
                          self.weight_decay)))

    def to_json(self) -> dict:
        return {"data": self.data, "deviation": self.deviation, "pinn": self.pinn,
                "orthogonal": self.orthogonal, "weight_decay": self.weight_decay}

    @classmethod
    def from_json(cls, d) -> CostTerms:
        """A model file's ``cost`` (a term missing from an older file: 0)."""
        if not isinstance(d, dict):
            raise UserError(f"cost: expected a mapping of the cost terms, got {type(d).__name__}")
        values = {}
        for name in TERMS:
            v = d.get(name, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UserError(f"cost.{name}: expected a finite number, got {v!r}")
            values[name] = float(v)
        return cls(**values)


@dataclass(frozen=True)
class Weights:
    """Weights of the cost terms (see the module docstring); ``lam_diag`` in THETA order."""

    lam_diag: np.ndarray
    pinn: float = 0.0
    orthogonal: float = 0.0
    weight_decay: float = 0.0


class Range:
    """An orthonormal basis ``U`` (m, k) of the range of a column-scaled linear system ``As``
    and its least-squares solution.

    ``qr``: ``As = U R`` by Cholesky QR applied twice (CholeskyQR2: Fukaya, Nakatsukasa,
    Yanagisawa and Yamamoto, 2014): ``R1`` the Cholesky factor of ``As'As``, ``U1 = As R1^-1``,
    then the same on ``U1``. The first pass squares the condition number, so ``U1`` is only
    approximately orthonormal (to about ``u * kappa**2``); the second pass makes it orthonormal
    to working precision where ``As``'s condition number is at most ``KAPPA_QR`` and ``U1``'s
    Gram matrix is within ``QR_GRAM_DEVIATION`` of the identity (``U1`` then has a condition
    number of at most 1.7: that pass squares nothing that matters). ``U = U1 T`` is kept as
    its two factors (``T`` the second pass's inverse triangular factor). About three times
    cheaper than an SVD here (21 columns): it is made of matrix products. ``svd``: the thin
    SVD, used
    where the check fails or the first Cholesky factorization does (nearly dependent columns:
    a network that mimics a physical regressor, a saturated neuron whose output is a constant,
    a condition number up to 1e16); its minimum-norm solution in scaled coordinates leaves out
    singular values below 1e-12 of the largest. Neither squares the condition number of the
    result: the solution and the basis are those of a backward-stable QR."""

    def __init__(self, kind: str, U: np.ndarray, R=None, s=None, Vt=None, T=None):
        self.kind, self._U, self.R, self.s, self.Vt, self._T = kind, U, R, s, Vt, T

    @classmethod
    def of(cls, As: np.ndarray, exact: bool = False) -> Range:
        """The range of ``As`` (columns of unit norm or zero); ``exact``: through the SVD."""
        if not exact:
            got = _cholesky_qr2(As)
            if got is not None:
                U1, T, R = got
                return cls("qr", U1, R=R, T=T)
        U, s, Vt = np.linalg.svd(As, full_matrices=False)
        keep = s > s[0] * 1e-12
        if not keep.all():
            U, s, Vt = U[:, keep], s[keep], Vt[keep]
        return cls("svd", U, s=s, Vt=Vt)

    @property
    def U(self) -> np.ndarray:
        """The orthonormal basis itself (``qr``: formed on demand; the methods do without)."""
        return self._U if self._T is None else self._U @ self._T

    def coordinates(self, M: np.ndarray) -> np.ndarray:
        """``U'M`` (``qr``: ``U = U1 T`` with the first pass's basis ``U1`` and the second
        pass's inverse factor ``T``, ``T'(U1'M)``: the product ``U1 T`` is never formed)."""
        C = self._U.T @ M
        return C if self._T is None else self._T.T @ C

    def project_out(self, J: np.ndarray) -> None:
        """``J -= U U'J`` in place (``J`` C-ordered): the update is one BLAS call that adds
        into ``J``, with no temporary of ``J``'s size."""
        C = self.coordinates(J)
        if self._T is not None:
            C = self._T @ C
        # In Fortran order J is J' (p, m): J' <- J' - C' U1'.
        scipy.linalg.blas.dgemm(-1.0, C, self._U, beta=1.0, c=J.T, trans_a=1, trans_b=1,
                                overwrite_c=1)

    def solve(self, c: np.ndarray) -> np.ndarray:
        """The least-squares solution of ``As x = c`` (minimum-norm where ``svd`` left out
        directions)."""
        if self.kind == "svd":
            return self.Vt.T @ ((self._U.T @ c) / self.s)
        return scipy.linalg.solve_triangular(self.R, self.coordinates(c), check_finite=False)


KAPPA_QR = 1e6
"""Largest condition number of the column-scaled linear system that :class:`Range` factorizes by
Cholesky QR: the first pass's basis is then orthonormal to ``u * kappa**2`` = 1e-4, which the
second pass repairs. Beyond (and for exactly dependent columns, whose Cholesky factor can look
regular by rounding), the SVD."""
QR_GRAM_DEVIATION = 0.5
"""Largest deviation (2-norm bound) of the first Cholesky QR pass's Gram matrix from the identity
for which :class:`Range` keeps the second pass's basis (checked after the fact)."""


def _cholesky_qr2(As: np.ndarray):
    """``(U1, T, R)`` with ``As = U R``, ``U = U1 T`` orthonormal and ``R`` upper triangular, by
    Cholesky QR twice; None where the first factorization fails or its basis is too far from
    orthonormal (:class:`Range`)."""
    potrf, trtri = scipy.linalg.lapack.dpotrf, scipy.linalg.lapack.dtrtri
    R1, info = potrf(As.T @ As, lower=0, clean=1)
    if info != 0:
        return None
    sv = np.linalg.svd(R1, compute_uv=False)  # those of As, to about u * kappa**2
    if not sv[-1] * KAPPA_QR > sv[0]:
        return None
    inv1, info = trtri(R1, lower=0)
    if info != 0:
        return None
    U1 = As @ inv1
    G = U1.T @ U1
    # The 2-norm of G - I is at most k times its largest entry.
    if len(G) * np.abs(G - np.eye(len(G))).max() > QR_GRAM_DEVIATION:
        return None
    R2, info = potrf(G, lower=0, clean=1)
    if info != 0:
        return None
    inv2, _ = trtri(R2, lower=0)
    return U1, inv2, R2 @ R1


class SeparableCost:
    """``cost(beta, jacobian)`` -> reduced residual ``r`` (and Jacobian) for
    :func:`controllers.optim.levenberg_marquardt`; ``||r||**2`` is the training cost at the best
    linear parameters for ``beta``, which :meth:`linear` returns. ``pinned``: physical
    parameters held at given values (index in THETA order -> value) while the rest is fitted
    (the profile of the cost over those parameters, :mod:`controllers.pgnn.profile`).

    The linear system, the Jacobian and their scratch arrays are allocated once, here: an
    evaluation writes into them (the Jacobian returned is that buffer, valid until the next
    call with ``jacobian=True``), and the blocks that do not depend on ``beta`` (the physical
    columns, the constant, the deviation and decay rows, the targets) are filled once."""

    def __init__(self, net: PGNNNetwork, phi: np.ndarray, target: np.ndarray,
                 theta_lip: np.ndarray, weights: Weights, fit_theta: bool,
                 pinned: dict[int, float] | None = None):
        self.net, self.phi, self.t = net, phi, target
        self.z = torch.from_numpy(np.ascontiguousarray(phi))
        # The network's input scaling (its first operation), once for all evaluations.
        self.zs = (self.z - net.mlp.input_mean) / net.mlp.input_std
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
        self.n_beta = len(self.decayed)
        self._layout()
        self._cache = (None, None)

    # -- the linear problem for fixed beta ---------------------------------------------------
    def _layout(self) -> None:
        """Rows of the linear least-squares problem in ``x = (theta?, w, b)``, by cost term:
        ``self.blocks`` (name, rows), the matrix ``self._A`` with every block that does not
        depend on the hidden outputs filled, the targets ``self._c``, and the Jacobian buffer."""
        n, w = self.n, self.w
        k = self.n_theta + self.n_hidden + 1
        ones = np.ones((n, 1))
        base = self.t - self.pinned_force if self.fit_theta else self.t - self.lip_pred
        parts = [("data", n, base * self.sq, self.sq)]
        if w.pinn > 0:
            s = np.sqrt(w.pinn) * self.sq
            parts.append(("pinn", n, (self.lip_pred - self.pinned_force if self.fit_theta
                                      else np.zeros(n)) * s, s))
        if self.fit_theta and np.any(w.lam_diag > 0):
            lam = w.lam_diag[self.free]
            parts.append(("deviation", len(self.free), np.sqrt(lam) * self.theta_lip[self.free],
                          None))
        if w.orthogonal > 0:
            parts.append(("orthogonal", 4, np.zeros(4), np.sqrt(w.orthogonal) * self.sq))
        if w.weight_decay > 0:
            parts.append(("weight_decay", self.n_hidden, np.zeros(self.n_hidden), None))
        m = sum(p[1] for p in parts)
        self._A = np.zeros((m, k))
        self._c = np.concatenate([p[2] for p in parts])
        self.blocks, self._factor, i = [], {}, 0
        for name, rows, _, factor in parts:
            sl = slice(i, i + rows)
            self.blocks.append((name, sl))
            self._factor[name] = factor
            A = self._A[sl]
            if name in ("data", "pinn"):
                if self.fit_theta:
                    A[:, :self.n_theta] = self.phi[:, self.free] * factor
                A[:, -1:] = ones * factor
            elif name == "deviation":
                A[:, :len(self.free)] = np.diag(np.sqrt(w.lam_diag[self.free]))
            elif name == "weight_decay":
                A[:, self.n_theta:self.n_theta + self.n_hidden] = \
                    np.sqrt(w.weight_decay) * np.eye(self.n_hidden)
            i += rows
        if w.orthogonal > 0:
            self._net_cols = np.ones((n, self.n_hidden + 1))
        # Jacobian: the linear-system rows (projected), then the hidden-weight decay rows.
        n_decay = int(self.decayed.sum()) if w.weight_decay > 0 else 0
        self._J = np.zeros((m + n_decay, self.n_beta))
        if n_decay:
            self._J[m + np.arange(n_decay), np.flatnonzero(self.decayed)] = \
                np.sqrt(w.weight_decay)
        self._jf = np.empty((n, self.n_beta))

    def _fill(self, h: np.ndarray) -> np.ndarray:
        """``self._A`` for hidden outputs ``h`` (N, n): the blocks that depend on them."""
        cols = slice(self.n_theta, self.n_theta + self.n_hidden)
        for name, sl in self.blocks:
            if name in ("data", "pinn"):
                np.multiply(h, self._factor[name], out=self._A[sl, cols])
            elif name == "orthogonal":
                self._net_cols[:, :-1] = h
                self._A[sl, self.n_theta:] = self._factor[name] * (self.q_phi.T @ self._net_cols)
        return self._A

    def _system(self, h: np.ndarray):
        """Blocks ``(name, A, c)`` of the linear least-squares problem in ``x`` for hidden
        outputs ``h``; ``x = (theta?, w, b)`` (views of buffers the next evaluation rewrites)."""
        A = self._fill(h)
        return [(name, A[sl], self._c[sl]) for name, sl in self.blocks]

    def _solve(self, beta: np.ndarray):
        """The linear least-squares problem at ``beta``, solved (cached for the last ``beta``):
        hidden outputs, layers, ``x``, the residual and the range of the column-scaled system
        (:class:`Range`)."""
        key = beta.tobytes()
        if self._cache[0] == key:
            return self._cache[1]
        layers = self.net.layer_outputs(beta, self.zs)
        h = layers[1][-1].numpy()
        A, c = self._fill(h), self._c
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        span = Range.of(A / scale)
        x = span.solve(c) / scale
        r_lin = A @ x - c
        out = {"h": h, "layers": layers, "x": x, "range": span, "r_lin": r_lin}
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

    def terms(self, beta: np.ndarray) -> CostTerms:
        """Each cost term (N**2) at ``beta`` and its best linear parameters."""
        sol = self._solve(beta)
        out = dict.fromkeys(TERMS, 0.0)
        for name, sl in self.blocks:
            part = sol["r_lin"][sl]
            out[name] += float(part @ part)
        if self.w.weight_decay > 0:
            d = self._decay_rows(beta)
            out["weight_decay"] += float(d @ d)
        return CostTerms(**out)

    def full_terms(self, p: np.ndarray) -> CostTerms:
        """Each cost term (N**2) at full parameters ``p = (x, beta)`` (no elimination: the
        optimizers lm and adam)."""
        r = self.full(p, False)
        beta = p[self.n_linear:]
        blocks = self._system(self.net.hidden_outputs(beta, self.z))
        out, i = dict.fromkeys(TERMS, 0.0), 0
        for name, A, _ in blocks:
            out[name] += float(r[i:i + len(A)] @ r[i:i + len(A)])
            i += len(A)
        out["weight_decay"] += float(r[i:] @ r[i:])
        return CostTerms(**out)

    def _residual(self, beta: np.ndarray, sol: dict) -> np.ndarray:
        return (np.concatenate([sol["r_lin"], self._decay_rows(beta)]) if self.w.weight_decay > 0
                else sol["r_lin"].copy())

    def __call__(self, beta: np.ndarray, jacobian: bool):
        sol = self._solve(beta)
        r = self._residual(beta, sol)
        if not jacobian:
            return r
        w_out = sol["x"][self.n_theta:self.n_theta + self.n_hidden]
        m = len(self._c)
        J = self._J[:m]
        self._beta_rows(beta, w_out, sol["layers"], out=J)
        # Kaufman: project out the range of A.
        sol["range"].project_out(J)
        return r, self._J

    def _beta_rows(self, beta, w_out, layers=None, out=None) -> np.ndarray:
        """``d (A(beta) x) / d beta`` for the linear-system rows, at output weights ``w_out``."""
        if out is None:
            out = np.zeros((len(self._c), len(beta)))
        if [name for name, _ in self.blocks if name in ("data", "pinn", "orthogonal")] \
                == ["data"]:
            # The network's Jacobian is linear in w_out: the data block's factor goes in
            # there, and the Jacobian is written in place (one pass over it saved).
            sl = self.blocks[0][1]
            self.net.network_jacobian(beta, w_out * self._factor["data"], self.zs, layers,
                                      out=out[sl])
            for name, rows in self.blocks[1:]:  # deviation, output-weight decay: no beta
                out[rows] = 0.0
            return out
        jf = self.net.network_jacobian(beta, w_out, self.zs, layers, out=self._jf)
        for name, sl in self.blocks:
            if name in ("data", "pinn"):
                np.multiply(jf, self._factor[name], out=out[sl])
            elif name == "orthogonal":
                out[sl] = self._factor[name] * (self.q_phi.T @ jf)
            else:  # deviation and output-weight decay rows do not depend on beta
                out[sl] = 0.0
        return out

    def _with_decay(self, J: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """``J`` with the rows of the hidden-weight decay (which depend on beta only)."""
        if not self.w.weight_decay > 0:
            return J
        decay = self._J[len(self._c):]
        Jd = np.zeros((len(decay), J.shape[1]))
        Jd[:, J.shape[1] - len(beta):] = decay
        return np.vstack([J, Jd])

    @property
    def n_linear(self) -> int:
        return self.n_theta + self.n_hidden + 1

    def full(self, p: np.ndarray, jacobian: bool):
        """The same cost over all parameters ``p = (x, beta)`` (no elimination): the problem
        the earlier fits solved, for comparison. Jacobian ``[A, d(A x)/d beta]``."""
        x, beta = p[:self.n_linear], p[self.n_linear:]
        layers = self.net.layer_outputs(beta, self.zs)
        A = self._fill(layers[1][-1].numpy())
        r = A @ x - self._c
        if self.w.weight_decay > 0:
            r = np.concatenate([r, self._decay_rows(beta)])
        if not jacobian:
            return r
        J = np.hstack([A, self._beta_rows(beta, x[self.n_theta:-1], layers)])
        return r, self._with_decay(J, beta)
