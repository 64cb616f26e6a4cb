"""PID design: oracles from python-control, the docstring formula and the closed-loop poles."""

import math

import control
import numpy as np
import pytest

from clm_sim.errors import UserError
from controllers.pid import PIDDesign, design_pid, filter_error

PLANT = dict(mass=18.8, viscous=172.0, stiffness=0.0)
TS = 1e-4


def _design(**kwargs):
    return design_pid(**PLANT, design=PIDDesign(**kwargs), ts=TS)


def _discrete_plant():
    plant = control.tf([1.0], [PLANT["mass"], PLANT["viscous"], PLANT["stiffness"]])
    return control.c2d(plant, TS, method="zoh")


def _loop_response(controller, hz):
    z = np.exp(2j * math.pi * np.atleast_1d(hz) * TS)
    return controller.discrete(z) * _discrete_plant()(z)


def _closed_loop_radius(crossover_hz, lowpass_hz=None, damping=0.7):
    """Largest |closed-loop pole|, from the PIDDesign docstring formula with default ratios,
    built independently of design_pid (so it also checks what design_pid rejects). Time is
    counted in samples (frequencies in rad/sample, period 1) so that c2d stays well-conditioned
    at kHz corners; sampling commutes with this rescaling for both tustin and zoh."""
    s = control.tf("s")
    wc = 2 * math.pi * crossover_hz * TS
    c = (1 + wc / 10 / s) * (s / (wc / 3) + 1) / (s / (wc * 3) + 1)
    if lowpass_hz is not None:
        wl = 2 * math.pi * lowpass_hz * TS
        c = c * control.tf([wl**2], [1, 2 * damping * wl, wl**2])
    m, v, k_s = PLANT["mass"], PLANT["viscous"], PLANT["stiffness"]
    plant = control.tf([TS**2], [m, v * TS, k_s * TS**2])  # 1/(m s^2 + v s + k), s = sigma/TS
    k = 1 / abs(complex((c * plant)(1j * wc)))
    loop = control.c2d(control.ss(k * c), 1.0, method="tustin") * control.c2d(
        control.ss(plant), 1.0, method="zoh")
    return np.max(np.abs(control.feedback(loop, 1).poles()))


def test_filter_error_matches_forced_response():
    controller = _design()
    e = np.random.default_rng(0).standard_normal(5000) * 1e-4
    u = filter_error(controller, e)
    _, expected = control.forced_response(controller.discrete, U=e)
    assert u.dtype == np.float64 and u.shape == e.shape
    # Two float64 realisations of one C(z) (DF2T vs python-control's state space) differ only by
    # round-off, which the integrator accumulates over 5000 samples: 1e-9 of the peak is ample.
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-9 * np.max(np.abs(expected)))


def test_b_a_are_discrete_tf_in_z_inverse():
    controller = _design(lowpass_hz=300.0)
    assert controller.a[0] == 1.0 and len(controller.b) == len(controller.a)
    assert controller.b.dtype == np.float64 and controller.a.dtype == np.float64
    z = np.exp(2j * math.pi * np.array([1.0, 30.0, 300.0, 3000.0]) * TS)
    zinv = z[:, None] ** -np.arange(len(controller.a))
    ratio = (zinv @ controller.b) / (zinv @ controller.a)
    # Same rational function evaluated two ways in float64; near z = 1 (the 1 Hz point) the
    # integrator pole makes both sums cancel by ~1e4, so allow 1e-7 rather than 1e-12.
    np.testing.assert_allclose(ratio, controller.discrete(z), rtol=1e-7)


@pytest.mark.parametrize("crossover_hz", [20.0, 30.0, 60.0])
def test_crossover_and_phase_margin(crossover_hz):
    controller = _design(crossover_hz=crossover_hz)
    # Tustin and the ZOH plant barely move |L| at <= 60 Hz of 10 kHz: 2 % is the requirement.
    assert controller.crossover_hz == pytest.approx(crossover_hz, rel=0.02)
    # The reported crossover really is the 0 dB point of Cd(z) Pd(z) (grid interpolation: 1e-3).
    assert abs(_loop_response(controller, controller.crossover_hz)[0]) == pytest.approx(1, rel=1e-3)
    assert 30.0 < controller.phase_margin_deg < 70.0
    # Phase margin from the phase of L at the crossover, independently of stability_margins.
    phase = np.degrees(np.angle(_loop_response(controller, controller.crossover_hz)[0]))
    assert controller.phase_margin_deg == pytest.approx(180 + phase, abs=0.05)
    assert 6.0 < controller.gain_margin_db < math.inf


def test_lowpass_reduces_phase_margin():
    plain = _design()
    filtered = _design(lowpass_hz=300.0)
    assert filtered.phase_margin_deg < plain.phase_margin_deg - 1.0
    assert filtered.gain_margin_db < plain.gain_margin_db


def test_default_is_stable():
    controller = _design()
    # Independent pole computation: docstring formula, our own c2d, state-space feedback.
    assert _closed_loop_radius(30.0) < 1
    assert "crossover 30.0 Hz" in controller.summary()


@pytest.mark.parametrize("crossover_hz, lowpass_hz", [(3000.0, 3500.0), (3000.0, None),
                                                      (100.0, 120.0)])
def test_unstable_design_raises(crossover_hz, lowpass_hz):
    # The oracle first: these designs really are unstable.
    assert _closed_loop_radius(crossover_hz, lowpass_hz) > 1
    with pytest.raises(UserError, match="unstable closed loop") as info:
        _design(crossover_hz=crossover_hz, lowpass_hz=lowpass_hz)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kwargs", [
    dict(crossover_hz=0.0), dict(crossover_hz=-30.0), dict(crossover_hz=float("nan")),
    dict(integrator_ratio=1.0), dict(derivative_ratio=0.5), dict(lowpass_hz=6000.0),
    dict(lowpass_hz=300.0, lowpass_damping=0.0), dict(discretization="gbt"),
])
def test_nonsensical_design_raises(kwargs):
    with pytest.raises(UserError, match="^pid: "):
        _design(**kwargs)


@pytest.mark.parametrize("plant, ts", [(dict(PLANT, mass=0.0), TS), (PLANT, 0.0)])
def test_nonsensical_plant_or_ts_raises(plant, ts):
    with pytest.raises(UserError, match="^pid: "):
        design_pid(**plant, design=PIDDesign(), ts=ts)


def test_parallel_form_reproduces_continuous():
    controller = _design()
    s = 2j * math.pi * np.array([0.3, 3.0, 30.0, 300.0, 3000.0])
    parallel = (controller.kp + controller.ki / s
                + controller.kd * s / (controller.tau_d * s + 1))
    # Algebraically identical; only float64 round-off separates them.
    np.testing.assert_allclose(parallel, controller.continuous(s), rtol=1e-10)
    assert min(controller.kp, controller.ki, controller.kd, controller.tau_d) > 0
