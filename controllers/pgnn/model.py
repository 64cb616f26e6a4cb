"""Physics-guided neural network (PGNN) feedforward: ``u = theta_phy . T(phi) + f_NN(phi)``.

``T(phi) = [a, v, sign v, y]`` are the LIP features (same alignment as
:mod:`controllers.lip`); ``f_NN`` is one tanh hidden layer of ``hidden`` neurons fed the same four
features through fixed scalings (mean and standard deviation of the training features) stored in
the model. Training variants (PGNN paper):

* ``simultaneous``: ``theta_phy`` and the network together; cost = mean squared error
  ``+ (theta_phy - theta_LIP)' Lambda (theta_phy - theta_LIP)`` (regularized cost; ``Lambda =
  lam * I`` by default, any diagonal allowed, physical units; ``lam = 0`` is pure MSE);
* ``sequential``: ``theta_phy = theta_LIP`` fixed, the network fits the LIP residual;
* ``pinn``: for comparison, MSE ``+ w * mean((u_hat - theta_LIP . T)**2)``, which pulls the whole
  output toward the LIP prediction and therefore biases the fit where the LIP is wrong.

Initialization (``optimized``, the paper's lemma): a seeded random hidden layer, then the output
weights, output bias and ``theta_phy`` from the (regularized) linear least-squares problem they
solve for that hidden layer. Since ``theta_LIP`` with zero output weights is one of its candidates,
the initial cost never exceeds the LIP cost on the same data, and is strictly lower unless the
cost gradient at that candidate vanishes (:func:`lemma_condition`). ``random``: the output layer
is random too and ``theta_phy`` starts at ``theta_LIP``.

Data, and why it is consistent. The encoder counts (0.1 um) make raw second differences noisy
(~7 m/s**2 rms against ~3 m/s**2 of true acceleration); fitting on them would bias ``mass``
(errors in variables). As the LIP does, the four columns and the force are passed through the
*same* zero-phase low-pass (the parallel regression filter, ``FeatureMap.regression_lowpass_hz``)
and the fit uses the filtered columns ``phi_f`` and filtered force. For the physical part this is
exact (a linear filter commutes with ``theta . T``). For the network it amounts to *defining* its
input as the filtered features: the model is ``theta . T(phi) + f_NN(filter(phi))``, and replay
applies the same filter to the reference's features, so training and use see the same inputs.
This is accurate as long as the parasitic forces vary slowly compared with the filter (the
filtered force of ``f(phi)`` is close to ``f`` of the filtered ``phi``), which holds for forces of
position and velocity. After the filter the data carry nothing above its cut-off, so they are
decimated (``decimation``, default 20 -> 500 Hz, a common IDIM-LS practice; for a static map
subsampling is only a loss of statistical efficiency, and neighbouring samples are strongly
correlated after the filter anyway) to keep a full-batch
second-order fit at a few seconds. The lemma's comparison with the LIP uses these same data.

Defaults (decimation 20, 100 LM iterations) were chosen by ``benchmarks/bench_optimizer.py
--sensitivity`` (n_l = 16, 3 seeds, default training run): over decimation 10/20/40 and 30/100/200
iterations the r1 MAE stays at 0.24-0.26 um (seed std 0.01-0.02 um) and the r2 MAE at 0.44-0.61 um
with a seed std of 0.06-0.21 um, i.e. the seed matters more than data size or iterations, while a
fit costs 1-37 s CPU (about 7-9 s at the defaults).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.features import FeatureMap, edge_force, held_force, lip_regressors
from clm_sim.plant import THETA_NAMES
from controllers import optim

TRAININGS = ("simultaneous", "sequential", "pinn")


@dataclass(frozen=True)
class TrainingData:
    """Fitting data: physical columns ``phi`` (N, 4) = filtered [a, v, sign v, y] (SI units), the
    network's inputs (the same columns) and the filtered force ``target`` (N,)."""

    phi: np.ndarray
    target: np.ndarray

    def split(self, fraction: float) -> tuple["TrainingData", "TrainingData | None"]:
        """The first ``1 - fraction`` for fitting, the last ``fraction`` (contiguous) held out."""
        if fraction <= 0:
            return self, None
        n = len(self.target) - int(round(fraction * len(self.target)))
        return (TrainingData(self.phi[:n], self.target[:n]),
                TrainingData(self.phi[n:], self.target[n:]))


def training_data(features: FeatureMap, *, y: np.ndarray, u: np.ndarray, ts: float,
                  decimation: int = 20) -> TrainingData:
    """Filtered, aligned and decimated fitting data from positions ``y`` (m) and inputs ``u`` (N)."""
    yf, v, a = features.motion(y, ts)
    cols = np.column_stack([lip_regressors(yf, v, a), edge_force(u)])
    keep = features.fit_slice(len(yf))
    cols = features.regression_filter(cols, ts)[keep][::decimation]
    return TrainingData(phi=np.ascontiguousarray(cols[:, :4]), target=cols[:, 4].copy())


def _as_theta(theta) -> np.ndarray:
    return np.array([float(theta[k]) for k in THETA_NAMES])


@dataclass
class _Layout:
    """Names and shapes of the parameters; the one place a flat vector is cut into them."""

    hidden: int
    free: tuple[str, ...]

    def shapes(self) -> dict[str, tuple[int, ...]]:
        n = self.hidden
        return {"theta": (4,), "W1": (n, 4), "b1": (n,), "w2": (n,), "b2": (1,)}

    def unpack(self, p: np.ndarray, fixed: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out, i = dict(fixed), 0
        for name in self.free:
            shape = self.shapes()[name]
            size = int(np.prod(shape))
            out[name] = p[i:i + size].reshape(shape)
            i += size
        return out

    def pack(self, params: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([np.ravel(params[k]) for k in self.free])


def _forward(params, phi, s):
    """Prediction (N,), hidden outputs (N, n) for physical columns ``phi``, scaled inputs ``s``."""
    h = np.tanh(s @ params["W1"].T + params["b1"])
    return phi @ params["theta"] + h @ params["w2"] + params["b2"][0], h


class _Problem:
    """The training cost as a residual vector: ``V = ||r||**2`` (for the optimizers)."""

    def __init__(self, data: TrainingData, s: np.ndarray, layout: _Layout, fixed: dict,
                 theta_lip: np.ndarray, lam_diag: np.ndarray, pinn_weight: float):
        self.phi, self.t, self.s = data.phi, data.target, s
        self.layout, self.fixed = layout, fixed
        self.theta_lip, self.lam = theta_lip, lam_diag
        self.pinn = pinn_weight
        self.lip_pred = data.phi @ theta_lip
        self.sq = 1.0 / np.sqrt(len(data.target))
        self.n_free = sum(int(np.prod(layout.shapes()[k])) for k in layout.free)

    def terms(self, params) -> dict[str, float]:
        pred, _ = _forward(params, self.phi, self.s)
        dev = params["theta"] - self.theta_lip
        out = {"data": float(np.mean((self.t - pred) ** 2)), "deviation": float(dev @ (self.lam * dev))}
        if self.pinn:
            out["pinn"] = float(self.pinn * np.mean((pred - self.lip_pred) ** 2))
        return out

    def __call__(self, p, jacobian):
        params = self.layout.unpack(p, self.fixed)
        pred, h = _forward(params, self.phi, self.s)
        parts = [(pred - self.t) * self.sq]
        if self.pinn:
            parts.append(np.sqrt(self.pinn) * self.sq * (pred - self.lip_pred))
        reg = "theta" in self.layout.free and np.any(self.lam > 0)
        if reg:
            parts.append(np.sqrt(self.lam) * (params["theta"] - self.theta_lip))
        r = np.concatenate(parts)
        if not jacobian:
            return r
        dh = (1.0 - h * h) * (params["w2"] * self.sq)  # d pred / d b1, scaled, (N, n)
        N, n = h.shape
        J = np.zeros((len(r), self.n_free))
        Jp = J[:N]
        col = 0
        for name in self.layout.free:
            if name == "theta":
                Jp[:, col:col + 4] = self.phi * self.sq
                reg_col = col
            elif name == "w2":
                Jp[:, col:col + n] = h * self.sq
            elif name == "b2":
                Jp[:, col] = self.sq
            elif name == "b1":
                Jp[:, col:col + n] = dh
            elif name == "W1":  # row-major (n, 4): column j*4 + i is d pred / d W1[j, i]
                Jp[:, col:col + 4 * n].reshape(N, n, 4)[:] = dh[:, :, None] * self.s[:, None, :]
            col += int(np.prod(self.layout.shapes()[name]))
        if self.pinn:
            J[N:2 * N] = np.sqrt(self.pinn) * Jp
        if reg:
            J[len(r) - 4:, reg_col:reg_col + 4] = np.diag(np.sqrt(self.lam))
        return r, J


def _output_least_squares(data, h, theta_lip, lam_diag, pinn_weight, fit_theta):
    """theta_phy (or theta_LIP when not ``fit_theta``), w2, b2 minimizing the cost for fixed
    hidden outputs ``h``: the linear problem of the paper's lemma."""
    n = len(data.target)
    sq = 1.0 / np.sqrt(n)
    base = data.target if fit_theta else data.target - data.phi @ theta_lip
    cols = np.hstack([data.phi, h, np.ones((n, 1))]) if fit_theta else np.hstack([h, np.ones((n, 1))])
    A, b = [cols * sq], [base * sq]
    if pinn_weight:
        w = np.sqrt(pinn_weight) * sq
        A.append(cols * w)
        # PINN term: distance of the whole output to the LIP output phi @ theta_LIP.
        b.append((data.phi @ theta_lip if fit_theta else np.zeros(n)) * w)
    if fit_theta and np.any(lam_diag > 0):
        R = np.zeros((4, cols.shape[1]))
        R[:, :4] = np.diag(np.sqrt(lam_diag))
        A.append(R)
        b.append(np.sqrt(lam_diag) * theta_lip)
    A, b = np.vstack(A), np.concatenate(b)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    x, *_ = np.linalg.lstsq(A / scale, b, rcond=None)
    x = x / scale
    if fit_theta:
        return x[:4], x[4:-1], x[-1:]
    return theta_lip.copy(), x[:-1], x[-1:]


def lemma_condition(data: TrainingData, h: np.ndarray, theta_lip, lam_diag=None,
                    rtol: float = 1e-9) -> bool:
    """True when the regularized cost's gradient at ``(theta_LIP, w2 = 0, b2 = 0)`` is nonzero for
    hidden outputs ``h`` (N, n): then the optimized initialization is strictly better than the LIP.
    With ``theta_LIP`` the least-squares LIP on these data this is the paper's condition: the LIP
    residual is not orthogonal to the hidden outputs and the constant."""
    theta_lip = _as_theta(theta_lip) if isinstance(theta_lip, dict) else np.asarray(theta_lip)
    resid = data.target - data.phi @ theta_lip
    cols = np.hstack([data.phi, h, np.ones((len(h), 1))])
    g = cols.T @ resid / len(resid)
    ref = np.linalg.norm(cols, axis=0) / np.sqrt(len(resid)) * np.sqrt(np.mean(resid**2))
    return bool(np.any(np.abs(g) > rtol * np.maximum(ref, 1e-300)))


@dataclass
class PGNNFeedforward:
    """A PGNN feedforward; ``fit`` learns ``theta_`` (named, SI units), the network and
    ``history_``; ``predict``/``feedforward`` use them; ``save``/``load`` keep them.

    hidden: tanh neurons n_l; training: simultaneous, sequential or pinn; lam: regularization
    weight toward theta_LIP (``lam * I``); lambda_diag: per-parameter weights overriding ``lam``
    for the names given (mass, viscous, coulomb, stiffness); pinn_weight: weight of the PINN term;
    init: optimized (lemma) or random; optimizer: lm or adam; max_iter: LM iterations (Jacobian
    evaluations) or Adam steps; adam_lr: Adam step size; validation_fraction: last part of the
    data held out, best iterate chosen on it (0: best training cost); decimation: keep every
    ``decimation``-th filtered sample; features: the preprocessing shared with the LIP.
    """

    hidden: int = 16
    training: str = "simultaneous"
    lam: float = 0.0
    lambda_diag: dict[str, float] | None = None
    pinn_weight: float = 1.0
    init: str = "optimized"
    optimizer: str = "lm"
    max_iter: int = 100
    adam_lr: float = 1e-3
    validation_fraction: float = 0.0
    decimation: int = 20
    features: FeatureMap = field(default_factory=FeatureMap)

    def _settings(self) -> dict:
        return {k: getattr(self, k) for k in (
            "hidden", "training", "lam", "lambda_diag", "pinn_weight", "init", "optimizer",
            "max_iter", "adam_lr", "validation_fraction", "decimation")}

    def lambda_matrix_diag(self) -> np.ndarray:
        """Diagonal of Lambda, in the order of ``THETA_NAMES``."""
        diag = {k: self.lam for k in THETA_NAMES}
        for k, v in (self.lambda_diag or {}).items():
            if k not in diag:
                raise UserError(f"pgnn.lambda_diag: unknown parameter {k!r}; "
                                f"expected one of {', '.join(THETA_NAMES)}")
            diag[k] = float(v)
        return np.array([diag[k] for k in THETA_NAMES])

    # -- fitting ----------------------------------------------------------------------------
    def fit(self, *, y: np.ndarray, u: np.ndarray, ts: float, theta_lip: dict[str, float],
            rng: np.random.Generator) -> "PGNNFeedforward":
        """Identify from positions ``y`` (m) and applied inputs ``u`` (N) of a logged run;
        ``theta_lip`` is the LIP fitted with the same ``features``; ``rng`` draws the network."""
        data = training_data(self.features, y=y, u=u, ts=ts, decimation=self.decimation)
        return self.fit_data(data=data, theta_lip=theta_lip, rng=rng)

    def init_params(self, data: TrainingData, theta_lip: np.ndarray, rng: np.random.Generator):
        """Input scalings and initial parameters (dict) for ``data``; see the module docstring."""
        mean = data.phi.mean(axis=0)
        std = data.phi.std(axis=0)
        std[std == 0] = 1.0
        s = (data.phi - mean) / std
        n = self.hidden
        # Unit-variance inputs: weights of std 1/sqrt(4) and biases of std 1 keep the neurons
        # spread over their tanh range rather than saturated or linear.
        W1 = rng.standard_normal((n, 4)) / 2.0
        b1 = rng.standard_normal(n)
        params = {"W1": W1, "b1": b1}
        if self.init == "optimized":
            h = np.tanh(s @ W1.T + b1)
            theta, w2, b2 = _output_least_squares(
                data, h, theta_lip, self.lambda_matrix_diag(),
                self.pinn_weight if self.training == "pinn" else 0.0,
                fit_theta=self.training != "sequential")
        elif self.init == "random":
            resid_std = float(np.std(data.target - data.phi @ theta_lip))
            theta = theta_lip.copy()
            w2 = rng.standard_normal(n) * resid_std / np.sqrt(n)
            b2 = np.zeros(1)
        else:
            raise UserError(f"pgnn.init: expected 'optimized' or 'random', got {self.init!r}")
        params.update(theta=theta, w2=w2, b2=b2)
        return mean, std, params

    def _problem(self, data, theta_lip, mean, std, params):
        free = ("W1", "b1", "w2", "b2") if self.training == "sequential" else \
            ("theta", "W1", "b1", "w2", "b2")
        layout = _Layout(self.hidden, free)
        fixed = {"theta": theta_lip.copy()} if self.training == "sequential" else {}
        return _Problem(data, (data.phi - mean) / std, layout, fixed, theta_lip,
                        self.lambda_matrix_diag(),
                        self.pinn_weight if self.training == "pinn" else 0.0)

    def training_problem(self, data: TrainingData, theta_lip: dict[str, float],
                         rng: np.random.Generator):
        """``(cost, p0)``: the training cost as a residual function ``cost(p, jacobian)`` for
        :mod:`controllers.optim` and the initial flat parameter vector (for benchmarks)."""
        theta = _as_theta(theta_lip)
        mean, std, params = self.init_params(data, theta, rng)
        problem = self._problem(data, theta, mean, std, params)
        return problem, problem.layout.pack(params)

    def fit_data(self, *, data: TrainingData, theta_lip: dict[str, float],
                 rng: np.random.Generator) -> "PGNNFeedforward":
        """Identify from prepared :class:`TrainingData` (see :func:`training_data`)."""
        if self.training not in TRAININGS:
            raise UserError(f"pgnn.training: expected one of {', '.join(TRAININGS)}, "
                            f"got {self.training!r}")
        theta_lip = _as_theta(theta_lip)
        fit, held_out = data.split(self.validation_fraction)
        mean, std, params = self.init_params(fit, theta_lip, rng)
        problem = self._problem(fit, theta_lip, mean, std, params)
        check = None if held_out is None else self._problem(held_out, theta_lip, mean, std, params)
        layout = problem.layout
        history, best = [], {"score": np.inf}

        def record(it, p, cost):
            prm = layout.unpack(p, problem.fixed)
            entry = {"iteration": it, "cost": cost, **problem.terms(prm),
                     "theta": dict(zip(THETA_NAMES, map(float, prm["theta"])))}
            score = cost
            if check is not None:
                entry["validation"] = sum(check.terms(prm).values())
                score = entry["validation"]
            history.append(entry)
            if score < best["score"]:
                best.update(score=score, p=p.copy(), iteration=it)

        p0 = layout.pack(params)
        if self.optimizer not in ("lm", "adam"):
            raise UserError(f"pgnn.optimizer: expected 'lm' or 'adam', got {self.optimizer!r}")
        with optim.blas_threads(1):
            if self.optimizer == "lm":
                optim.levenberg_marquardt(problem, p0, max_iter=self.max_iter, callback=record)
            else:
                optim.adam(problem, p0, max_iter=self.max_iter, lr=self.adam_lr, callback=record)
        final = layout.unpack(best["p"], problem.fixed)
        self.scale_mean_, self.scale_std_ = mean, std
        self.params_ = {k: np.array(v, dtype=np.float64) for k, v in final.items()}
        self.theta_ = dict(zip(THETA_NAMES, map(float, final["theta"])))
        self.theta_lip_ = dict(zip(THETA_NAMES, map(float, theta_lip)))
        self.history_ = history
        self.best_iteration_ = int(best["iteration"])
        self.cost_ = problem.terms(final)
        self.n_samples_ = int(len(fit.target))
        return self

    # -- use ----------------------------------------------------------------------------------
    def _check_fitted(self):
        if not hasattr(self, "params_"):
            raise RuntimeError("PGNNFeedforward: call fit() before predict()")

    def network(self, phi_f: np.ndarray) -> np.ndarray:
        """The network's force (N) for filtered feature columns ``phi_f`` (N, 4)."""
        self._check_fitted()
        s = (phi_f - self.scale_mean_) / self.scale_std_
        return np.tanh(s @ self.params_["W1"].T + self.params_["b1"]) @ self.params_["w2"] \
            + self.params_["b2"][0]

    def predict_parts(self, *, y: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
        """Physical part ``theta . T`` and network part (N) at the sample instants of ``y`` (m)."""
        self._check_fitted()
        yf, v, a = self.features.motion(y, ts)
        phi = lip_regressors(yf, v, a)
        physical = phi @ _as_theta(self.theta_)
        return physical, self.network(self.features.regression_filter(phi, ts))

    def predict(self, *, y: np.ndarray, ts: float) -> np.ndarray:
        """Force (N) at the sample instants for positions ``y`` (m)."""
        physical, net = self.predict_parts(y=y, ts=ts)
        return physical + net

    def feedforward(self, r: np.ndarray, ts: float) -> np.ndarray:
        """The held input (N) per sample that tracks reference ``r`` (m)."""
        return held_force(self.predict(y=r, ts=ts))

    # -- storage ------------------------------------------------------------------------------
    def to_json(self) -> dict:
        self._check_fitted()
        return {"kind": "pgnn", "settings": self._settings(),
                "features": {k: getattr(self.features, k) for k in (
                    "regression_lowpass_hz", "position_lowpass_hz", "lowpass_order",
                    "edge_samples")},
                "theta": self.theta_, "theta_lip": self.theta_lip_, "cost": self.cost_,
                "input_mean": self.scale_mean_.tolist(), "input_std": self.scale_std_.tolist(),
                "best_iteration": self.best_iteration_, "n_samples": self.n_samples_,
                "history": self.history_}

    def save(self, path) -> None:
        """Write ``path.pt`` (tensors: weights and input scalings) and ``path.json`` (settings,
        scalings, theta, history)."""
        import torch

        path = Path(path)
        state = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in self.params_.items()}
        state["input_mean"] = torch.from_numpy(self.scale_mean_.copy())
        state["input_std"] = torch.from_numpy(self.scale_std_.copy())
        torch.save(state, path.with_suffix(".pt"))
        path.with_suffix(".json").write_text(json.dumps(self.to_json(), indent=1))

    @classmethod
    def load(cls, path) -> "PGNNFeedforward":
        """Read a model written by :meth:`save` (tensors loaded with ``weights_only=True``)."""
        import torch

        path = Path(path)
        try:
            info = json.loads(path.with_suffix(".json").read_text())
            state = torch.load(path.with_suffix(".pt"), weights_only=True)
        except (OSError, ValueError) as exc:
            raise UserError(f"{path}: cannot read PGNN model ({exc})") from None
        model = cls(**info["settings"], features=FeatureMap(**info["features"]))
        model.params_ = {k: state[k].numpy().astype(np.float64)
                         for k in ("theta", "W1", "b1", "w2", "b2")}
        model.scale_mean_ = state["input_mean"].numpy().astype(np.float64)
        model.scale_std_ = state["input_std"].numpy().astype(np.float64)
        model.theta_ = {k: float(v) for k, v in info["theta"].items()}
        model.theta_lip_ = info["theta_lip"]
        model.history_ = info["history"]
        model.best_iteration_ = info["best_iteration"]
        model.cost_ = info["cost"]
        model.n_samples_ = info["n_samples"]
        return model
