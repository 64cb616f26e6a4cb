"""PGNN feedforward: the lemma's inequality, regularization limits, recovery, determinism, storage."""

from __future__ import annotations

import numpy as np
import pytest

from clm_sim.features import FeatureMap
from clm_sim.plant import THETA_NAMES
from clm_sim.reference import PointToPoint
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
    mean, std, params = model.init_params(data, theta, np.random.default_rng(seed))
    return np.tanh((data.phi - mean) / std @ params["W1"].T + params["b1"])


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
        init = model.history_[0]["cost"]
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
    assert model.history_[0]["cost"] == pytest.approx(lip_cost, rel=1e-9)  # round-off only


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
    model = PGNNFeedforward(hidden=8, lam=0.0, lambda_diag={name: 1e10}, max_iter=30)
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
    model = PGNNFeedforward(hidden=16, lam=0.01, max_iter=100)
    model.fit_data(data=data, theta_lip=as_dict(theta), rng=np.random.default_rng(1))
    got = np.array([model.theta_[k] for k in THETA_NAMES])
    # 1 %: the penalty 0.01*dtheta**2 must stay below the data-term gain (a few N**2).
    np.testing.assert_allclose(got[:3], theta[:3], rtol=0.01)
    # The sine (3 N amplitude, 4.5 N**2 power) is learnable; noise floor 0.04 N**2.
    assert model.cost_["data"] < 0.1 * lip_cost
    # theta_LIP itself is close to the truth: the sine hides no bias in mass, viscous, coulomb.
    np.testing.assert_allclose(theta[:3], THETA_TRUE[:3], rtol=0.05)
    costs = [h["cost"] for h in model.history_]
    assert all(b <= a for a, b in zip(costs, costs[1:]))  # LM accepts only decreases


@pytest.mark.parametrize("training", ["simultaneous", "sequential", "pinn"])
def test_same_seed_same_bits(data, training):
    theta = as_dict(lip_theta(data))
    fits = [PGNNFeedforward(hidden=5, training=training, max_iter=5).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(s)) for s in (7, 7, 8)]
    for k in fits[0].params_:
        np.testing.assert_array_equal(fits[0].params_[k], fits[1].params_[k])
    assert not np.array_equal(fits[0].params_["W1"], fits[2].params_["W1"])


def test_sequential_keeps_theta_lip(data):
    theta = as_dict(lip_theta(data))
    model = PGNNFeedforward(hidden=5, training="sequential", max_iter=10).fit_data(
        data=data, theta_lip=theta, rng=np.random.default_rng(0))
    assert model.theta_ == theta


def test_jacobian_matches_finite_differences(data):
    theta = lip_theta(data)
    for training, lam in (("simultaneous", 0.3), ("pinn", 0.0), ("sequential", 0.0)):
        model = PGNNFeedforward(hidden=4, training=training, lam=lam)
        mean, std, params = model.init_params(data, theta, np.random.default_rng(0))
        problem = model._problem(data, theta, mean, std, params)
        p = problem.layout.pack(params)
        _, J = problem(p, True)
        fd = np.empty_like(J)
        for k in range(len(p)):
            dp = np.zeros_like(p)
            dp[k] = 1e-6 * max(1.0, abs(p[k]))
            fd[:, k] = (problem(p + dp, False) - problem(p - dp, False)) / (2 * dp[k])
        # Central differences: truncation ~ step**2 * third derivative, round-off ~ 1e-16/1e-6.
        np.testing.assert_allclose(J, fd, atol=1e-7 * np.abs(J).max())


def test_save_load_round_trip(tmp_path, data):
    model = PGNNFeedforward(hidden=6, lam=0.01, max_iter=5, features=FeatureMap(edge_samples=50))
    model.fit_data(data=data, theta_lip=as_dict(lip_theta(data)), rng=np.random.default_rng(2))
    model.save(tmp_path / "model")
    back = PGNNFeedforward.load(tmp_path / "model")
    r = PointToPoint(points_m=(0.0, 0.05, 0.0), dwell_s=0.05).sample(1e-4).r
    np.testing.assert_array_equal(back.feedforward(r, 1e-4), model.feedforward(r, 1e-4))
    assert back.theta_ == model.theta_ and back.features == model.features


def test_predict_refuses_before_fit():
    with pytest.raises(RuntimeError):
        PGNNFeedforward().feedforward(np.zeros(100), 1e-4)


def test_paper_table_config_has_the_eight_rows():
    from pathlib import Path

    from experiments.config import load_config

    root = Path(__file__).resolve().parents[1]
    config = load_config(root / "experiments/configs/paper_table.yaml")
    rows = [(f.kind, f.training, f.lam, f.hidden) for f in config.feedforwards]
    assert rows == [("none", None, None, None), ("lip", None, None, None)] + [
        ("pgnn", t, lam, n) for n in (16, 8)
        for t, lam in (("sequential", None), ("simultaneous", 0.0), ("simultaneous", 0.01))]
    assert all(f.seeds >= 5 for f in config.feedforwards if f.kind == "pgnn")


def test_study_config_loads_and_refuses_unknown_keys(tmp_path):
    from pathlib import Path

    from clm_sim.errors import UserError
    from experiments.study import load_study

    root = Path(__file__).resolve().parents[1]
    config, study = load_study(root / "experiments/configs/extrapolation_study.yaml")
    assert 0.0 in study.lambdas and study.paper_lambda in study.lambdas
    bad = tmp_path / "bad.yaml"
    bad.write_text("study:\n  lambdaz: [0]\n")
    with pytest.raises(UserError, match=r"bad.yaml: study.lambdaz: unknown key"):
        load_study(bad)
