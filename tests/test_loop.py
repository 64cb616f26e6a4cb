"""The closed loop: signal bookkeeping, the PID inside the loop, dither, divergence, determinism."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from clm_sim.errors import UserError
from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from clm_sim.reference import PointToPoint
from experiments.config import ExperimentConfig, FeedforwardSpec, Training
from experiments.runner import run_experiment
from experiments.testbed import Testbed


def test_run_signals_are_consistent(default_training_run, default_pid, r1, r1_dither, ts):
    run = default_training_run
    n = len(r1)
    assert all(getattr(run, k).shape == (n,) and getattr(run, k).dtype == np.float64
               for k in ("t", "r", "y", "y_true", "u", "u_fb", "u_ff", "dither", "e"))
    np.testing.assert_array_equal(run.t, np.arange(n) * ts)
    np.testing.assert_array_equal(run.r, r1)
    np.testing.assert_array_equal(run.dither, r1_dither)
    np.testing.assert_array_equal(run.u_ff, 0.0)
    np.testing.assert_array_equal(run.e, run.r - run.y)
    # The applied force is the sum of its parts, bit for bit (one addition order in the loop).
    np.testing.assert_array_equal(run.u, run.u_fb + run.u_ff + run.dither)
    assert run.y_true[0] == r1[0]  # starts at rest on the reference


def test_pid_in_loop_equals_its_discrete_transfer_function(default_training_run, default_pid):
    """u_fb is C(z) applied to the logged error e (scipy's lfilter as the oracle)."""
    run = default_training_run
    expected = scipy.signal.lfilter(default_pid.b, default_pid.a, run.e)
    # Same DF2T recursion on the same doubles; lfilter may fuse multiply-adds differently, and
    # the integrator accumulates that round-off over 176k samples: 1e-9 of the peak force.
    np.testing.assert_allclose(run.u_fb, expected, rtol=0, atol=1e-9 * np.max(np.abs(expected)))


@pytest.mark.parametrize("hold", [1, 4, 25])
def test_dither_statistics_and_hold(hold):
    d = Dither(std_n=50.0, hold_samples=hold).draw(200_000, np.random.default_rng(5))
    assert d.shape == (200_000,)
    blocks = d[: len(d) // hold * hold].reshape(-1, hold)
    assert np.all(blocks == blocks[:, :1])  # each draw held for exactly `hold` samples
    assert np.all(blocks[1:, 0] != blocks[:-1, 0])
    draws = blocks[:, 0]
    # Sample std of m Gaussian draws has relative standard error 1/sqrt(2m) (<= 0.8 % here):
    # 4 % is five of those at the coarsest hold; the mean within 5 standard errors.
    assert abs(draws.std() / 50.0 - 1.0) < 0.04
    assert abs(draws.mean()) < 5 * 50.0 / np.sqrt(len(draws))


def test_zero_dither_draws_nothing():
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    np.testing.assert_array_equal(Dither(std_n=0.0).draw(100, rng), 0.0)
    assert rng.bit_generator.state == state


def test_diverging_loop_is_refused_with_a_message(ts):
    class TooHot:  # a pure gain of 1e9 N/m on 18.8 kg sampled at 10 kHz: violently unstable
        b = np.array([1e9])
        a = np.array([1.0])

    r = np.concatenate([np.zeros(10), np.full(990, 1e-3)])
    with pytest.raises(UserError, match="diverged"):
        simulate(Plant(), TooHot(), r, ts)


def test_wrong_length_feedforward_is_refused(default_pid, ts):
    with pytest.raises(ValueError, match="length"):
        simulate(Plant(), default_pid, np.zeros(100), ts, u_ff=np.zeros(99))


# --------------------------------------------------------------------------------------------
# Determinism
# --------------------------------------------------------------------------------------------

def test_same_seed_gives_identical_runs():
    tb = Testbed(ExperimentConfig(training=Training(repeats=1)))  # one pass of r1
    a, b = (tb.training_run(7) for _ in range(2))
    for name, value in a.signals().items():
        np.testing.assert_array_equal(value, b.signals()[name], err_msg=name)
    c = tb.training_run(8)
    assert not np.array_equal(a.dither, c.dither)
    assert not np.array_equal(a.y_true, c.y_true)


def _short_config(seed: int) -> ExperimentConfig:
    """The baseline experiment on short references (1.3 s of training) to keep the test fast."""
    refs = {"r1": PointToPoint(points_m=(0.0, 0.02, -0.02, 0.0), dwell_s=0.05),
            "r2": PointToPoint(points_m=(0.0, 0.03, 0.0), dwell_s=0.05)}
    return ExperimentConfig(name="short", seed=seed, references=refs,
                            training=Training(repeats=1),
                            feedforwards=(FeedforwardSpec(kind="none"),
                                          FeedforwardSpec(kind="lip")))


def test_runner_is_deterministic(tmp_path):
    tables = []
    for i in range(2):
        out = tmp_path / f"run{i}"
        run_experiment(_short_config(seed=4), out, quiet=True)
        tables.append((out / "table.json").read_text())
        runs = np.load(out / "runs" / "training.npz")
        if i == 0:
            first = {k: runs[k] for k in ("y", "u", "dither")}
        else:
            for k, v in first.items():
                np.testing.assert_array_equal(runs[k], v, err_msg=k)
    assert tables[0] == tables[1]
    other = tmp_path / "other_seed"
    run_experiment(_short_config(seed=5), other, quiet=True)
    assert (other / "table.json").read_text() != tables[0]
