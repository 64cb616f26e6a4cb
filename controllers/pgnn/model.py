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

import hashlib
import json
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch

from clm_sim.errors import NotFittedError, UserError, check_ts
from clm_sim.features import FeatureMap, held_force, lip_regressors
from clm_sim.modelfile import mapping, number, read_json, regular_file, sample_time
from clm_sim.numerics import available_memory_bytes, single_threaded
from clm_sim.plant import THETA_NAMES
from controllers import optim
from controllers.pgnn.cost import CostTerms, SeparableCost, Weights
from controllers.pgnn.data import TrainingData, training_data
from controllers.pgnn.fit_record import FitRecord, Iterate, Start, ThetaPoint, verdict
from controllers.pgnn.network import PGNNNetwork
from controllers.pgnn.starts import StartCache, StartOutcome
from clm_sim.schema import build
from controllers.pgnn_settings import (CONSTRAINTS, LAMBDA_KEYS, PGNNSettings, check_settings,
                                       checked_widths, parameter_count)

_OPTIONS = frozenset(f.name for f in fields(PGNNSettings))  # a model's options, by name
# A model file's settings keys are the Python names but where it spells lambda out.
_FILE_KEYS = {v: k for k, v in LAMBDA_KEYS.items() if v != "lam"}


def _as_theta(theta) -> np.ndarray:
    """theta as a vector in the order of ``THETA_NAMES`` (from a named dict or a vector)."""
    if isinstance(theta, dict):
        return np.array([float(theta[k]) for k in THETA_NAMES])
    return np.asarray(theta, dtype=np.float64)


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
        values = {**self._values(), "hidden": list(self.widths())}
        return {_FILE_KEYS.get(k, k): values[k] for k in CONSTRAINTS}

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
        return SeparableCost(net, data.phi, data.target, _as_theta(theta_lip),
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

    def initial_point(self, cost: SeparableCost, theta_lip, rng: np.random.Generator):
        """Starting parameters for the optimizer: ``beta`` (varpro) or ``(x, beta)``."""
        beta = cost.net.get_nonlinear()
        if self.settings.optimizer == "varpro":
            return beta
        if self.settings.init == "optimized":
            x = cost._solve(beta)["x"]
        else:
            resid_std = float(np.std(cost.t - cost.lip_pred))
            n = cost.n_hidden
            x = np.concatenate([_as_theta(theta_lip)[:cost.n_theta],
                                rng.standard_normal(n) * resid_std / np.sqrt(n), [0.0]])
        return np.concatenate([x, beta])

    # -- fitting ----------------------------------------------------------------------------
    def fit(self, *, y: np.ndarray, u: np.ndarray, ts: float, theta_lip: dict[str, float],
            rng: np.random.Generator | int | None = None) -> PGNNFeedforward:
        """Identify from positions ``y`` (m) and applied inputs ``u`` (N) of a logged run sampled
        at ``ts`` (s); ``theta_lip`` is the LIP fitted with the same ``features``; ``rng`` (a
        ``numpy.random.Generator`` or an integer seed; required) draws the network."""
        rng = _generator(rng)
        data = training_data(self.features, y=y, u=u, ts=ts,
                             decimation=self.settings.decimation)
        return self.fit_data(data=data, theta_lip=theta_lip, rng=rng)

    def fit_data(self, *, data: TrainingData, theta_lip: dict[str, float],
                 rng: np.random.Generator | int | None = None,
                 reuse: StartCache | None = None) -> PGNNFeedforward:
        """Identify from prepared :class:`TrainingData` (see :func:`training_data`).

        ``reuse``: the optimizations other fits ran already
        (:class:`controllers.pgnn.starts.StartCache`). A start of this fit with the same key
        (same data, draw, cost weights and optimizer settings: :meth:`_start_key`) takes that
        outcome instead of running again, bit for bit what it would compute (the optimizer is
        deterministic); the starts this fit runs are added to it, for the next fits."""
        self._check()
        rng = _generator(rng)
        theta_lip_v = _as_theta(theta_lip)
        opt = self.settings
        fit, held_out = data.split(opt.validation_fraction)
        self._check_size(len(fit.target), len(data.target))
        cache = StartCache() if reuse is None else reuse
        best, starts = None, []

        def optimize(beta0, weights=None, model=self) -> tuple[StartOutcome, bool, str]:
            """The outcome from ``beta0`` of ``model``'s cost (``weights``), whether it was
            taken from the cache, and its key."""
            key = model._start_key(fit, held_out, theta_lip_v, beta0, weights)
            got = cache.take(key)
            if got is not None:
                return got, True, key
            got = model._one_start(fit, held_out, theta_lip_v, rng, beta0, weights)
            cache.keep(key, got)
            return got, False, key

        with single_threaded():
            for _ in range(opt.restarts):
                beta0 = self.new_network(fit, rng).get_nonlinear()
                seen = set()
                for start, (got, reused, key) in self._tries(beta0, optimize):
                    if key is not None and key in seen:  # one optimization reached twice
                        continue
                    seen.add(key)
                    starts.append(Start(start, got.result.cost, got.result.stop,
                                        got.result.iterations, reused))
                    if best is None or got.result.cost < best[1].result.cost:
                        best = (start, got)
        kept_start, best = best
        res = best.result
        moved = theta_movement(best.history, fit)
        stop = verdict(res.stop, res.first_order, opt.ftol,
                       None if self.training == "sequential" else moved, opt.theta_ftol)
        self.network_ = best.net
        self.theta_ = dict(zip(THETA_NAMES, map(float, self.network_.theta.detach().numpy())))
        self.theta_lip_ = dict(zip(THETA_NAMES, map(float, theta_lip_v)))
        self.history_ = best.history
        self.best_iteration_ = int(best.best_iteration)
        self.cost_ = best.terms
        self.n_samples_ = len(fit.target)
        self.ts_ = data.ts
        self.fit_ = FitRecord(
            stop=stop, cost_stop=res.stop, iterations=res.iterations,
            iterations_total=int(sum(s.iterations for s in starts)), theta_moved=moved,
            theta_ftol=opt.theta_ftol, theta_path=theta_path(best.history),
            continuation_lam=(float(opt.continuation_lam)
                              if self._continues() or self._exchanges() else 0.0),
            data_cost=self.cost_.data, reg_cost=self.cost_.regularization,
            grad_norm=res.grad_norm, first_order=res.first_order, ftol=opt.ftol,
            max_iter=opt.max_iter, start=kept_start, starts=tuple(starts),
            start_rtol=opt.start_rtol)
        return self

    def _tries(self, beta0: np.ndarray, optimize) -> list[tuple[str, tuple]]:
        """The optimizations of one draw at this model's cost, as ``(start, (outcome, reused,
        key))`` (see ``PGNNSettings.starts``): from the draw; from the draw's sequential
        solution (``lip``); at lambda = 0 from the solution regularized with
        ``continuation_lam`` (``continuation``); with ``exchange``, the lambda = 0 and lambda =
        ``continuation_lam`` fits start from each other's best until the regularized one
        improves by at most ``start_rtol`` (``EXCHANGE_ROUNDS`` at most), and the lambda = 0 fit
        last starts from the regularized best wherever that is lower than its own: its
        objective then never ends above the regularized solution's (every regularized solution
        is feasible at lambda = 0, and a fit keeps its lowest iterate). ``optimize(beta0,
        weights, model)`` runs or takes one optimization; one optimization may be listed twice
        (two starts that reach the same hidden layers)."""
        s = self.settings
        own = self._weights()
        bases = [beta0]
        if "lip" in s.starts and self.training != "sequential":
            twin = PGNNFeedforward(hidden=self.hidden, training="sequential",
                                   settings=self.settings, features=self.features)
            bases.append(optimize(beta0, None, twin)[0].net.get_nonlinear())
        names = ("draw", "lip")

        def base(weights):
            return [(names[i], optimize(b, weights)) for i, b in enumerate(bases)]

        if self._exchanges():
            zero = replace(own, lam_diag=np.zeros(4))
            reg = replace(own, lam_diag=np.full(4, float(s.continuation_lam)))
            free, pulled = base(zero), base(reg)

            def cost(tries):
                return min(t[1][0].result.cost for t in tries)

            def beta(tries):
                return min(tries, key=lambda t: t[1][0].result.cost)[1][0].net.get_nonlinear()

            free.append(("continuation", optimize(beta(pulled), zero)))
            for _ in range(EXCHANGE_ROUNDS):
                before = cost(pulled)
                pulled.append(("exchange", optimize(beta(free), reg)))
                if cost(pulled) >= before * (1 - s.start_rtol):
                    break
                free.append(("continuation", optimize(beta(pulled), zero)))
            if cost(pulled) < cost(free):
                free.append(("continuation", optimize(beta(pulled), zero)))
            return free if not np.any(own.lam_diag) else pulled
        tries = base(own)
        if self._continues():
            lam_c = np.full(4, float(s.continuation_lam))
            pre = optimize(beta0, self._weights(lam_c))[0]
            tries.append(("continuation", optimize(pre.net.get_nonlinear())))
        return tries

    def fit_pinned(self, *, data: TrainingData, theta_lip: dict[str, float],
                   beta0: np.ndarray, pinned: dict[str, float],
                   atol: float | None = None) -> PGNNFeedforward:
        """Fit with the physical parameters ``pinned`` (name -> value, SI units) held fixed and
        everything else trained (varpro from hidden layers ``beta0``, this model's cost with
        theta_phy's pinned entries removed): one point of the cost's profile over them.
        ``atol`` (N**2): also stop, as ``resolved``, where the Gauss-Newton model predicts an
        absolute decrease of at most this (:func:`controllers.optim.levenberg_marquardt`)."""
        self._check()
        if self.settings.optimizer != "varpro" or self.training == "sequential":
            raise UserError("fit_pinned: needs optimizer varpro and a trained theta_phy")
        unknown = set(pinned) - set(THETA_NAMES)
        if unknown:
            raise UserError(f"fit_pinned: unknown parameter(s) {sorted(unknown)}; expected "
                            f"{', '.join(THETA_NAMES)}")
        theta_lip_v = _as_theta(theta_lip)
        index = {THETA_NAMES.index(k): float(v) for k, v in pinned.items()}
        history = []
        with single_threaded():
            net = self.new_network(data, None, np.asarray(beta0, dtype=np.float64))
            cost = SeparableCost(net, data.phi, data.target, theta_lip_v, self._weights(),
                                 fit_theta=True, pinned=index)

            def record(it, p, value):
                theta, _, _ = cost.linear(p)
                history.append(Iterate.at(it, value, cost.terms(p),
                                          theta=dict(zip(THETA_NAMES, map(float, theta)))))

            res = optim.levenberg_marquardt(cost, net.get_nonlinear(),
                                            max_iter=self.settings.max_iter,
                                            ftol=self.settings.ftol, atol=atol, callback=record)
            theta, w, b = cost.linear(res.p)
            net.set_nonlinear(res.p)
            net.set_linear(theta, w, b)
            terms = cost.terms(res.p)
        self.network_ = net
        self.theta_ = dict(zip(THETA_NAMES, map(float, theta)))
        self.theta_lip_ = dict(zip(THETA_NAMES, map(float, theta_lip_v)))
        self.history_, self.best_iteration_, self.cost_ = history, res.iterations, terms
        self.n_samples_ = len(data.target)
        self.fit_ = FitRecord(
            stop=res.stop, cost_stop=res.stop, iterations=res.iterations,
            data_cost=terms.data, pinned=dict(pinned), reg_cost=terms.regularization,
            first_order=res.first_order, grad_norm=res.grad_norm, ftol=self.settings.ftol,
            max_iter=self.settings.max_iter)
        return self

    def _start_key(self, fit: TrainingData, held_out, theta_lip, beta0: np.ndarray,
                   weights: Weights | None = None) -> str | None:
        """What decides the outcome of one optimization (:meth:`_one_start`), as a digest: the
        data, theta_LIP, the start, the cost's weights and the settings the optimizer reads.
        None where the outcome also depends on the random stream (a random initialization)."""
        if self.settings.optimizer != "varpro":
            return None
        w = weights or self._weights()
        h = hashlib.sha256()
        none = held_out is None
        for part in (fit.phi, fit.target, np.zeros(0) if none else held_out.phi,
                     np.zeros(0) if none else held_out.target, theta_lip, beta0, w.lam_diag):
            h.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
            h.update(b"|")
        s = self.settings
        h.update(repr((w.pinn, w.orthogonal, w.weight_decay, self.training, self.widths(),
                       s.activation, s.max_iter, s.ftol, s.init)).encode())
        return h.hexdigest()

    def _one_start(self, fit: TrainingData, held_out, theta_lip, rng, beta0: np.ndarray,
                   weights: Weights | None = None) -> StartOutcome:
        """One optimization from hidden layers ``beta0`` (of the cost with ``weights``, default
        the model's own)."""
        net = self.new_network(fit, None, beta0)
        cost = self.training_cost(fit, theta_lip, net, weights)
        check = None if held_out is None else self.training_cost(held_out, theta_lip, net,
                                                                 weights)
        varpro = self.settings.optimizer == "varpro"
        p0 = self.initial_point(cost, theta_lip, rng)
        history, best = [], {"score": np.inf}

        def unpack(p):
            """(beta, (theta, w_out, b_out)) of an optimizer vector."""
            if varpro:
                return p, cost.linear(p)
            x, beta = p[:cost.n_linear], p[cost.n_linear:]
            theta = x[:4] if cost.n_theta else theta_lip.copy()
            return beta, (theta, x[cost.n_theta:-1], float(x[-1]))

        def terms(p) -> CostTerms:
            return cost.terms(p) if varpro else cost.full_terms(p)

        def record(it, p, value):
            beta, (theta, w, b) = unpack(p)
            validation = None
            if check is not None:
                net.set_nonlinear(beta)
                net.set_linear(theta, w, b)
                pred = _predict(net, held_out)
                validation = float(np.mean((held_out.target - pred) ** 2))
            history.append(Iterate.at(it, value, terms(p),
                                      theta=dict(zip(THETA_NAMES, map(float, theta))),
                                      validation=validation))
            score = value if validation is None else validation
            if score < best["score"]:
                best.update(score=score, p=p.copy(), iteration=it)

        fun = cost if varpro else cost.full
        s = self.settings
        if s.optimizer == "adam":
            result = optim.adam(fun, p0, max_iter=s.max_iter, lr=s.adam_lr, callback=record)
        else:
            result = optim.levenberg_marquardt(fun, p0, max_iter=s.max_iter, ftol=s.ftol,
                                               callback=record)
        beta, (theta, w, b) = unpack(best["p"])
        net.set_nonlinear(beta)
        net.set_linear(theta, w, b)
        return StartOutcome(net=net, result=result, history=history,
                            best_iteration=best["iteration"], terms=terms(best["p"]))

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
        return phi_f @ _as_theta(self.theta_), self.network(phi_f)

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
        self._check_fitted()
        return {"kind": "pgnn", "ts": getattr(self, "ts_", None), "settings": self._settings(),
                "features": {k: getattr(self.features, k) for k in (
                    "regression_lowpass_hz", "position_lowpass_hz", "lowpass_order",
                    "edge_samples")},
                "theta": self.theta_, "theta_lip": self.theta_lip_,
                "cost": None if self.cost_ is None else self.cost_.to_json(),
                "fit": self.fit_.to_json(), "best_iteration": self.best_iteration_,
                "n_samples": self.n_samples_, "history": (None if self.history_ is None
                                                        else [h.to_json() for h in self.history_])}

    def save(self, path) -> None:
        """Write ``path.pt`` (the module's state_dict: float64 tensors, input scalings included)
        and ``path.json`` (settings, theta, fit record, history)."""
        self._check_fitted()
        path = Path(path)
        torch.save(self.network_.state_dict(), path.with_suffix(".pt"))
        path.with_suffix(".json").write_text(json.dumps(self.to_json(), indent=1))

    @classmethod
    def load(cls, path) -> PGNNFeedforward:
        """Read a model written by :meth:`save` (tensors loaded with ``weights_only=True``)."""
        path = Path(path)
        info = read_json(path.with_suffix(".json"), "PGNN model")
        pt = regular_file(path.with_suffix(".pt"), "PGNN weights file")
        try:
            python = {v: k for k, v in _FILE_KEYS.items()}
            settings = {python.get(k, k): v for k, v in
                        mapping(info.get("settings"), "settings").items()
                        if python.get(k, k) in CONSTRAINTS}
            settings["hidden"] = checked_widths(settings.get("hidden"), "settings.hidden")
            check_settings(settings)
            features = build(FeatureMap, mapping(info.get("features"), "features"), "features")
            theta = mapping(info.get("theta"), "theta")
            theta = {k: number(theta.get(k), f"theta.{k}") for k in THETA_NAMES}
            ts = sample_time(info.get("ts"))
            fit = FitRecord.from_json(info.get("fit"))
            cost = info.get("cost")
            cost = None if cost is None else CostTerms.from_json(cost)
            history = info.get("history")
            if history is not None:
                if not isinstance(history, list):
                    raise UserError("history: expected a list")
                history = [Iterate.from_json(e) for e in history]
            # The weights' size follows from the widths: a larger file is not this model's.
            weights = parameter_count(settings["hidden"]) + 8  # + the input scalings
            if pt.stat().st_size > 16 * weights + 2 ** 20:
                raise UserError(f"{pt.name}: {pt.stat().st_size} bytes, far more than the "
                                f"{weights} weights of hidden {list(settings['hidden'])}")
        except UserError as exc:
            raise UserError(f"{path}: cannot read PGNN model ({exc})") from None
        try:
            state = torch.load(pt, weights_only=True)
            model = cls(**settings, features=features)
            net = PGNNNetwork(hidden=model.widths(), activation=model.settings.activation)
            _check_shapes(state, net, pt, f"{path.with_suffix('.json').name}'s hidden "
                                          f"{list(model.widths())}")
            net.load_state_dict(state)
        except UserError:
            raise
        except Exception as exc:  # a truncated or foreign .pt, weights of another shape
            first = (str(exc).splitlines() or [type(exc).__name__])[0][:200]
            raise UserError(f"{path}: cannot read PGNN model ({first})") from None
        for name, tensor in net.state_dict().items():
            if not bool(torch.isfinite(tensor).all()):
                raise UserError(f"{pt}: {name} holds NaN or inf; not a usable model")
        if not bool((net.mlp.input_std > 0).all()):
            raise UserError(f"{pt}: mlp.input_std must be positive (a scaling), got "
                            f"{net.mlp.input_std.tolist()}")
        model.network_ = net
        model.theta_ = theta
        model.theta_lip_ = info.get("theta_lip")
        model.history_ = history
        model.best_iteration_ = info.get("best_iteration")
        model.cost_ = cost
        model.fit_ = fit
        model.n_samples_ = info.get("n_samples")
        model.ts_ = ts  # older files: unknown
        return model


def _check_shapes(state, net: torch.nn.Module, pt: Path, widths: str) -> None:
    """Refuse in one line a ``.pt`` whose tensors are not those of the network its ``.json``
    describes (``widths``): the first tensor missing, of another shape, or extra, by name,
    expected against found (``load_state_dict`` says it in a paragraph)."""
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor)
                                              for v in state.values()):
        return  # load_state_dict says what it is
    for name, tensor in net.state_dict().items():
        shape = tuple(tensor.shape)
        if name not in state:
            raise UserError(f"{pt}: no tensor {name}; {widths} expects one of shape "
                            f"{shape}")
        if tuple(state[name].shape) != shape:
            raise UserError(f"{pt}: {name} has shape {tuple(state[name].shape)}; "
                            f"{widths} expects {shape}")
    extra = [k for k in state if k not in net.state_dict()]
    if extra:
        raise UserError(f"{pt}: {extra[0]} is no tensor of {widths}")


def _generator(rng) -> np.random.Generator:
    """The network's random draw from ``rng``: a Generator, or an integer seed. There is no
    default seed on purpose: fits that forget it would all share one draw and look like
    independent seeds."""
    if rng is None:
        raise UserError("PGNNFeedforward.fit: give rng=, a numpy.random.Generator or an integer "
                        "seed (it draws the network's hidden layers; there is no default seed)")
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer, np.random.SeedSequence)) and not isinstance(rng, bool):
        return np.random.default_rng(rng)
    raise UserError(f"PGNNFeedforward.fit: rng must be a numpy.random.Generator or an integer "
                    f"seed, got {type(rng).__name__}")


EXCHANGE_ROUNDS = 3  # at most: each round is two optimizations of a draw

CHECKPOINTS = (0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000)


def theta_path(history: list[Iterate]) -> tuple[ThetaPoint, ...]:
    """theta_phy (named) at the iterations ``CHECKPOINTS`` that the fit reached, and at its last
    accepted iteration: how theta moves as the optimizer goes on."""
    by_it = {e.iteration: e for e in history}
    its = [i for i in CHECKPOINTS if i in by_it] + [history[-1].iteration]
    return tuple(ThetaPoint(i, by_it[i].data, dict(by_it[i].theta))
                 for i in dict.fromkeys(its))


def theta_movement(history: list[Iterate], data: TrainingData) -> float:
    """How far theta_phy still travels at the end of a fit: the rms of ``T . delta theta`` over
    ``data`` (delta theta: last accepted iterate minus the one a quarter of the iterations
    earlier), as a fraction of the rms training force. 0 for a fit without iterations."""
    last = history[-1]
    m = max(1, int(np.ceil(last.iteration / 4)))
    earlier = next((e for e in history if e.iteration >= last.iteration - m), history[0])
    d = _as_theta(last.theta) - _as_theta(earlier.theta)
    return float(np.sqrt(np.mean((data.phi @ d) ** 2)) / np.sqrt(np.mean(data.target ** 2)))


def _predict(net: PGNNNetwork, data: TrainingData) -> np.ndarray:
    with torch.no_grad():
        z = torch.from_numpy(np.ascontiguousarray(data.phi))
        return net(z, z).numpy()
