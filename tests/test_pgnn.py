"""PGNN feedforward: the lemma's inequality, regularization limits, recovery, derivatives,
convergence records, the successors' regularizers, determinism, storage."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from clm_sim.errors import NotFittedError
from clm_sim.features import FeatureMap
from clm_sim.plant import THETA_NAMES
from clm_sim.reference import PointToPoint
from controllers import optim
from controllers.pgnn import PGNNFeedforward, TrainingData, lemma_condition

THETA_TRUE = np.array([18.8, 172.0, 7.21, 20.0])


def synthetic(n: int, seed: int, parasitic: float = 3.0, noise: float = 0.2) -> TrainingData:
    """Motion-like columns and a force that hides a learnable parasitic force of position
    (a cogging-like sine, amplitude ``parasitic`` N) plus white noise (N)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, n)
    y = 0.1 * np.sin(2 * np.pi * 0.5 * t) + 0.002 * rng.standard_normal(n)
    v = 0.1 * np.pi * np.cos(2 * np.pi * 0.5 * t) + 0.02 * rng.standard_normal(n)
    a = -0.1 * np.pi**2 * np.sin(2 * np.pi * 0.5 * t) + 2.0 * rng.standard_normal(n)
    phi = np.column_stack([a, v, np.sign(v), y])
    target = phi @ THETA_TRUE + parasitic * np.sin(2 * np.pi * y / 0.05) \
        + noise * rng.standard_normal(n)
    return TrainingData(phi=phi, target=target)


def lip_theta(data: TrainingData) -> np.ndarray:
    coef, *_ = np.linalg.lstsq(data.phi, data.target, rcond=None)
    return coef


def as_dict(theta) -> dict[str, float]:
    return dict(zip(THETA_NAMES, map(float, theta)))


def hidden_outputs(model, data, theta, seed):
    """The first start's hidden-layer outputs of a fit of ``model`` with rng seed ``seed``."""
    net = model.new_network(data, np.random.default_rng(seed))
    return net.hidden_outputs(net.get_nonlinear(), torch.from_numpy(data.phi))


@pytest.fixture(scope="session")
def data():
    return synthetic(3000, seed=0)


@pytest.mark.parametrize("training,lam", [("simultaneous", 0.0), ("simultaneous", 0.01),
                                          ("simultaneous", 10.0), ("sequential", 0.0),
                                          ("pinn", 0.0)])
def test_optimized_init_never_costs_more_than_lip(training, lam):
    """Lemma: the LIP (theta_LIP, zero output layer) is a candidate of the initial least squares,
    so the initial cost is <= the LIP cost, strictly when the lemma's condition holds."""
    for draw in range(40):
        data = synthetic(400, seed=100 + draw, parasitic=float(draw % 4))
        theta = lip_theta(data)
        lip_cost = float(np.mean((data.target - data.phi @ theta) ** 2))
        model = PGNNFeedforward(hidden=1 + draw % 12, training=training, lam=lam, max_iter=1)
        model.fit_data(data=data, theta_lip=as_dict(theta), rng=np.random.default_rng(draw))
        init = model.history_[0].cost
        # 1e-9 relative: round-off of two least-squares solutions of the same problem.
        assert init <= lip_cost * (1 + 1e-9)
        h = hidden_outputs(model, data, theta, draw)
        if lemma_condition(data, h, theta):
            assert init < lip_cost * (1 - 1e-6)


def test_init_equals_lip_cost_when_residual_is_orthogonal(data):
    """The other side of the lemma: a LIP residual orthogonal to the hidden outputs and the
    constant leaves nothing for the initialization to gain."""
    theta = lip_theta(data)
    model = PGNNFeedforward(hidden=6, lam=0.01, max_iter=1)
    h = hidden_outputs(model, data, theta, seed=3)
    basis = np.hstack([data.phi, h, np.ones((len(h), 1))])
    noise = np.random.default_rng(9).standard_normal(len(h))
    noise -= basis @ np.linalg.lstsq(basis, noise, rcond=None)[0]
    flat = TrainingData(phi=data.phi, target=data.phi @ theta + noise)
    assert not lemma_condition(flat, h, theta)
    model.fit_data(data=flat, theta_lip=as_dict(theta), rng=np.random.default_rng(3))
    lip_cost = float(np.mean(noise**2))
    assert model.history_[0].cost == pytest.approx(lip_cost, rel=1e-9)  # round-off only


def test_very_large_lambda_pins_theta_to_lip(data):
    theta = lip_theta(data) * 1.05  # any theta_LIP: the penalty must win over the data
    model = PGNNFeedforward(hidden=8, lam=1e10, max_iter=30)
    model.fit_data(data=data, theta_lip=as_dict(theta), rng=np.random.default_rng(0))
    got = np.array([model.theta_[k] for k in THETA_NAMES])
    # 1e-6 relative: the data gradient (~1e2) over the penalty curvature (1e10) times theta.
    np.testing.assert_allclose(got, theta, rtol=1e-6)


@pytest.mark.parametrize("name", THETA_NAMES)
def test_diagonal_lambda_pins_only_its_parameter(data, name):
    theta = lip_theta(data) * 1.05
    model = PGNNFeedforward(hidden=8, lam=0.0, lam_diag={name: 1e10}, max_iter=30)
    model.fit_data(data=data, theta_lip=as_dict(theta), rng=np.random.default_rng(0))
    i = THETA_NAMES.index(name)
    assert model.theta_[name] == pytest.approx(theta[i], rel=1e-6)  # as the scalar case
    # The unpinned ones follow the data, away from the 5 % offset (the data's LS is theta/1.05).
    others = [k for k in THETA_NAMES if k != name and k != "stiffness"]
    assert any(abs(model.theta_[k] / theta[THETA_NAMES.index(k)] - 1) > 0.01 for k in others)


def test_regularized_pgnn_learns_parasitic_force_and_keeps_theta(data):
    """A sine of position the LIP cannot express: the regularized PGNN keeps theta_LIP (which is
    near the truth here, the sine being nearly orthogonal to the LIP columns) and fits it."""
    theta = lip_theta(data)
    lip_cost = float(np.mean((data.target - data.phi @ theta) ** 2))
    # Three draws, the lowest training cost kept: from one draw a fit can end in a local
    # minimum that misses part of the sine (measured: 1 of 4 draws at 0.45 N**2).
    model = PGNNFeedforward(hidden=16, lam=0.01, max_iter=100, restarts=3)
    model.fit_data(data=data, theta_lip=as_dict(theta), rng=np.random.default_rng(1))
    got = np.array([model.theta_[k] for k in THETA_NAMES])
    # 1 %: the penalty 0.01*dtheta**2 must stay below the data-term gain (a few N**2).
    np.testing.assert_allclose(got[:3], theta[:3], rtol=0.01)
    # The sine (3 N amplitude, 4.5 N**2 power) is learnable; noise floor 0.04 N**2.
    assert model.cost_.data < 0.1 * lip_cost
    # theta_LIP itself is close to the truth: the sine hides no bias in mass, viscous, coulomb.
    np.testing.assert_allclose(theta[:3], THETA_TRUE[:3], rtol=0.05)
    costs = [h.cost for h in model.history_]
    assert all(b <= a for a, b in itertools.pairwise(costs))  # LM accepts only decreases


@pytest.mark.parametrize("training", ["simultaneous", "sequential", "pinn"])
def test_same_seed_same_bits(data, training):
    theta = as_dict(lip_theta(data))
    fits = [PGNNFeedforward(hidden=5, training=training, max_iter=5).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(s)) for s in (7, 7, 8)]
    states = [f.network_.state_dict() for f in fits]
    for k in states[0]:
        assert torch.equal(states[0][k], states[1][k]), k
    assert not torch.equal(states[0]["mlp.hidden.0.weight"], states[2]["mlp.hidden.0.weight"])


def test_sequential_keeps_theta_lip(data):
    theta = as_dict(lip_theta(data))
    model = PGNNFeedforward(hidden=5, training="sequential", max_iter=10).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(0))
    assert model.theta_ == theta


def _central_differences(fun, p, step=1e-6):
    cols = []
    for k in range(len(p)):
        dp = np.zeros_like(p)
        dp[k] = step * max(1.0, abs(p[k]))
        cols.append((fun(p + dp) - fun(p - dp)) / (2 * dp[k]))
    return np.column_stack(cols)


@pytest.mark.parametrize("training,lam,extra,hidden", [
    ("simultaneous", 0.3, {}, 4), ("pinn", 0.0, {}, 4), ("sequential", 0.0, {}, 4),
    ("simultaneous", 0.0, {"orthogonal_weight": 2.0, "weight_decay": 1e-3}, 4),
    ("simultaneous", 0.01, {"activation": "softplus"}, (3, 2))])
def test_jacobian_matches_finite_differences(data, training, lam, extra, hidden):
    """The torch.func Jacobian of the full problem, and the exact gradient of the reduced
    (variable projection) cost, against central differences written independently."""
    small = TrainingData(data.phi[:400], data.target[:400])
    theta = lip_theta(small)
    model = PGNNFeedforward(hidden=hidden, training=training, lam=lam, optimizer="lm", **extra)
    net = model.new_network(small, np.random.default_rng(0))
    cost = model.training_cost(small, theta, net)
    p = model.initial_point(cost, theta, np.random.default_rng(1))
    p = p + 0.05 * np.random.default_rng(2).standard_normal(len(p))  # off the LS solution
    _, J = cost.full(p, True)
    fd = _central_differences(lambda q: cost.full(q, False), p)
    # Central differences: truncation ~ step**2 * third derivative, round-off ~ 1e-16/1e-6.
    np.testing.assert_allclose(J, fd, atol=1e-6 * np.abs(J).max())
    beta = p[cost.n_linear:]
    r, Jr = cost(beta, True)
    grad_fd = _central_differences(lambda b: np.atleast_1d(cost(b, False) @ cost(b, False)),
                                   beta)[0]
    # Kaufman's Jacobian is approximate, but J'r is the exact gradient of the reduced cost.
    np.testing.assert_allclose(2 * Jr.T @ r, grad_fd, atol=1e-6 * np.abs(grad_fd).max())


def _kaufman_reference(cost, beta, weight_decay=0.0):
    """The reduced problem's residual and Kaufman Jacobian at ``beta`` formed densely, written
    apart from the product: the range of the unscaled linear system by scipy.linalg.orth (an
    SVD), the projection applied to the whole Jacobian, the decay rows stacked below."""
    import scipy.linalg

    sol = cost._solve(beta)
    B = cost._beta_rows(beta, sol["x"][cost.n_theta:cost.n_theta + cost.n_hidden],
                        sol["layers"])
    Q = scipy.linalg.orth(cost._A.copy(), rcond=1e-12)
    J = B - Q @ (Q.T @ B)
    if weight_decay > 0:
        rows = np.zeros((int(cost.decayed.sum()), len(beta)))
        rows[np.arange(len(rows)), np.flatnonzero(cost.decayed)] = np.sqrt(weight_decay)
        J = np.vstack([J, rows])
    return cost(beta, False), J, B


@pytest.mark.parametrize("linear_scale,dead,lam,weight_decay,kind,kappa", [
    (None, False, 0.0, 0.0, "qr", 1e3),     # a drawn network: well conditioned
    (1e-2, False, 0.0, 0.0, "qr", 1e5),     # a nearly linear neuron: columns cancel
    (3e-3, False, 0.0, 0.0, "qr", 1e6),     # nearly rank-deficient, still Cholesky QR
    (1e-3, False, 0.0, 0.0, "svd", 1e7),    # beyond it: the SVD
    (1e-4, False, 0.0, 0.0, "svd", 1e9),    # the projected columns at the rounding level
    (None, True, 0.0, 0.0, "svd", np.inf),  # a constant neuron: exactly rank-deficient
    (1e-2, False, 0.01, 1e-3, "qr", 1e5)])
def test_the_damped_step_is_the_dense_jacobian_solve(
        data, linear_scale, dead, lam, weight_decay, kind, kappa):
    """The optimizer's damped step (``J'J`` and ``J'r`` of the Kaufman Jacobian, the linear
    system factorized by Cholesky QR or the SVD, the projection in place) against the damped
    least-squares problem on the Kaufman Jacobian formed apart (``_kaufman_reference``) and
    solved by an orthogonal factorization (``numpy.linalg.lstsq``, which never forms
    ``J'J``), at lambda = 0 down to a nearly and an exactly rank-deficient linear system."""
    small = TrainingData(data.phi[:600], data.target[:600])
    model = PGNNFeedforward(hidden=4, lam=lam, weight_decay=weight_decay)
    net = model.new_network(small, np.random.default_rng(3))
    beta = net.get_nonlinear()
    if linear_scale is not None:  # neuron 0 nearly linear: its output nearly a physical column
        beta[:4] *= linear_scale
        beta[16] = 0.0
    if dead:  # neuron 1's output the constant 1 (tanh(50) rounds to 1)
        beta[4:8] = 0.0
        beta[17] = 50.0
    net.set_nonlinear(beta)
    cost = model.training_cost(small, lip_theta(small), net)
    r, J_product = cost(beta, True)
    N, g = J_product.T @ J_product, J_product.T @ r
    span = cost._solve(beta)["range"]
    assert span.kind == kind
    As = cost._A / np.linalg.norm(cost._A, axis=0)
    assert np.linalg.cond(As) < kappa  # the case is as conditioned as its label says
    r_ref, J, B = _kaufman_reference(cost, beta, weight_decay)
    np.testing.assert_array_equal(r, r_ref)
    mu = 1e-3  # the optimizer's first damping (Marquardt-scaled)
    d = np.sqrt(np.maximum(np.diag(N), 0.0))
    d[d == 0] = 1.0  # a dead neuron's columns are exactly zero on both sides
    step = -scipy_linalg().cho_solve(scipy_linalg().cho_factor(
        N / np.outer(d, d) + mu * np.eye(len(g))), g / d) / d
    d_ref = np.sqrt(np.einsum("ij,ij->j", J, J))
    d_ref[d_ref == 0] = 1.0
    aug = np.vstack([J / d_ref, np.sqrt(mu) * np.eye(len(g))])
    want = -np.linalg.lstsq(aug, np.concatenate([r, np.zeros(len(g))]), rcond=None)[0] / d_ref
    bb = np.einsum("ij,ij->j", B, B)
    live = np.einsum("ij,ij->j", J[:len(B)], J[:len(B)]) > 1e-12 * bb
    if not live[bb > 0].all():
        # Neuron 0's projected columns are at the rounding level of B's (1e-16 of their
        # norm): their step is rounding in both, so the step is compared off them, and the
        # normal matrix in absolute terms.
        assert linear_scale == 1e-4
        np.testing.assert_allclose(N, J.T @ J, atol=1e-14 * bb.max())
        np.testing.assert_allclose(g[live], (J.T @ r)[live], rtol=1e-8,
                                   atol=1e-12 * np.abs(g).max())
        return
    # Observed within 3e-10 (relative); 1e-8 bounds the rounding of a damped system whose
    # scaled condition is at most 1/mu, built on columns known to 1e-13 of their norm or
    # better. An arithmetic that squares kappa loses every digit at kappa = 1e7.
    assert np.linalg.norm(step - want) <= 1e-8 * np.linalg.norm(want)
    assert optim.first_order_from_normal(N, g, float(r @ r)) == pytest.approx(
        optim.first_order_measure(r, J), rel=1e-5)


def scipy_linalg():
    import scipy.linalg

    return scipy.linalg


@pytest.mark.parametrize("hidden,activation", [
    (5, "tanh"), ((4, 3), "tanh"), (4, "sigmoid"), ((3, 3), "softplus"), (4, "silu"),
    ((4, 2, 3), "gelu"), (4, "relu")])
def test_closed_form_network_jacobian_is_torch_func(data, hidden, activation):
    """The training's backpropagation in closed form against torch.func's per-sample reverse
    mode (the framework's derivative, an independent computation), every depth and activation."""
    from torch.func import functional_call, jacrev, vmap

    small = TrainingData(data.phi[:300], data.target[:300])
    model = PGNNFeedforward(hidden=hidden, activation=activation)
    net = model.new_network(small, np.random.default_rng(5))
    beta = net.get_nonlinear()
    w_out = np.random.default_rng(6).standard_normal(net.mlp.out.in_features)
    z = torch.from_numpy(small.phi)
    params, w = net._split(beta), torch.from_numpy(w_out)

    def f(p, zi):
        return functional_call(net.mlp, p, (zi[None],), {"last_hidden": True}, strict=False)[0] @ w

    grads = vmap(jacrev(f), in_dims=(None, 0))(params, z)
    want = torch.cat([grads[k].reshape(len(z), -1) for k in net.nonlinear_names()], 1).numpy()
    zs = (z - net.mlp.input_mean) / net.mlp.input_std
    got = net.network_jacobian(beta, w_out, zs)
    # Same derivative, other summation order: agreement to a few ulps of the largest entry
    # (relu's derivative at exactly 0 never occurs with these continuous draws).
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * np.abs(want).max())
    h = net.layer_outputs(beta, zs)[1][-1].numpy()
    np.testing.assert_array_equal(h, net.hidden_outputs(beta, z))


def test_reduced_cost_is_the_full_cost_at_its_linear_solution(data):
    """Variable projection: the reduced cost at beta equals the full cost at (x*(beta), beta),
    and there the full gradient with respect to the linear parameters vanishes."""
    small = TrainingData(data.phi[:500], data.target[:500])
    theta = lip_theta(small) * 1.02
    model = PGNNFeedforward(hidden=5, lam=0.05, weight_decay=1e-3, orthogonal_weight=0.5)
    net = model.new_network(small, np.random.default_rng(4))
    cost = model.training_cost(small, theta, net)
    beta = net.get_nonlinear()
    th, w, b = cost.linear(beta)
    p = np.concatenate([th, w, [b], beta])
    r_full, J_full = cost.full(p, True)
    r_red = cost(beta, False)
    assert r_full @ r_full == pytest.approx(r_red @ r_red, rel=1e-12)  # same numbers
    g_lin = 2 * J_full[:, :cost.n_linear].T @ r_full
    # Normal equations hold to round-off (relative to the gradient's natural scale).
    assert np.abs(g_lin).max() < 1e-9 * np.abs(J_full).max() * np.linalg.norm(r_full)


@pytest.mark.parametrize("hidden,activation", [(16, "tanh"), ((12, 6), "tanh")])
def test_fit_converges_and_records_how(data, hidden, activation):
    """On a learnable parasitic force the fit ends by the first-order test, and its record says
    so with the numbers that justify it."""
    theta = lip_theta(data)
    # Restarts: a single draw can converge to a local minimum that misses part of the sine.
    # 600 iterations: the lowest-cost draw takes 200 to 400 depending on the rounding.
    model = PGNNFeedforward(hidden=hidden, activation=activation, lam=0.01, weight_decay=1e-5,
                            max_iter=600, restarts=4).fit_data(data=data, theta_lip=as_dict(theta),
                                                   rng=np.random.default_rng(0))
    f = model.fit_
    assert f.stop == "converged", f
    assert f.first_order <= model.settings.ftol and f.iterations <= model.settings.max_iter
    assert f.data_cost == pytest.approx(model.cost_.data)
    assert f.reg_cost == pytest.approx(model.cost_.deviation + model.cost_.weight_decay)
    lip_cost = float(np.mean((data.target - data.phi @ theta) ** 2))
    assert f.data_cost < 0.1 * lip_cost  # the 3 N sine is learned (noise floor 0.04 N**2)


def test_capped_fit_says_max_iter(data):
    model = PGNNFeedforward(hidden=16, max_iter=2).fit_data(
        data=data, theta_lip=as_dict(lip_theta(data)), rng=np.random.default_rng(0))
    assert model.fit_.stop == "max_iter" and model.fit_.iterations == 2


def test_restarts_keep_the_lowest_training_cost(data):
    theta = as_dict(lip_theta(data))
    model = PGNNFeedforward(hidden=3, max_iter=8, restarts=3, continuation_lam=0.0).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(5))
    costs = [s.cost for s in model.fit_.starts]
    assert len(costs) == 3 and len(set(costs)) == 3  # three different draws
    assert model.cost_.total == pytest.approx(min(costs), rel=1e-12)


def test_lambda_zero_costs_no_more_than_the_regularized_fit_of_its_draw(data):
    """Every lambda = 0.01 solution is feasible for lambda = 0, so the lambda = 0 fit (which also
    starts from that solution: continuation) must end at a training cost no higher than the
    lambda = 0.01 fit's data and weight-decay terms, for the same draw of the hidden layers."""
    theta = as_dict(lip_theta(data))
    kw = dict(hidden=8, weight_decay=1e-5, max_iter=60)
    for seed in range(3):
        free = PGNNFeedforward(lam=0.0, **kw).fit_data(data=data, theta_lip=theta,
                                                       rng=np.random.default_rng(seed))
        reg = PGNNFeedforward(lam=0.01, **kw).fit_data(data=data, theta_lip=theta,
                                                       rng=np.random.default_rng(seed))
        assert [s.start for s in free.fit_.starts] == ["draw", "continuation"]
        assert [s.start for s in reg.fit_.starts] == ["draw"]  # theta is pulled: no need
        bound = reg.cost_.data + reg.cost_.weight_decay
        assert free.cost_.total <= bound * (1 + 1e-9), (seed, free.fit_, reg.cost_)


def test_orthogonal_projection_keeps_theta_lip(data):
    """Kon et al.: with the network kept orthogonal to the physical regressors, theta_phy is the
    least-squares LIP of the data, whatever the network learns (no theta_LIP in the cost)."""
    theta = lip_theta(data)
    model = PGNNFeedforward(hidden=16, lam=0.0, orthogonal_weight=10.0, max_iter=100).fit_data(
        data=data, theta_lip=as_dict(theta * 1.3), rng=np.random.default_rng(1))
    got = np.array([model.theta_[k] for k in THETA_NAMES])
    # 2 %: the bar; the penalty leaves only round-off and the unconverged remainder.
    np.testing.assert_allclose(got, theta, rtol=0.02)
    f = model.network(data.phi)
    q = np.linalg.qr(data.phi)[0]
    assert np.linalg.norm(q.T @ f) < 0.05 * np.linalg.norm(f)  # nearly orthogonal


def test_weight_decay_shrinks_the_weights(data):
    theta = as_dict(lip_theta(data))
    norms = []
    for alpha in (0.0, 1e-2):
        m = PGNNFeedforward(hidden=8, weight_decay=alpha, max_iter=60).fit_data(
            data=data, theta_lip=theta, rng=np.random.default_rng(3))
        norms.append(sum(float((v**2).sum()) for k, v in m.network_.state_dict().items()
                         if k.endswith("weight")))
        assert (m.cost_.weight_decay > 0) == (alpha > 0)
    assert norms[1] < 0.5 * norms[0]


def test_result_does_not_depend_on_the_callers_thread_count(data):
    """Fits pin torch and BLAS to one thread, so the caller's setting cannot change a bit."""
    theta = as_dict(lip_theta(data))
    before = torch.get_num_threads()
    states = []
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            m = PGNNFeedforward(hidden=16, max_iter=20).fit_data(
                data=data, theta_lip=theta, rng=np.random.default_rng(0))
            states.append(m.network_.state_dict())
    finally:
        torch.set_num_threads(before)
    for k in states[0]:
        assert torch.equal(states[0][k], states[1][k]), k


def test_worker_pool_gives_the_same_bits(data, fit_pool):
    """Fits on the process pool equal fits in this process (the pool asked for, whatever the
    cores: under pytest-xdist the other tests fit in their own process, conftest.py)."""
    from experiments.processes import workers as parallel
    theta = as_dict(lip_theta(data))
    small = TrainingData(data.phi[:600], data.target[:600])
    payloads = [({"hidden": 4, "max_iter": 10}, FeatureMap(), small, theta,
                 np.random.SeedSequence(11, spawn_key=(1, s))) for s in range(2)]
    pooled = parallel.map_fits(payloads)
    assert fit_pool  # the fits went to the pool
    for p, m in zip(payloads, pooled):
        here = parallel.fit_pgnn(p)
        for k, v in here.network_.state_dict().items():
            assert torch.equal(v, m.network_.state_dict()[k]), k


def test_first_order_measure_survives_a_failing_eigensolver(monkeypatch):
    """Where numpy's eigh does not converge (LAPACK's divide and conquer, seen on a real fit) the
    measure comes from the QL/QR iteration and is the same number."""
    rng = np.random.default_rng(3)
    J, r = rng.standard_normal((200, 12)), rng.standard_normal(200)
    want = optim.first_order_measure(r, J)

    def fails(a):
        raise np.linalg.LinAlgError("Eigenvalues did not converge")
    monkeypatch.setattr(np.linalg, "eigh", fails)
    assert optim.first_order_measure(r, J) == pytest.approx(want, rel=1e-10)


def test_optimizer_first_order_measure_is_scale_invariant():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((50, 4))
    r = rng.standard_normal(50)
    D = np.diag([1e-3, 1.0, 1e3, 7.0])
    assert optim.first_order_measure(r, J) == pytest.approx(optim.first_order_measure(r, J @ D))
    r_perp = r - J @ np.linalg.lstsq(J, r, rcond=None)[0]
    assert optim.first_order_measure(r_perp, J) < 1e-20  # stationary: nothing to gain


@pytest.mark.parametrize("hidden,activation", [(6, "tanh"), ((5, 3), "silu")])
def test_save_load_round_trip(tmp_path, data, hidden, activation):
    model = PGNNFeedforward(hidden=hidden, activation=activation, lam=0.01, max_iter=5,
                            features=FeatureMap(edge_samples=50))
    model.fit_data(data=data, theta_lip=as_dict(lip_theta(data)), rng=np.random.default_rng(2))
    model.save(tmp_path / "model")
    # The tensors alone are a plain state_dict: loadable with weights_only=True.
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert all(v.dtype == torch.float64 for v in state.values())
    assert {"mlp.input_mean", "mlp.input_std", "theta"} <= set(state)
    back = PGNNFeedforward.load(tmp_path / "model")
    assert back.fit_ == model.fit_
    r = PointToPoint(points_m=(0.0, 0.05, 0.0), dwell_s=0.05).sample(1e-4).r
    np.testing.assert_array_equal(back.feedforward(r, 1e-4), model.feedforward(r, 1e-4))
    assert back.theta_ == model.theta_ and back.features == model.features


def test_predict_refuses_before_fit():
    with pytest.raises(NotFittedError, match="fit"):
        PGNNFeedforward().feedforward(np.zeros(100), 1e-4)


def test_paper_table_config_has_the_twelve_rows():
    """Per n_l: sequential; lambda = 0 and 0.01 with the paper's cost (one start); lambda = 0
    and 0.01 with weight decay at their optimum (several starts, exchanged)."""
    from pathlib import Path

    from experiments.config import load_config

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "experiments/configs/paper_table.yaml")
    rows = [(f.kind, f.training, f.lam, f.hidden) for f in config.feedforwards]
    assert rows == [("none", None, None, None), ("lip", None, None, None)] + [
        ("pgnn", t, lam, n) for n in (16, 8)
        for t, lam in (("sequential", None), ("simultaneous", 0.0), ("simultaneous", 0.01),
                       ("simultaneous", 0.0), ("simultaneous", 0.01))]
    assert all(f.seeds >= 10 for f in config.feedforwards if f.kind == "pgnn")
    starts = [f.pgnn.starts for f in config.feedforwards if f.kind == "pgnn"]
    assert starts == [("draw", "lip", "exchange"), ("draw",), ("draw",),
                      ("draw", "lip", "exchange"), ("draw", "lip", "exchange")] * 2


def test_exchanged_starts_put_lambda_zero_at_or_below_the_regularized_objective(data):
    """With ``starts: [draw, lip, exchange]`` the lambda = 0 and lambda = 0.01 fits of a draw
    share their optimizations (the second fit runs none: it takes them from the cache), each
    keeps its lowest objective, and the lambda = 0 objective never ends above the lambda =
    0.01 objective, pull included (every regularized solution is feasible at lambda = 0). The
    record's counts are those of its starts."""
    from controllers.pgnn.starts import StartCache

    theta = as_dict(lip_theta(data))
    kw = dict(hidden=6, weight_decay=1e-5, max_iter=40, starts=("draw", "lip", "exchange"))
    for seed in range(3):
        cache = StartCache()
        free = PGNNFeedforward(lam=0.0, **kw).fit_data(
            data=data, theta_lip=theta, rng=np.random.default_rng(seed), reuse=cache)
        reg = PGNNFeedforward(lam=0.01, **kw).fit_data(
            data=data, theta_lip=theta, rng=np.random.default_rng(seed), reuse=cache)
        assert all(s.reused for s in reg.fit_.starts)
        assert not free.fit_.starts[0].reused  # the first fit ran its own draw
        assert {s.start for s in free.fit_.starts} >= {"draw", "lip", "continuation"}
        assert {s.start for s in reg.fit_.starts} >= {"draw", "lip", "exchange"}
        for model in (free, reg):
            f = model.fit_
            assert f.objective == pytest.approx(min(s.cost for s in f.starts), rel=1e-12)
            assert 1 <= f.agree <= len(f.starts)
            assert f.spread == pytest.approx(
                max(s.cost for s in f.starts) / min(s.cost for s in f.starts) - 1)
        # rounding only: the bound holds by construction
        assert free.fit_.objective <= reg.fit_.objective * (1 + 1e-12), (seed, free.fit_)
        assert reg.fit_.continuation_lam == free.fit_.continuation_lam == 0.01


def test_default_starts_are_the_draw_and_the_continuation(data):
    """Without ``starts`` a fit runs as it always did: lambda = 0 from its draw and from the
    draw's regularized solution; lambda > 0 from its draw alone."""
    theta = as_dict(lip_theta(data))
    free = PGNNFeedforward(lam=0.0, hidden=4, max_iter=10).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(0))
    reg = PGNNFeedforward(lam=0.01, hidden=4, max_iter=10).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(0))
    assert [s.start for s in free.fit_.starts] == ["draw", "continuation"]
    assert [s.start for s in reg.fit_.starts] == ["draw"]
    assert reg.fit_.agree == 1 and not reg.fit_.multiple_optima


@pytest.mark.parametrize("starts", [["lip"], ["draw", "draw"], ["draw", "nowhere"], "draw"])
def test_starts_must_name_known_starts_with_the_draw(starts):
    from clm_sim.errors import UserError

    with pytest.raises(UserError, match="pgnn.starts"):
        PGNNFeedforward(starts=starts)


def test_study_config_loads_and_refuses_unknown_keys(tmp_path):
    from pathlib import Path

    from clm_sim.errors import UserError
    from experiments.studies.extrapolation.study import load_study

    root = Path(__file__).resolve().parents[1]
    _, study = load_study(root / "experiments/configs/extrapolation_study.yaml")
    assert 0.0 in study.lams and study.paper_lam in study.lams
    bad = tmp_path / "bad.yaml"
    bad.write_text("study:\n  lambdaz: [0]\n")
    with pytest.raises(UserError, match=r"bad.yaml: study.lambdaz: unknown key"):
        load_study(bad)


def test_workers_are_spawned_where_the_fork_server_cannot_start(monkeypatch):
    """A fork server needs a socket in the temporary folder: where it cannot start, the pool's
    workers are spawn processes and the work is done all the same."""
    import multiprocessing.forkserver

    from experiments.processes import worker_life, workers
    def fails():
        raise OSError(30, "Read-only file system")
    monkeypatch.setattr(worker_life, "_SERVER_FAILED", False)
    monkeypatch.setattr(multiprocessing.forkserver, "ensure_running", fails)
    assert workers.map_in_order(abs, [-1, -2, 3], 2) == [1, 2, 3]
    assert worker_life.context().get_start_method() == "spawn"


@pytest.mark.parametrize("cost_stop,first_order,moved,want", [
    ("converged", 9e-5, 0.001, "converged"),
    ("converged", 9e-5, 0.005, "at_edge"),       # settled, but within 3x of theta_ftol
    ("converged", 9e-5, 0.02, "at_edge"),        # moving, but within 3x
    ("converged", 9e-5, 0.031, "theta_moving"),
    ("max_iter", 2e-4, 0.001, "at_edge"),        # at the cap within 3x of ftol
    ("max_iter", 4e-4, 0.001, "max_iter"),
    ("max_iter", 2e-4, 0.05, "theta_moving"),
    ("stalled", 1e-5, 0.0, "stalled"),
    ("converged", 9e-5, None, "converged")])    # sequential: no theta test
def test_a_verdict_is_judged_with_its_margin(cost_stop, first_order, moved, want):
    from controllers.pgnn.fit_record import verdict

    assert verdict(cost_stop, first_order, 1e-4, moved, 0.01) == want


def test_a_verdict_never_flips_from_converged_to_moving_within_its_margin():
    """A change of theta's travel by less than the margin squared (9x) moves a fit at most
    between converged and at_edge, or at_edge and theta_moving: never across both."""
    from controllers.pgnn.fit_record import VERDICT_MARGIN, verdict

    moved = np.geomspace(1e-4, 1.0, 400)
    for factor in np.geomspace(1.0 / VERDICT_MARGIN ** 2, VERDICT_MARGIN ** 2, 9)[1:-1]:
        pairs = {(verdict("converged", 9e-5, 1e-4, m, 0.01),
                  verdict("converged", 9e-5, 1e-4, m * factor, 0.01)) for m in moved}
        assert ("converged", "theta_moving") not in pairs
        assert ("theta_moving", "converged") not in pairs
