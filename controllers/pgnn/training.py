"""How a PGNN is fitted (:class:`controllers.pgnn.model.PGNNFeedforward` delegates here): the
starts of each draw and the one kept (:func:`fit_data`), one optimization from given hidden layers
(:func:`one_start`) and the key under which later fits reuse it (:func:`start_key`), the fit with
physical parameters held (:func:`fit_pinned`), and what a fit records of its path
(:func:`theta_path`, :func:`theta_movement`). Each function takes the model whose settings it
fits as ``model`` and sets its learned attributes."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np
import torch

from clm_sim.errors import UserError
from clm_sim.numerics import single_threaded
from clm_sim.plant import THETA_NAMES
from controllers import optim
from controllers.pgnn.cost import CostTerms, SeparableCost, Weights
from controllers.pgnn.data import TrainingData
from controllers.pgnn.fit_record import FitRecord, Iterate, Start, ThetaPoint, verdict
from controllers.pgnn.network import PGNNNetwork
from controllers.pgnn.starts import StartCache, StartOutcome

EXCHANGE_ROUNDS = 3  # at most: each round is two optimizations of a draw

CHECKPOINTS = (0, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000)


def as_theta(theta) -> np.ndarray:
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
    theta_lip = as_theta(theta_lip) if isinstance(theta_lip, dict) else np.asarray(theta_lip)
    resid = data.target - data.phi @ theta_lip
    cols = np.hstack([data.phi, h, np.ones((len(h), 1))])
    g = cols.T @ resid / len(resid)
    ref = np.linalg.norm(cols, axis=0) / np.sqrt(len(resid)) * np.sqrt(np.mean(resid**2))
    return bool(np.any(np.abs(g) > rtol * np.maximum(ref, 1e-300)))


def generator(rng) -> np.random.Generator:
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


def fit_data(model, *, data: TrainingData, theta_lip: dict[str, float],
             rng: np.random.Generator | int | None = None,
             reuse: StartCache | None = None):
    """Fit ``model`` on prepared :class:`TrainingData` and return it
    (:meth:`controllers.pgnn.model.PGNNFeedforward.fit_data`): ``restarts`` draws, each
    optimized from the starts of :func:`tries`, the lowest cost kept; an optimization whose
    :func:`start_key` is in ``reuse`` is taken from it, and those run are added to it."""
    model._check()
    rng = generator(rng)
    theta_lip_v = as_theta(theta_lip)
    opt = model.settings
    fit, held_out = data.split(opt.validation_fraction)
    model._check_size(len(fit.target), len(data.target))
    cache = StartCache() if reuse is None else reuse
    best, starts = None, []
    # The LM iterations of every optimization this fit ran, and of those it took from the
    # cache (each once): listed starts or not (a sequential twin, the regularized side of
    # an exchange), so that a table's sum is what its command ran.
    counted = set()
    ran = took = 0

    def optimize(beta0, weights=None, model=model) -> tuple[StartOutcome, bool, str]:
        """The outcome from ``beta0`` of ``model``'s cost (``weights``), whether it was
        taken from the cache, and its key."""
        nonlocal ran, took
        key = start_key(model, fit, held_out, theta_lip_v, beta0, weights)
        got = cache.take(key)
        if got is not None:
            if key not in counted:
                counted.add(key)
                took += got.result.iterations
            return got, True, key
        got = one_start(model, fit, held_out, theta_lip_v, rng, beta0, weights)
        cache.keep(key, got)
        counted.add(key)
        ran += got.result.iterations
        return got, False, key

    with single_threaded():
        for _ in range(opt.restarts):
            beta0 = model.new_network(fit, rng).get_nonlinear()
            seen = set()
            for start, (got, reused, key) in tries(model, beta0, optimize):
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
                   None if model.training == "sequential" else moved, opt.theta_ftol)
    model.network_ = best.net
    model.theta_ = dict(zip(THETA_NAMES, map(float, model.network_.theta.detach().numpy())))
    model.theta_lip_ = dict(zip(THETA_NAMES, map(float, theta_lip_v)))
    model.history_ = best.history
    model.best_iteration_ = int(best.best_iteration)
    model.cost_ = best.terms
    model.n_samples_ = len(fit.target)
    model.ts_ = data.ts
    model.fit_ = FitRecord(
        stop=stop, cost_stop=res.stop, iterations=res.iterations,
        iterations_total=int(sum(s.iterations for s in starts)),
        iterations_run=ran, iterations_reused=took, theta_moved=moved,
        theta_ftol=opt.theta_ftol, theta_path=theta_path(best.history),
        continuation_lam=(float(opt.continuation_lam)
                          if model._continues() or model._exchanges() else 0.0),
        data_cost=model.cost_.data, reg_cost=model.cost_.regularization,
        grad_norm=res.grad_norm, first_order=res.first_order, ftol=opt.ftol,
        max_iter=opt.max_iter, start=kept_start, starts=tuple(starts),
        start_rtol=opt.start_rtol)
    return model


def tries(model, beta0: np.ndarray, optimize) -> list[tuple[str, tuple]]:
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
    s = model.settings
    own = model._weights()
    bases = [beta0]
    if "lip" in s.starts and model.training != "sequential":
        twin = type(model)(hidden=model.hidden, training="sequential",
                               settings=model.settings, features=model.features)
        bases.append(optimize(beta0, None, twin)[0].net.get_nonlinear())
    names = ("draw", "lip")

    def base(weights):
        return [(names[i], optimize(b, weights)) for i, b in enumerate(bases)]

    if model._exchanges():
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
    if model._continues():
        lam_c = np.full(4, float(s.continuation_lam))
        pre = optimize(beta0, model._weights(lam_c))[0]
        tries.append(("continuation", optimize(pre.net.get_nonlinear())))
    return tries


def fit_pinned(model, *, data: TrainingData, theta_lip: dict[str, float],
               beta0: np.ndarray, pinned: dict[str, float],
               atol: float | None = None):
    """Fit with the physical parameters ``pinned`` (name -> value, SI units) held fixed and
    everything else trained (varpro from hidden layers ``beta0``, this model's cost with
    theta_phy's pinned entries removed): one point of the cost's profile over them.
    ``atol`` (N**2): also stop, as ``resolved``, where the Gauss-Newton model predicts an
    absolute decrease of at most this (:func:`controllers.optim.levenberg_marquardt`)."""
    model._check()
    if model.settings.optimizer != "varpro" or model.training == "sequential":
        raise UserError("fit_pinned: needs optimizer varpro and a trained theta_phy")
    unknown = set(pinned) - set(THETA_NAMES)
    if unknown:
        raise UserError(f"fit_pinned: unknown parameter(s) {sorted(unknown)}; expected "
                        f"{', '.join(THETA_NAMES)}")
    theta_lip_v = as_theta(theta_lip)
    index = {THETA_NAMES.index(k): float(v) for k, v in pinned.items()}
    history = []
    with single_threaded():
        net = model.new_network(data, None, np.asarray(beta0, dtype=np.float64))
        cost = SeparableCost(net, data.phi, data.target, theta_lip_v, model._weights(),
                             fit_theta=True, pinned=index)

        def record(it, p, value):
            theta, _, _ = cost.linear(p)
            history.append(Iterate.at(it, value, cost.terms(p),
                                      theta=dict(zip(THETA_NAMES, map(float, theta)))))

        res = optim.levenberg_marquardt(cost, net.get_nonlinear(),
                                        max_iter=model.settings.max_iter,
                                        ftol=model.settings.ftol, atol=atol, callback=record)
        theta, w, b = cost.linear(res.p)
        net.set_nonlinear(res.p)
        net.set_linear(theta, w, b)
        terms = cost.terms(res.p)
    model.network_ = net
    model.theta_ = dict(zip(THETA_NAMES, map(float, theta)))
    model.theta_lip_ = dict(zip(THETA_NAMES, map(float, theta_lip_v)))
    model.history_, model.best_iteration_, model.cost_ = history, res.iterations, terms
    model.n_samples_ = len(data.target)
    model.fit_ = FitRecord(
        stop=res.stop, cost_stop=res.stop, iterations=res.iterations,
        data_cost=terms.data, pinned=dict(pinned), reg_cost=terms.regularization,
        first_order=res.first_order, grad_norm=res.grad_norm, ftol=model.settings.ftol,
        max_iter=model.settings.max_iter)
    return model


def start_key(model, fit: TrainingData, held_out, theta_lip, beta0: np.ndarray,
               weights: Weights | None = None) -> str | None:
    """What decides the outcome of one optimization (:func:`one_start`), as a digest: the
    data, theta_LIP, the start, the cost's weights and the settings the optimizer reads.
    None where the outcome also depends on the random stream (a random initialization)."""
    if model.settings.optimizer != "varpro":
        return None
    w = weights or model._weights()
    h = hashlib.sha256()
    none = held_out is None
    for part in (fit.phi, fit.target, np.zeros(0) if none else held_out.phi,
                 np.zeros(0) if none else held_out.target, theta_lip, beta0, w.lam_diag):
        h.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
        h.update(b"|")
    s = model.settings
    h.update(repr((w.pinn, w.orthogonal, w.weight_decay, model.training, model.widths(),
                   s.activation, s.max_iter, s.ftol, s.init)).encode())
    return h.hexdigest()


def one_start(model, fit: TrainingData, held_out, theta_lip, rng, beta0: np.ndarray,
               weights: Weights | None = None) -> StartOutcome:
    """One optimization from hidden layers ``beta0`` (of the cost with ``weights``, default
    the model's own)."""
    net = model.new_network(fit, None, beta0)
    cost = model.training_cost(fit, theta_lip, net, weights)
    check = None if held_out is None else model.training_cost(held_out, theta_lip, net,
                                                             weights)
    varpro = model.settings.optimizer == "varpro"
    p0 = initial_point(model, cost, theta_lip, rng)
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
            pred = predict_on(net, held_out)
            validation = float(np.mean((held_out.target - pred) ** 2))
        history.append(Iterate.at(it, value, terms(p),
                                  theta=dict(zip(THETA_NAMES, map(float, theta))),
                                  validation=validation))
        score = value if validation is None else validation
        if score < best["score"]:
            best.update(score=score, p=p.copy(), iteration=it)

    fun = cost if varpro else cost.full
    s = model.settings
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


def initial_point(model, cost: SeparableCost, theta_lip, rng: np.random.Generator):
    """Starting parameters for the optimizer: ``beta`` (varpro) or ``(x, beta)``."""
    beta = cost.net.get_nonlinear()
    if model.settings.optimizer == "varpro":
        return beta
    if model.settings.init == "optimized":
        x = cost._solve(beta)["x"]
    else:
        resid_std = float(np.std(cost.t - cost.lip_pred))
        n = cost.n_hidden
        x = np.concatenate([as_theta(theta_lip)[:cost.n_theta],
                            rng.standard_normal(n) * resid_std / np.sqrt(n), [0.0]])
    return np.concatenate([x, beta])


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
    d = as_theta(last.theta) - as_theta(earlier.theta)
    return float(np.sqrt(np.mean((data.phi @ d) ** 2)) / np.sqrt(np.mean(data.target ** 2)))


def predict_on(net: PGNNNetwork, data: TrainingData) -> np.ndarray:
    with torch.no_grad():
        z = torch.from_numpy(np.ascontiguousarray(data.phi))
        return net(z, z).numpy()
