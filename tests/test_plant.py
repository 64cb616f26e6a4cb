"""The simulated motor against independent oracles.

* linear part: python-control's ZOH-sampled state-space model (closed and open loop);
* integration inside a sample: halving the sub-step (convergence below one encoder count);
* Coulomb/Stribeck sticking: no creep below breakaway, motion above it, no false sticking;
* each named effect: a tight ``scipy.integrate.solve_ivp`` integration of the same ODE, and the
  least-squares round trip ``regressors`` -> ``from_coefficients``;
* the encoder: quantized to its resolution, within half a count of the true position.
"""

from __future__ import annotations

import dataclasses
import math

import control
import numpy as np
import pytest
import scipy.integrate
import scipy.signal

from clm_sim.effects import EFFECTS, total_force
from clm_sim.effects.friction import FrictionAsymmetry, Presliding, Stribeck, dahl_path
from clm_sim.effects.position import (CableSlab, CableTaut, Cogging, ForceOffset, ForceRipple,
                                      TrackEnd)
from clm_sim.errors import UserError
from clm_sim.loop import simulate
from clm_sim.plant import Plant
from clm_sim.reference import PointToPoint
from controllers.pid import PIDDesign, design_pid

# --------------------------------------------------------------------------------------------
# Linear plant (fc = 0, no effects, ideal encoder) vs python-control
# --------------------------------------------------------------------------------------------

STIFFNESS = (0.0, 500.0)  # N/m: a free mass and one on a spring (underdamped with fv = 172)


def _linear_plant(stiffness: float) -> Plant:
    return Plant(coulomb=0.0, effects=(), encoder_resolution=0.0, stiffness=stiffness)


def _sampled_plant(plant: Plant, ts: float) -> control.StateSpace:
    """ZOH sample of m y'' = F - fv y' - fk y, state [y, y'], built by python-control."""
    a = [[0.0, 1.0], [-plant.stiffness / plant.mass, -plant.viscous / plant.mass]]
    b = [[0.0], [1.0 / plant.mass]]
    return control.c2d(control.ss(a, b, [[1.0, 0.0]], [[0.0]]), ts, method="zoh")


def _reversals(x: np.ndarray) -> int:
    """Number of sign changes of the sampled velocity (zero steps ignored)."""
    s = np.sign(np.diff(x))
    s = s[s != 0]
    return int(np.count_nonzero(s[1:] != s[:-1]))


def _closed_loop_oracle(plant, ts, r):
    pid = design_pid(mass=plant.mass, viscous=plant.viscous, stiffness=plant.stiffness,
                     design=PIDDesign(), ts=ts)
    loop = control.feedback(control.series(control.ss(pid.discrete), _sampled_plant(plant, ts)), 1)
    y = control.forced_response(loop, U=r).outputs
    u = scipy.signal.lfilter(pid.b, pid.a, r - y)
    return pid, y, u


def _first_reversal(x: np.ndarray) -> int:
    """Index of the first sample after which the sampled velocity changes sign (len(x) if none)."""
    s = np.sign(np.diff(x))
    moving = np.flatnonzero(s != 0)
    flips = moving[1:][s[moving[1:]] != s[moving[:-1]]]
    return int(flips[0]) if len(flips) else len(x)


@pytest.mark.parametrize("stiffness", STIFFNESS)
def test_linear_closed_loop_matches_sampled_state_space(stiffness, ts):
    """Back and forth with the designed PID: the product's loop vs python-control's."""
    plant = _linear_plant(stiffness)
    r = PointToPoint(points_m=(0.0, 0.02, -0.02, 0.0), dwell_s=0.05).sample(ts).r
    pid, y_ref, u_ref = _closed_loop_oracle(plant, ts, r)
    run = simulate(plant, pid, r, ts)
    np.testing.assert_array_equal(run.y, run.y_true)  # encoder_resolution = 0: ideal reading
    # Until the first velocity reversal both sides propagate the same exact ZOH matrices
    # (product: sub-steps of expm(A h); python-control: expm(A ts)), so they differ by
    # float64 round-off only, accumulated by the loop's integrator: 1e-12 of the stroke is
    # ~100x above that.
    k = _first_reversal(y_ref)
    assert k > 1000
    np.testing.assert_allclose(run.y_true[:k], y_ref[:k], rtol=0,
                               atol=1e-12 * np.max(np.abs(r)))
    # The force is the controller gain (~7e5 N/m) times that position round-off.
    np.testing.assert_allclose(run.u[:k], u_ref[:k], rtol=0, atol=1e-9 * np.max(np.abs(u_ref)))
    # Over the whole run (several reversals): with fc = 0 the friction is continuous at v = 0,
    # so the plant keeps its exact step through reversals and the two agree to round-off
    # accumulated by the loop (1e-12 of the stroke, as above).
    assert _reversals(run.y_true) >= 4
    np.testing.assert_allclose(run.y_true, y_ref, rtol=0, atol=1e-12 * np.max(np.abs(r)))


@pytest.mark.parametrize("stiffness", STIFFNESS)
def test_linear_open_loop_matches_zoh_recursion(stiffness, ts, zero_controller):
    """Zero controller, a held input sequence u_ff: y_true is the ZOH state-space response."""
    plant = _linear_plant(stiffness)
    n = 2000
    t = np.arange(n) * ts
    # Positive, rough input (so the stage never reverses and the reversal branch stays out).
    u = 60.0 + 20.0 * np.sin(2 * np.pi * 7.0 * t) \
        + np.random.default_rng(3).uniform(-10.0, 10.0, n)
    run = simulate(plant, zero_controller, np.zeros(n), ts, u_ff=u)
    assert _reversals(run.y_true) == 0
    np.testing.assert_array_equal(run.u, u)
    sys_d = _sampled_plant(plant, ts)
    x = np.zeros(2)
    y_ref = np.empty(n)
    for k in range(n):  # y[k] is read before u[k] is applied: the record's convention
        y_ref[k] = x[0]
        x = sys_d.A @ x + sys_d.B[:, 0] * u[k]
    # Same exact propagation, different association of the float64 products: round-off only.
    np.testing.assert_allclose(run.y_true, y_ref, rtol=0, atol=1e-12 * np.max(np.abs(y_ref)))
    _, y_ctrl = control.forced_response(sys_d, U=u)
    np.testing.assert_allclose(run.y_true, y_ctrl, rtol=0, atol=1e-12 * np.max(np.abs(y_ref)))


# --------------------------------------------------------------------------------------------
# Integration inside a sample
# --------------------------------------------------------------------------------------------

def test_halving_the_substep_moves_the_trajectory_less_than_one_count(default_pid, r1, r1_dither,
                                                                      ts, default_training_run):
    """Default plant and effects, closed loop on r1 with the 50 N dither: 4 -> 8 sub-steps."""
    plant = Plant()
    fine = simulate(dataclasses.replace(plant, substeps=2 * plant.substeps), default_pid, r1, ts,
                    dither=r1_dither)
    diff = float(np.max(np.abs(fine.y_true - default_training_run.y_true)))
    print(f"\nsubsteps {plant.substeps} -> {2 * plant.substeps}: max |dy_true| = {diff:.3e} m "
          f"over {len(r1)} samples")
    assert diff < plant.encoder_resolution  # the bar: below one encoder count


@pytest.mark.parametrize("coulomb, stiffness", [(0.0, 2.0e6), (7.21, 1.0e8)])
def test_halving_the_substep_with_presliding_moves_less_than_one_count(coulomb, stiffness,
                                                                       default_pid, r1, r1_dither,
                                                                       ts):
    """Dahl bristles (stiff: 1e8 N/m on 18.8 kg is a 370 Hz mode) with and without Coulomb
    friction, closed loop with dither on the first 4 s of r1: 2 -> 4 sub-steps."""
    n = 40000
    plant = Plant(coulomb=coulomb, effects=(Presliding(sliding=7.21, stiffness=stiffness),))
    runs = [simulate(dataclasses.replace(plant, substeps=k), default_pid, r1[:n], ts,
                     dither=r1_dither[:n]) for k in (plant.substeps, 2 * plant.substeps)]
    diff = float(np.max(np.abs(runs[1].y_true - runs[0].y_true)))
    print(f"\npresliding {stiffness:g} N/m: max |dy_true| = {diff:.3e} m")
    assert diff < plant.encoder_resolution  # the bar: below one encoder count
    assert np.ptp(runs[0].y_true) > 0.01  # it did move


# --------------------------------------------------------------------------------------------
# Stiction and reversals
# --------------------------------------------------------------------------------------------

STICTION_PLANTS = {
    "coulomb": Plant(effects=()),
    "stribeck": Plant(effects=(Stribeck(peak=1.5, velocity=0.001, exponent=2.0),)),
    # A dip: breakaway below Coulomb (friction rising to it with speed).
    "stribeck dip": Plant(effects=(Stribeck(peak=-3.0, velocity=0.01, exponent=2.0),)),
    "asymmetric": Plant(effects=(FrictionAsymmetry(coulomb_pos=2.0, coulomb_neg=0.5),)),
    # Position forces (cable carrier, ripple at y0) shift the force the motor must apply.
    "default effects": Plant(),
}
Y0 = 0.05  # m, where the stage rests (off-centre, so the cable-carrier force is not zero)


def _breakaway(plant: Plant, direction: float) -> float:
    """Static friction level (N) for pushing in ``direction``, from the parameters."""
    level = plant.coulomb
    for e in plant.effects:
        if isinstance(e, Stribeck):
            level += e.peak
        if isinstance(e, FrictionAsymmetry):
            level += e.coulomb_pos if direction > 0 else e.coulomb_neg
    return level


def _input_for_net_force(plant: Plant, y0: float, net: float) -> float:
    """The held input u with ``u - sum(effect forces at rest at y0) - fk*y0 = net`` (affine)."""
    def f(u):
        return u - float(total_force(plant.effects, np.array(y0), np.array(0.0), np.array(u))) \
            - plant.stiffness * y0
    return (net - f(0.0)) / (f(1.0) - f(0.0))


@pytest.mark.parametrize("name", list(STICTION_PLANTS))
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_stage_at_rest_below_breakaway_never_creeps(name, direction, ts, zero_controller):
    plant = STICTION_PLANTS[name]
    u = _input_for_net_force(plant, Y0, 0.99 * direction * _breakaway(plant, direction))
    n = 20000  # 2 s
    run = simulate(plant, zero_controller, np.full(n, Y0), ts, u_ff=np.full(n, u))
    # Exact: a sticking stage must not move by a single bit (no smoothed sign, no creep).
    assert np.all(run.y_true == Y0)


@pytest.mark.parametrize("name", list(STICTION_PLANTS))
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_stage_breaks_away_above_breakaway(name, direction, ts, zero_controller):
    plant = STICTION_PLANTS[name]
    u = _input_for_net_force(plant, Y0, 1.01 * direction * _breakaway(plant, direction))
    n = 5000
    run = simulate(plant, zero_controller, np.full(n, Y0), ts, u_ff=np.full(n, u))
    steps = np.diff(run.y_true)
    # It moves from the first sample on, in the force's direction only, and keeps moving.
    assert np.all(steps * direction > 0)
    assert (run.y_true[-1] - Y0) * direction > 1e-6


def _coulomb_reversal_oracle(plant: Plant, u1: float, t1: float, t: np.ndarray) -> np.ndarray:
    """Exact position of m a = u - fv v - fc sign(v) from rest at 0: +u1 until t1, then -u1.

    Piecewise exponentials: on each piece the net force F is constant and
    v(t) = F/fv + (v0 - F/fv) exp(-t/tau), tau = m/fv.
    """
    m, fv, fc = plant.mass, plant.viscous, plant.coulomb
    tau = m / fv

    def piece(y0, v0, force, dt):
        vinf = force / fv
        e = np.exp(-dt / tau)
        return y0 + vinf * dt + (v0 - vinf) * tau * (1 - e), vinf + (v0 - vinf) * e

    y = np.empty_like(t)
    first = t <= t1
    y[first], _ = piece(0.0, 0.0, u1 - fc, t[first])
    y1, v1 = piece(0.0, 0.0, u1 - fc, t1)
    vinf = (-u1 - fc) / fv
    tc = t1 + tau * math.log((vinf - v1) / vinf)  # the velocity crosses zero here
    second = (t > t1) & (t <= tc)
    y[second], _ = piece(y1, v1, -u1 - fc, t[second] - t1)
    yc, _ = piece(y1, v1, -u1 - fc, tc - t1)
    third = t > tc
    y[third], _ = piece(yc, 0.0, -u1 + fc, t[third] - tc)
    return y


@pytest.mark.parametrize("substeps, tol", [(4, 1e-9), (64, 1e-11)])
def test_reversal_under_large_force_matches_exact_solution(substeps, tol, ts, zero_controller):
    """Coulomb friction only: +50 N for 0.1 s, then -50 N; the stage reverses once.

    The crossing time and the rest of that sub-step use a constant-acceleration estimate, a local
    error that shrinks faster than the sub-step (measured 3.2e-10 m with 4, 1.3e-12 m with 64):
    the tolerances sit 3-8x above those and 100x below an encoder count.
    """
    plant = dataclasses.replace(STICTION_PLANTS["coulomb"], substeps=substeps)
    n, k1 = 4000, 1000
    u = np.where(np.arange(n) < k1, 50.0, -50.0)
    run = simulate(plant, zero_controller, np.zeros(n), ts, u_ff=u)
    y_ref = _coulomb_reversal_oracle(plant, 50.0, k1 * ts, run.t)
    np.testing.assert_allclose(run.y_true, y_ref, rtol=0, atol=tol)


@pytest.mark.parametrize("name", ["coulomb", "stribeck", "asymmetric", "default effects"])
def test_reversal_under_large_force_does_not_stick(name, ts, zero_controller):
    """The velocity crosses zero once and the stage continues the other way (no false stop)."""
    plant = STICTION_PLANTS[name]
    n, k1 = 4000, 1000
    u = np.where(np.arange(n) < k1, 50.0, -50.0)
    run = simulate(plant, zero_controller, np.full(n, Y0), ts, u_ff=u)
    steps = np.diff(run.y_true)
    turn = int(np.argmax(steps < 0))
    assert turn > k1 and np.all(steps[:turn - 1] > 0) and np.all(steps[turn:] < 0)
    assert _reversals(run.y_true) == 1


# --------------------------------------------------------------------------------------------
# Effects: sign convention against an independent ODE integration, and the LIP round trip
# --------------------------------------------------------------------------------------------

# Exaggerated parameters so each effect clearly shapes 0.2 s of motion.
EFFECT_CASES = {
    "cogging": Cogging(amplitude=3.0, period=0.01, phase=0.4),
    "force_ripple": ForceRipple(amplitude=0.05, period=0.01, phase=-1.0),
    "cable_slab": CableSlab(coefficients=(1.0, 50.0, 300.0, 2.0e4), center=-0.01),
    # taut within 15 mm: the motion crosses its hardening and its flat part
    "cable_taut": CableTaut(pull=4.0, reach=0.012, center=0.002),
    "stribeck": Stribeck(peak=2.0, velocity=0.02, exponent=2.0),
    "stribeck dip": Stribeck(peak=-3.0, velocity=0.02, exponent=2.0),
    "friction_asymmetry": FrictionAsymmetry(coulomb_pos=1.0, coulomb_neg=0.5, viscous_pos=20.0,
                                            viscous_neg=10.0),
    "force_offset": ForceOffset(force_n=3.0),
    "presliding": Presliding(sliding=4.0, stiffness=2.0e5),
    # the coil leaves the track 3 mm from the start: the motor force falls to ~70 % by 15 mm
    "track_end": TrackEnd(start=0.003, coil_length=0.04, fringe=0.004),
}


def test_every_registered_effect_has_a_case():
    assert {e.type for e in EFFECT_CASES.values()} == set(EFFECTS)
    assert all(type(e) is EFFECTS[e.type] for e in EFFECT_CASES.values())


def _ode_oracle(plant: Plant, effect, u: float, direction: float, t: np.ndarray) -> np.ndarray:
    """m a = u - fv v - fc s - fk y - effect.force(y, v, u), from rest at 0, moving in s."""
    m, fv, fc, fk = plant.mass, plant.viscous, plant.coulomb, plant.stiffness

    def rhs(_, state):
        y, v, z = state
        # At t = 0 the stage is at rest but already moving in ``direction`` (u is above breakaway):
        # evaluate direction-dependent forces on that side of v = 0.
        v_side = v if v * direction > 0 else direction * 1e-300
        if isinstance(effect, Presliding):  # Dahl's ODE in time: dz/dt = v*(1 - sign(v)*z)/L
            f, dz = effect.sliding * z, v * (1.0 - direction * z) / effect.length
        else:
            f, dz = float(effect.force(np.array(y), np.array(v_side), np.array(u))), 0.0
        return [v, (u - fv * v - fc * direction - fk * y - f) / m, dz]

    sol = scipy.integrate.solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0, 0.0], method="DOP853",
                                    t_eval=t, rtol=1e-12, atol=1e-15)
    assert sol.success
    return sol.y[0]


@pytest.mark.parametrize("name", list(EFFECT_CASES))
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_effect_in_plant_matches_ode(name, direction, ts, zero_controller):
    """Sign convention: the plant applies ``-effect.force`` exactly as the docstring's ODE says.

    Within a sub-step the compiled plant holds the nonlinear forces at their start value, a
    first-order method: the error to the ODE must fall ~4x per 4x finer sub-step and reach
    1e-9 m at 1000 sub-steps (0.1 us; measured <= 5e-10 m). A wrong sign or factor of an effect
    shows as >= 1e-5 m here and does not converge.
    """
    effect = EFFECT_CASES[name]
    n = 2000  # 0.2 s
    u = 30.0 * direction
    t = np.arange(n) * ts
    y_ref = _ode_oracle(Plant(), effect, u, direction, t)
    assert np.all(np.diff(y_ref) * direction > 0)  # moving one way: no reversal in the oracle
    assert np.max(np.abs(y_ref)) > 0.01

    def error(substeps):
        plant = dataclasses.replace(Plant(), effects=(effect,), substeps=substeps,
                                    encoder_resolution=0.0)
        run = simulate(plant, zero_controller, np.zeros(n), ts, u_ff=np.full(n, u))
        return float(np.max(np.abs(run.y_true - y_ref)))

    e4, e16, e1000 = error(4), error(16), error(1000)
    assert e1000 < 1e-9
    # 4 sub-steps (twice the product's default) on these exaggerated effects, open loop (nothing
    # corrects the drift): measured <= 1.2e-7 m over 0.2 s.
    assert e4 < 2e-7
    if isinstance(effect, Presliding):  # trapezoidal Dahl force: second order (measured ~16x)
        assert e4 / e16 > 8.0
    elif not isinstance(effect, ForceOffset):  # a constant force is integrated exactly
        assert 3.0 < e4 / e16 < 5.0


def _antisymmetric_friction(e: FrictionAsymmetry) -> FrictionAsymmetry:
    c, d = (e.coulomb_pos - e.coulomb_neg) / 2, (e.viscous_pos - e.viscous_neg) / 2
    return FrictionAsymmetry(coulomb_pos=c, coulomb_neg=-c, viscous_pos=d, viscous_neg=-d)


# Columns a LIP (or an offset) already holds, which absorb part of an effect, and the effect that
# the round trip must then return.
ABSORBED = {
    "cable_slab": (lambda y, v: {"one": np.ones_like(y),
                                 "y": y - EFFECT_CASES["cable_slab"].center},
                   CableSlab(coefficients=(0.0, 0.0) + EFFECT_CASES["cable_slab"].coefficients[2:],
                             center=EFFECT_CASES["cable_slab"].center)),
    "friction_asymmetry": (lambda y, v: {"sign_v": np.sign(v), "v": v},
                           _antisymmetric_friction(EFFECT_CASES["friction_asymmetry"])),
}


@pytest.mark.parametrize("name", list(EFFECT_CASES))
def test_effect_regressors_round_trip(name):
    """Least squares of ``force`` on ``regressors`` gives back the effect via ``from_coefficients``.

    Where the LIP's own columns (offset, stiffness, fc sign v, fv v) absorb part of an effect
    (the cable carrier's constant and linear terms, the symmetric part of a friction asymmetry),
    those columns join the fit and the round trip returns the rest.
    """
    effect = EFFECT_CASES[name]
    if effect.plant_only:  # no column to fit: refused with a one-line error
        with pytest.raises(UserError, match=f"{effect.type} is plant-only"):
            effect.regressors(np.zeros(3), np.zeros(3), np.zeros(3))
        return
    rng = np.random.default_rng(7)
    n = 4000
    y = rng.uniform(-0.12, 0.12, n)
    v = rng.uniform(-0.06, 0.06, n)
    v[::50] = 0.0  # standstill samples too
    u = rng.normal(0.0, 50.0, n)
    cols = effect.regressors(y, v, u)
    absorbed, expected = ABSORBED.get(name, (lambda y, v: {}, effect))
    extra = absorbed(y, v)
    x = np.column_stack([*cols.values(), *extra.values()])
    coef, *_ = np.linalg.lstsq(x, effect.force(y, v, u), rcond=None)
    back = effect.from_coefficients(dict(zip([*cols, *extra], coef)))
    assert type(back) is type(effect)
    # Noise-free, well-conditioned fits: coefficients are exact up to round-off (1e-9).
    for key, value in expected.parameters().items():
        np.testing.assert_allclose(back.parameters()[key], value, rtol=1e-9, atol=1e-9,
                                   err_msg=f"{name}.{key}")
    # The rebuilt effect plus the absorbed part reproduces the force.
    rebuilt = back.force(y, v, u) + (x[:, len(cols):] @ coef[len(cols):] if extra else 0.0)
    np.testing.assert_allclose(rebuilt, effect.force(y, v, u), rtol=0, atol=1e-9)


def test_dahl_path_is_rate_independent_and_exact_on_monotone_paths():
    """The state from a 10 kHz path equals the one from every 10th sample (1 kHz) at the common
    samples, where the path is monotone between them; on a monotone path from 0 it is the closed
    form ``s*(1 - exp(-|y - y0|/L))``."""
    t = np.arange(20001) * 1e-4
    y = 2e-5 * np.sin(2 * np.pi * t)  # +-20 um, reversals at the quarter periods
    length = 3e-6
    fast, slow = dahl_path(y, length), dahl_path(y[::10], length)
    # Round-off only (1e-12): exp(-a)exp(-b) = exp(-a-b) between the common samples.
    np.testing.assert_allclose(fast[::10], slow, rtol=0, atol=1e-12)
    up = np.linspace(0.0, 1e-5, 50)
    np.testing.assert_allclose(dahl_path(up, length), 1 - np.exp(-up / length), rtol=0,
                               atol=1e-12)


# --------------------------------------------------------------------------------------------
# Encoder
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("resolution", [1e-6, 1e-7, 2.5e-8])
def test_encoder_quantizes_within_half_a_count(resolution, default_pid, r1, r1_dither, ts):
    n = 30000  # 3 s of r1 with dither: motion, standstill and reversals
    plant = Plant(encoder_resolution=resolution)
    run = simulate(plant, default_pid, r1[:n], ts, dither=r1_dither[:n])
    counts = run.y / resolution
    # Integer counts up to the float64 rounding of count*resolution (|count| <= 1e6 here).
    np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
    # Rounding to the nearest count: half a count, plus float64 round-off of the product.
    assert np.max(np.abs(run.y - run.y_true)) <= resolution / 2 * (1 + 1e-6)
    assert len(np.unique(run.y)) > 100  # the stage really moved across many counts


@pytest.mark.parametrize("stiffness", [2.0e3, 2.0e6, 1.0e8])
def test_the_presliding_substep_solves_its_equation_to_rounding(stiffness):
    """The implicit pre-sliding sub-step (``kernel.dahl_substep``) returns a displacement
    whose residual is at the rounding level of the position, from states across the bristle
    range, speeds of both signs and forces inside and beyond the sliding force; a bisection of
    the same monotone equation to the last bit agrees within that level."""
    from clm_sim import kernel

    plant = Plant(coulomb=0.0, effects=(Presliding(sliding=7.21, stiffness=stiffness),))
    motor = plant.kernel_plant(1e-3)
    ad, bd = motor.ad, motor.bd
    d_f, d_l = motor.effects.dahl_sliding, motor.effects.dahl_length
    rng = np.random.default_rng(0)
    for _ in range(200):
        x, v = rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2)
        g, z = rng.uniform(-50.0, 50.0), np.array([rng.uniform(-1.0, 1.0)])
        x1, _, dx = kernel.dahl_substep.py_func(x, v, g, ad, bd, d_f, d_l, z.copy())
        x0 = ad[0, 0] * x + ad[0, 1] * v - x

        def phi(d):
            return d - x0 - bd[0] * (g - kernel._dahl_mean.py_func(d_f, d_l, z, d)[0])

        lo, hi = x0 + bd[0] * (g - d_f.sum()), x0 + bd[0] * (g + d_f.sum())
        while True:  # plain bisection to adjacent floats
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            lo, hi = (lo, mid) if phi(mid) > 0 else (mid, hi)
        # Rounding level of the position: the equation carries x's rounding (ad @ [x, v] - x).
        tol = 1e-14 * (abs(x) + abs(dx))
        assert abs(phi(dx)) <= tol
        assert abs(dx - lo) <= tol and x1 == x + dx
