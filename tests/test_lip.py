"""LIP identification: recovery of the true parameters on effect-free data (the issue's bar).

Two sources of data: the product's own training run (plant without parasitic forces, fine
encoder, 50 N dither, r1 three times as the runner does it), and a record made by an
independent simulator written here (exact piecewise solution of ``m a = u - fv v - fc sign v``,
its own PID, reference and dither, other parameters), identified through ``clm-sim identify``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clm_sim.errors import NotFittedError
from clm_sim.plant import Plant
from controllers.lip import LIPFeedforward
from experiments.cli import main
from experiments.config import ExperimentConfig
from experiments.testbed import Testbed

CRUISE = 0.05  # m/s: the references' cruise speed, where the friction force is compared


def check_recovery(theta: dict, true: dict) -> dict:
    """Assert the issue's recovery tolerances; returns the relative errors (for the report)."""
    def rel(x, ref):
        return abs(x - ref) / abs(ref)

    friction = lambda p: p["viscous"] * CRUISE + p["coulomb"]  # noqa: E731
    errors = {"mass": rel(theta["mass"], true["mass"]),
              "friction_at_cruise": rel(friction(theta), friction(true)),
              "viscous": rel(theta["viscous"], true["viscous"]),
              "coulomb": rel(theta["coulomb"], true["coulomb"]),
              "stiffness_n_per_m": abs(theta["stiffness"] - true.get("stiffness", 0.0))}
    print("\nLIP recovery: " + ", ".join(f"{k} {v:.3g}" for k, v in errors.items()))
    assert errors["mass"] < 0.02
    assert errors["friction_at_cruise"] < 0.03
    assert errors["viscous"] < 0.15
    assert errors["coulomb"] < 0.15
    assert errors["stiffness_n_per_m"] < 20.0
    return errors


@pytest.fixture(scope="session")
def effect_free_training():
    """The runner's training experiment on a plant without parasitic forces, 1 nm encoder."""
    config = ExperimentConfig(seed=3, plant=Plant(effects=(), encoder_resolution=1e-9))
    assert config.training.dither.std_n == 50.0  # the dither
    return config, Testbed(config).training_run()


def test_lip_recovers_effect_free_plant(effect_free_training):
    config, run = effect_free_training
    lip = LIPFeedforward(features=config.features).fit(y=run.y, u=run.u, ts=config.ts)
    check_recovery(lip.theta_, config.plant.theta())


def test_lip_fit_is_the_same_whatever_blas_threads_the_caller_set(effect_free_training):
    """OpenBLAS splits the sums of a long record's normal matrix over its threads: ``std_``
    moved in its last digits between one and two threads (the EMPS record's ``theta_`` too)."""
    import threadpoolctl

    config, run = effect_free_training
    fits = []
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(threads, user_api="blas"):
            lip = LIPFeedforward(features=config.features).fit(y=run.y, u=run.u, ts=config.ts)
        fits.append(json.dumps([lip.theta_, lip.std_, lip.residual_rms_]))
    assert fits[0] == fits[1]


def test_lip_predict_refuses_before_fit(ts):
    with pytest.raises(NotFittedError, match="fit"):
        LIPFeedforward().predict(y=np.zeros(1000), ts=ts)


def test_lip_predict_reproduces_inverse_dynamics(ts):
    """On an exact cubic trajectory the fitted model's force is m a + fv v + fc sign v + fk y."""
    lip = LIPFeedforward()
    lip.theta_ = {"mass": 18.8, "viscous": 172.0, "coulomb": 7.21, "stiffness": 30.0}
    lip.effects_ = ()
    t = np.arange(1000) * ts
    y = 0.01 + 0.02 * t + 0.5 * t**2 + 2.0 * t**3  # central differences are exact on a cubic
    v, a = 0.02 + t + 6.0 * t**2, 1.0 + 12.0 * t
    want = 18.8 * a + 172.0 * v + 7.21 * np.sign(v) + 30.0 * y
    got = lip.predict(y=y, ts=ts)
    # Central first difference of a cubic is exact up to ts^2*y'''/6 = 2e-8 m/s; second
    # differences are exact; float64 cancellation in (y[k+1]-2y[k]+y[k-1])/ts^2 costs ~1e-7
    # m/s^2 at these magnitudes. 1e-4 N covers both with margin.
    np.testing.assert_allclose(got[1:-1], want[1:-1], rtol=0, atol=1e-4)


# --------------------------------------------------------------------------------------------
# An independent simulator: not clm_sim's, other parameters, its own controller and excitation
# --------------------------------------------------------------------------------------------

INDEPENDENT_TRUE = {"mass": 12.0, "viscous": 90.0, "coulomb": 4.0, "stiffness": 0.0}


def independent_record(m, fv, fc, ts, r, dither, resolution):
    """Closed loop of a PID (no filter) around ``m a = u - fv v - fc sign v``, solved exactly.

    Within a sample the input is held, so the velocity is an exponential towards ``(u - fc s)/fv``
    while the direction ``s`` stays fixed; a zero crossing is solved for in closed form, and at
    rest the stage sticks while ``|u| <= fc``. The encoder rounds to ``resolution``. Returns the
    measured positions and the applied inputs.
    """
    tau = m / fv
    wn = 2 * math.pi * 25.0
    kp, kd = m * wn**2, 1.4 * m * wn
    ki = kp * 2 * math.pi * 2.5
    y = v = integral = e_prev = 0.0
    y_log, u_log = np.empty(len(r)), np.empty(len(r))
    for k in range(len(r)):
        yq = resolution * round(y / resolution)
        e = r[k] - yq
        integral += e * ts
        u = kp * e + ki * integral + kd * (e - e_prev) / ts + dither[k]
        e_prev = e
        y_log[k], u_log[k] = yq, u
        left = ts
        while left > 0.0:
            if v == 0.0:
                if abs(u) <= fc:
                    break  # sticks for the rest of the sample
                s = 1.0 if u > 0 else -1.0
            else:
                s = 1.0 if v > 0 else -1.0
            vinf = (u - fc * s) / fv
            if v != 0.0 and vinf * s < 0:  # decelerating through zero: where does it cross?
                tc = tau * math.log((vinf - v) / vinf)
                if tc < left:
                    y += vinf * tc + (v - vinf) * tau * (1 - math.exp(-tc / tau))
                    v, left = 0.0, left - tc
                    continue
            decay = math.exp(-left / tau)
            y += vinf * left + (v - vinf) * tau * (1 - decay)
            v = vinf + (v - vinf) * decay
            left = 0.0
    return y_log, u_log


@pytest.fixture(scope="session")
def independent_csv(tmp_path_factory):
    """20 s at 10 kHz: a 0.1 m, 0.08 Hz sine (peak speed 0.05 m/s) with 50 N Gaussian dither."""
    ts, n = 1e-4, 200_000
    t = np.arange(n) * ts
    r = 0.1 * np.sin(2 * np.pi * 0.08 * t)
    dither = np.random.default_rng(2024).normal(0.0, 50.0, n)
    p = INDEPENDENT_TRUE
    y, u = independent_record(p["mass"], p["viscous"], p["coulomb"], ts, r, dither, 1e-9)
    assert np.max(np.abs(r - y)) < 1e-3  # the loop tracks: the record is a sane experiment
    path = tmp_path_factory.mktemp("independent") / "record.csv"
    np.savetxt(path, np.column_stack([t, r, y, u]), delimiter=",", header="t,r,y,u",
               comments="", fmt="%.17g")
    return path


def test_identify_cli_recovers_independent_record(independent_csv, tmp_path, capsys):
    assert main(["identify", str(independent_csv), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    theta = json.loads((tmp_path / "lip.json").read_text())
    assert set(theta) >= {"mass", "viscous", "coulomb", "stiffness"}
    for name in ("mass", "viscous", "coulomb", "stiffness"):
        assert name in printed
    check_recovery(theta, INDEPENDENT_TRUE)
