"""Physics-guided neural network (PGNN) feedforward: ``u = theta_phy . T(phi) + f_NN(phi)``.

``T(phi) = [a, v, sign v, y]`` are the LIP features (same alignment as :mod:`controllers.lip`);
``f_NN`` is a multilayer perceptron (:class:`controllers.pgnn.network.PGNNNetwork`, any widths and
activation) fed the same four features through fixed scalings (mean and standard deviation of the
training features) stored in the model. Training variants and cost terms
(:mod:`controllers.pgnn.cost`):

* ``simultaneous``: ``theta_phy`` and the network together; cost = mean squared error
  ``+ (theta_phy - theta_LIP)' Lambda (theta_phy - theta_LIP)`` (regularized cost of the PGNN
  paper; ``Lambda = lam * I`` by default, any diagonal allowed, physical units; ``lam = 0`` is pure
  MSE); ``orthogonal_weight`` adds the orthogonal-projection penalty of Kon et al. (2022) and
  ``weight_decay`` an L2 penalty on the network weights, with or without ``lam``;
* ``sequential``: ``theta_phy = theta_LIP`` fixed, the network fits the LIP residual;
* ``pinn``: for comparison, MSE ``+ w * mean((u_hat - theta_LIP . T)**2)``, which pulls the whole
  output toward the LIP prediction and therefore biases the fit where the LIP is wrong.

Initialization (``optimized``, the paper's lemma): seeded random hidden layers, then the output
weights, output bias and ``theta_phy`` from the (regularized) linear least-squares problem they
solve for those hidden layers. Since ``theta_LIP`` with zero output weights is one of its
candidates, the initial cost never exceeds the LIP cost on the same data, and is strictly lower
unless the cost gradient at that candidate vanishes (:func:`lemma_condition`).

Optimizer (``varpro``, default): the output layer and ``theta_phy`` enter linearly, so they are
eliminated by least squares at every step (variable projection); Levenberg-Marquardt with
Marquardt scaling works on the hidden layers alone. The lemma's initialization is the starting
point of that reduced problem by construction. A fit stops as ``converged`` when the Gauss-Newton
model predicts a relative decrease of at most ``ftol`` (:func:`controllers.optim.first_order_measure`,
a first-order stationarity test independent of parameter scaling), or at ``max_iter``;
``restarts`` independent draws of the hidden layers are optimized and the one with the lowest
training cost is kept. ``lm`` (Levenberg-Marquardt on all parameters, the earlier method) and
``adam`` remain for comparison (``benchmarks/bench_optimizer.py``).

Every fit runs on one thread (torch and BLAS), whatever the environment says: a reduction is then
always summed in the same order, so the same data and seed give the same bits on any machine with
the same libraries, and no result depends on ``OMP_NUM_THREADS``.

Data, and why it is consistent. The encoder counts (0.1 um) make raw second differences noisy
(~7 m/s**2 rms against ~3 m/s**2 of true acceleration); fitting on them would bias ``mass``
(errors in variables). As the LIP does, the four columns and the force are passed through the
*same* zero-phase low-pass (the parallel regression filter, ``FeatureMap.regression_lowpass_hz``)
and the fit uses the filtered columns ``phi_f`` and filtered force. For the physical part this is
exact (a linear filter commutes with ``theta . T``). For the network it amounts to *defining* its
input as the filtered features: the model is ``theta . filter(T) + f_NN(filter(T))``, and replay
applies the same filter to the reference's features for both parts, so training and use evaluate
the same function (replaying ``theta`` on raw features leaks ``delta_theta . (T - filter(T))`` of a
drifted fit at every reversal, where the network cancels only the filtered part).
This is accurate as long as the parasitic forces vary slowly compared with the filter, which holds
for forces of position and velocity. After the filter the data carry nothing above its cut-off, so
they are decimated (``decimation``, default one sample per 8 ms: 80 at 10 kHz, 8 at 1 kHz, so
125 samples/s at any rate, 6,600 samples for the default
training run, some 80 per network parameter; for a static map subsampling only costs statistical
efficiency, and neighbouring samples are strongly correlated after the filter anyway) to keep a
full-batch second-order fit at a few seconds. The lemma's comparison with the LIP uses these same
data.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import torch

from clm_sim.errors import NotFittedError, UserError, check_ts
from clm_sim.features import FeatureMap, held_force, lip_regressors
from clm_sim.numerics import available_memory_bytes, single_threaded
from clm_sim.plant import THETA_NAMES
from controllers.pgnn import storage, training
from controllers.pgnn.cost import SeparableCost, Weights
from controllers.pgnn.data import TrainingData, training_data
from controllers.pgnn.network import PGNNNetwork
from controllers.pgnn.starts import StartCache
from controllers.pgnn.training import as_theta, generator
from controllers.pgnn_settings import PGNNSettings, check_settings, parameter_count

_OPTIONS = frozenset(f.name for f in fields(PGNNSettings))  # a model's options, by name


MIN_FIT_SAMPLES = 50  # samples below which a network fit is a fit of noise, whatever its size


def fit_memory_bytes(parameters: int, samples: int, optimizer: str) -> int:
    """The memory (bytes) a fit's float64 matrices take at most: the Jacobian, its work copies,
    the network's own Jacobian and layer outputs (eight of samples x parameters), and for the
    Gauss-Newton optimizers (``lm``, ``varpro``) six square matrices of the parameters (the
    normal matrix, its damped copy, its Cholesky factor, the identity, an eigen-decomposition's
    vectors and a spare). Measured: a 1115-parameter network on 2099 samples grew the process
    by 0.17 GB at its peak; estimated 0.20 GB."""
    square = 0 if optimizer == "adam" else 6 * parameters ** 2
    return 8 * (square + 8 * samples * parameters)


class PGNNFeedforward:
    """A physics-guided neural network (PGNN) feedforward.

    The LIP's physical layer in parallel with a small tanh network, both on the filtered
    features ``[a, v, sign v, y]``, fitted from a logged run (``fit(*, y, u, ts, theta_lip,
    rng)``: ``rng``, a ``numpy.random.Generator`` or an integer seed, draws the network and
    has no default). ``predict``/``feedforward`` use the model at the fitted sample time only;
    ``save(path)`` writes ``path.pt`` (tensors) and ``path.json``, ``load`` reads them back
    (``weights_only=True``).

    Parameters
    ----------
    hidden : int or tuple of int
        Widths of the hidden layers (an int for one layer).
    training : {"simultaneous", "sequential", "pinn"}
        Physical layer and network together, the network on the LIP's residual, or with a
        PINN term.
    lam : float
        Weight of the distance of theta_phy to theta_LIP (simultaneous training).
    settings : PGNNSettings, optional
        The optimizer's and the cost's options.
    features : FeatureMap, optional
        The preprocessing shared with the LIP.
    **options
        Options of ``PGNNSettings`` by name (``PGNNFeedforward(hidden=8, max_iter=50)``):
        they replace those of ``settings``.

    Attributes
    ----------
    theta_ : dict
        The physical layer's parameters (kg, N*s/m, N, N/m).
    network_ : torch.nn.Module
        The network, its input scalings included.
    fit_ : FitRecord
        How the fit stopped (``stop``: converged, theta_moving, max_iter, stalled),
        ``iterations``, the cost terms.
    cost_, history_
        The cost terms at the kept iterate, and at every iteration.
    ts_ : float
        Sample time (s) of the data the model was fitted on.

    Raises
    ------
    UserError
        A setting its constraint refuses (here and again in ``fit``), a ``fit`` without
        ``rng``, another sample time than the fitted at ``predict``/``feedforward``.
    TypeError
        An unknown option, or ``settings`` that is not a ``PGNNSettings``.
    NotFittedError
        ``predict``, ``feedforward`` or ``save`` before ``fit``.

    Examples
    --------
    >>> from clm_sim import ExperimentConfig, Plant, PointToPoint, Testbed, Training
    >>> back_and_forth = PointToPoint(points_m=(0.0, 0.02, -0.02, 0.0), dwell_s=0.1)
    >>> config = ExperimentConfig(plant=Plant(effects=()), references={"r": back_and_forth},
    ...                           training=Training(reference="r", repeats=1), replay=("r",))
    >>> run = Testbed(config).training_run(seed=1)   # 2 s in closed loop, 50 N dither
    >>> from clm_sim import LIPFeedforward, PGNNFeedforward
    >>> lip = LIPFeedforward().fit(y=run.y, u=run.u, ts=run.ts)
    >>> pgnn = PGNNFeedforward(hidden=4, lam=0.01, max_iter=5).fit(
    ...     y=run.y, u=run.u, ts=run.ts, theta_lip=lip.theta_, rng=0)
    >>> pgnn.fit_.stop, pgnn.fit_.iterations
    ('max_iter', 5)
    >>> abs(pgnn.theta_["mass"] / lip.theta_["mass"] - 1) < 0.01   # held near the LIP's
    True
    >>> from pathlib import Path
    >>> pgnn.save("pgnn"); sorted(p.name for p in Path(".").glob("pgnn.*"))
    ['pgnn.json', 'pgnn.pt']
    """

    def __init__(self, *, hidden: int | tuple[int, ...] = 16, training: str = "simultaneous",
                 lam: float = 0.0, settings: PGNNSettings | None = None,
                 features: FeatureMap | None = None, **options):
        unknown = sorted(set(options) - _OPTIONS)
        if unknown:
            raise TypeError(f"PGNNFeedforward: unknown setting(s) {', '.join(unknown)}; the "
                            f"options are {', '.join(sorted(_OPTIONS))}")
        settings = PGNNSettings() if settings is None else settings
        if not isinstance(settings, PGNNSettings):
            raise TypeError(f"PGNNFeedforward: settings must be a PGNNSettings, got "
                            f"{type(settings).__name__}")
        self.hidden, self.training, self.lam = hidden, training, lam
        self.settings = replace(settings, **options) if options else settings
        self.features = FeatureMap() if features is None else features
        self._check()

    def __repr__(self) -> str:
        changed = ", ".join(f"{f.name}={getattr(self.settings, f.name)!r}"
                            for f in fields(self.settings)
                            if getattr(self.settings, f.name) != f.default)
        return (f"PGNNFeedforward(hidden={self.hidden!r}, training={self.training!r}, "
                f"lam={self.lam!r}, settings=PGNNSettings({changed}))")

    def _values(self) -> dict:
        """Every setting by its Python name: the model's own and its options."""
        return {"hidden": self.hidden, "training": self.training, "lam": self.lam,
                **{f.name: getattr(self.settings, f.name) for f in fields(self.settings)}}

    def _settings(self) -> dict:
        """The settings as a model file names them (lambda spelled out where a file does), in
        the order of ``CONSTRAINTS``."""
        return storage.file_settings({**self._values(), "hidden": list(self.widths())})

    def widths(self) -> tuple[int, ...]:
        """Widths of the hidden layers."""
        if np.isscalar(self.hidden):
            return (int(self.hidden),)
        return tuple(int(h) for h in self.hidden)

    def lam_matrix_diag(self) -> np.ndarray:
        """Diagonal of Lambda, in the order of ``THETA_NAMES``."""
        diag = {k: float(self.lam) for k in THETA_NAMES}
        diag.update({k: float(v) for k, v in (self.settings.lam_diag or {}).items()})
        return np.array([diag[k] for k in THETA_NAMES])

    def _check(self) -> None:
        """The settings against the one table (``controllers.pgnn_settings.CONSTRAINTS``)."""
        check_settings(self._values())

    def _check_size(self, samples: int, total: int) -> None:
        """Refuse (``UserError``) a fit on fewer samples than :data:`MIN_FIT_SAMPLES`
        (``samples`` of ``total`` after decimation and the validation split), or one whose
        matrices need more memory than the machine has left (:func:`fit_memory_bytes`): both
        before anything is allocated."""
        params = parameter_count(self.widths())
        if samples < MIN_FIT_SAMPLES:
            raise UserError(
                f"pgnn: the fit keeps {samples} samples ({total} after decimation, less the "
                f"validation part); a network fit needs at least {MIN_FIT_SAMPLES} (a smaller "
                f"pgnn.decimation or a longer training run)")
        need = fit_memory_bytes(params, samples, self.settings.optimizer)
        free = available_memory_bytes()
        if free is not None and need > free:
            raise UserError(
                f"pgnn: a fit of {params} parameters on {samples} samples needs about "
                f"{need / 2 ** 30:.3g} GB ({self.settings.optimizer}), more than the "
                f"{free / 2 ** 30:.3g} GB this machine has free; use fewer neurons, a larger "
                f"pgnn.decimation or optimizer: adam")

    # -- the training problem ---------------------------------------------------------------
    def _weights(self, lam_diag: np.ndarray | None = None) -> Weights:
        simultaneous = self.training != "sequential"
        if lam_diag is None:
            lam_diag = self.lam_matrix_diag() if simultaneous else np.zeros(4)
        s = self.settings
        return Weights(lam_diag=lam_diag, pinn=s.pinn_weight if self.training == "pinn" else 0.0,
                       orthogonal=s.orthogonal_weight, weight_decay=s.weight_decay)

    def new_network(self, data: TrainingData, rng: np.random.Generator | None,
                    beta: np.ndarray | None = None) -> PGNNNetwork:
        """A network with the input scalings of ``data`` and randomly drawn hidden layers:
        weights of std ``1/sqrt(fan_in)`` and biases of std 1 keep the neurons spread over their
        range rather than saturated or linear (inputs have unit variance). ``beta``: the hidden
        layers given instead of drawn."""
        net = PGNNNetwork(hidden=self.widths(), activation=self.settings.activation)
        mean = data.phi.mean(axis=0)
        std = data.phi.std(axis=0)
        std[std == 0] = 1.0
        net.mlp.input_mean.copy_(torch.from_numpy(mean))
        net.mlp.input_std.copy_(torch.from_numpy(std))
        if beta is not None:
            net.set_nonlinear(beta)
            return net
        draws = []
        for layer in net.mlp.hidden:
            n_out, n_in = layer.weight.shape
            draws += [rng.standard_normal((n_out, n_in)) / np.sqrt(n_in),
                      rng.standard_normal(n_out)]
        net.set_nonlinear(np.concatenate([d.ravel() for d in draws]))
        return net

    def training_cost(self, data: TrainingData, theta_lip, net: PGNNNetwork,
                      weights: Weights | None = None) -> SeparableCost:
        """The training cost of ``net`` on ``data`` (see :mod:`controllers.pgnn.cost`)."""
        return SeparableCost(net, data.phi, data.target, as_theta(theta_lip),
                             weights or self._weights(), fit_theta=self.training != "sequential")

    def _continues(self) -> bool:
        """Whether a draw also starts from its regularized solution: nothing in the cost pulls
        theta_phy toward theta_LIP, so every regularized solution is feasible and the lambda = 0
        optimum costs no more than it; a descent from there finds such a point, which a descent
        from the draw alone need not (the cost is flat along the physics/network trade-off)."""
        s = self.settings
        return ("continuation" in s.starts and s.continuation_lam > 0
                and s.optimizer == "varpro" and not self._exchanges()
                and self.training == "simultaneous" and s.orthogonal_weight == 0
                and not np.any(self.lam_matrix_diag()))

    def _exchanges(self) -> bool:
        """Whether this fit's draws exchange solutions with the other end of the continuation
        (``starts`` has ``exchange``): a simultaneous varpro fit without the projection penalty
        at lambda = 0 or at a uniform lambda = continuation_lam."""
        s = self.settings
        diag = self.lam_matrix_diag()
        return ("exchange" in s.starts and s.continuation_lam > 0 and s.optimizer == "varpro"
                and self.training == "simultaneous" and s.orthogonal_weight == 0
                and (not np.any(diag) or bool(np.all(diag == float(s.continuation_lam)))))


    # -- fitting ----------------------------------------------------------------------------
    def fit(self, *, y: np.ndarray, u: np.ndarray, ts: float, theta_lip: dict[str, float],
            rng: np.random.Generator | int | None = None) -> PGNNFeedforward:
        """Identify from positions ``y`` (m) and applied inputs ``u`` (N) of a logged run sampled
        at ``ts`` (s); ``theta_lip`` is the LIP fitted with the same ``features``; ``rng`` (a
        ``numpy.random.Generator`` or an integer seed; required) draws the network."""
        rng = generator(rng)
        data = training_data(self.features, y=y, u=u, ts=ts,
                             decimation=self.settings.decimation)
        return self.fit_data(data=data, theta_lip=theta_lip, rng=rng)


    def fit_data(self, *, data: TrainingData, theta_lip: dict[str, float],
                 rng: np.random.Generator | int | None = None,
                 reuse: StartCache | None = None) -> PGNNFeedforward:
        """Identify from prepared :class:`TrainingData` (see :func:`training_data`).

        ``reuse``: the optimizations other fits ran already
        (:class:`controllers.pgnn.starts.StartCache`). A start of this fit with the same key
        (same data, draw, cost weights and optimizer settings:
        :func:`controllers.pgnn.training.start_key`) takes that outcome instead of running
        again, bit for bit what it would compute (the optimizer is deterministic); the starts
        this fit runs are added to it, for the next fits."""
        return training.fit_data(self, data=data, theta_lip=theta_lip, rng=rng, reuse=reuse)

    def fit_pinned(self, *, data: TrainingData, theta_lip: dict[str, float],
                   beta0: np.ndarray, pinned: dict[str, float],
                   atol: float | None = None) -> PGNNFeedforward:
        """Fit with the physical parameters ``pinned`` (name -> value, SI units) held fixed and
        everything else trained (:func:`controllers.pgnn.training.fit_pinned`)."""
        return training.fit_pinned(self, data=data, theta_lip=theta_lip, beta0=beta0,
                                   pinned=pinned, atol=atol)

    def initial_point(self, cost: SeparableCost, theta_lip, rng: np.random.Generator):
        """Starting parameters for the optimizer: ``beta`` (varpro) or ``(x, beta)``."""
        return training.initial_point(self, cost, theta_lip, rng)


    # -- use ----------------------------------------------------------------------------------
    def _check_fitted(self):
        if not hasattr(self, "network_"):
            raise NotFittedError("PGNNFeedforward is not fitted: call fit() before predict(), "
                                 "feedforward() or save()")

    def _rate(self, ts: float | None) -> float:
        """``ts`` checked against the fitted sample time (default: that one)."""
        own = getattr(self, "ts_", None)
        if ts is None:
            if own is None:
                raise UserError("PGNNFeedforward: give ts (this model does not know its rate)")
            return own
        check_ts(own, ts, "PGNNFeedforward (fitted)")
        return float(ts)

    def network(self, phi_f: np.ndarray) -> np.ndarray:
        """The network's force (N) for filtered feature columns ``phi_f`` (N, 4)."""
        self._check_fitted()
        with single_threaded(), torch.no_grad():
            return self.network_.mlp(torch.from_numpy(np.ascontiguousarray(phi_f))).numpy()

    def predict_parts(self, *, y: np.ndarray, ts: float | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Physical part ``theta . filt(T)`` and network part ``f(filt(T))`` (N) at the sample
        instants of ``y`` (m), sampled at ``ts`` (s; default and only allowed rate: the fitted
        ``ts_``). Both parts see the filtered features, as in the fit: the replayed function is the
        fitted one (a drifted theta is cancelled by the network on exactly the columns it saw)."""
        return self.parts(self.filtered_features(y=y, ts=ts))

    def filtered_features(self, *, y: np.ndarray, ts: float | None = None) -> np.ndarray:
        """The filtered feature columns ``phi_f`` (N, 4) = filt([a, v, sign v, y]) that both
        parts see for positions ``y`` (m) sampled at ``ts`` (s; as :meth:`predict_parts`). They
        depend on the features and the rate only, not on the fit: models that share them may
        share this array (``parts(phi_f)``)."""
        self._check_fitted()
        ts = self._rate(ts)
        yf, v, a = self.features.motion(y, ts)
        return self.features.regression_filter(lip_regressors(yf, v, a), ts)

    def parts(self, phi_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Physical part ``theta . phi_f`` and network part ``f(phi_f)`` (N) for filtered
        feature columns ``phi_f`` (:meth:`filtered_features`)."""
        return phi_f @ as_theta(self.theta_), self.network(phi_f)

    def predict(self, *, y: np.ndarray, ts: float | None = None) -> np.ndarray:
        """Force (N) at the sample instants for positions ``y`` (m) sampled at ``ts`` (s; default
        and only allowed rate: the fitted ``ts_``)."""
        physical, net = self.predict_parts(y=y, ts=ts)
        return physical + net

    def feedforward(self, r: np.ndarray, ts: float | None = None) -> np.ndarray:
        """The held input (N) per sample that tracks reference ``r`` (m), as :meth:`predict`."""
        return held_force(self.predict(y=r, ts=ts))

    # -- storage ------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The model file's content (:func:`controllers.pgnn.storage.to_json`)."""
        return storage.to_json(self)

    def save(self, path) -> None:
        """Write ``path.pt`` (the module's state_dict: float64 tensors, input scalings included)
        and ``path.json`` (settings, theta, fit record, history)."""
        storage.save(self, path)

    @classmethod
    def load(cls, path) -> PGNNFeedforward:
        """Read a model written by :meth:`save` (tensors loaded with ``weights_only=True``)."""
        return storage.load(cls, path)
