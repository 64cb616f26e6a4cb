"""The coil leaving the magnet track (``TrackEnd``): its overlap fraction against an independent
quadrature of the geometry, the exact motor command, refused parameters, and the mechanism study
on the plant variant. (Its kernel lowering against its law, its export to C and ONNX and the
plant against an ODE: the effect-parametrized tests of test_export_laws.py and test_plant.py.)"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from clm_sim.effects.position import CableSlab, TrackEnd
from clm_sim.errors import UserError
from clm_sim.plant import Plant
from small_config import tiny_mechanism

ROOT = Path(__file__).resolve().parent.parent


def _overlap_by_quadrature(effect: TrackEnd, y: float) -> float:
    """The fraction of the coil over the magnets, written from the geometry: a coil of length L
    centred at y over magnets on [-(start + L/2), start + L/2], each edge of the magnetic field
    blurred by a logistic density of scale w (the fringing), integrated numerically."""
    w, length = effect.fringe, effect.coil_length
    edge = effect.start + length / 2

    def field(x):  # the track's field seen at x: two blurred steps
        return (1 / (1 + math.exp(-(x + edge) / w))) - (1 / (1 + math.exp(-(x - edge) / w)))

    value, _ = scipy.integrate.quad(field, y - length / 2, y + length / 2, epsabs=1e-13,
                                    epsrel=1e-12, limit=200)
    return value / length


@pytest.mark.parametrize("effect", [TrackEnd(), TrackEnd(start=0.05, coil_length=0.08,
                                                        fringe=0.01)])
def test_overlap_is_the_coil_fraction_over_the_blurred_track(effect):
    """g(y) equals the integral of the blurred field over the coil, divided by its length
    (quadrature to 1e-10; the closed form is exact), at the centre, the edges and off the track."""
    y = np.array([0.0, 0.03, 0.1, 0.12, 0.15, 0.17, -0.17, 0.2, 0.26, -0.3])
    want = np.array([_overlap_by_quadrature(effect, float(p)) for p in y])
    np.testing.assert_allclose(effect.overlap(y), want, rtol=0, atol=1e-10)


def test_default_numbers_are_those_the_config_argues():
    """start 0.12 m, coil 0.12 m, fringe 4 mm: flat to 0.02 % over the training range, down to
    58.3 % at r2's 0.17 m (the hard overlap (0.18 - 0.11)/0.12 = 0.5833)."""
    g = TrackEnd().overlap(np.array([0.1, 0.17]))
    assert 1 - g[0] < 3e-4
    assert g[1] == pytest.approx(7 / 12, abs=1e-5)


def test_force_is_the_exact_inverse_and_the_motor_command_holds_the_rest():
    """force = (1 - g) u; the plant's motor command u satisfies g u = rest exactly (1e-12), where
    inverse_force's first-order form (u fed with the rest) does not."""
    effect = TrackEnd()
    y = np.linspace(-0.17, 0.17, 35)
    u = np.linspace(-50.0, 50.0, 35)
    np.testing.assert_allclose(effect.force(y, 0 * y, u), (1 - effect.overlap(y)) * u, rtol=0,
                               atol=1e-12)
    plant = Plant(effects=(CableSlab(coefficients=(0.0, 10.0)), effect))
    z = np.zeros_like(y)
    command = plant.motor_command(y, z, z)
    np.testing.assert_allclose(effect.overlap(y) * command, 10.0 * y, rtol=0, atol=1e-12)
    first_order = plant.inverse_force(y, z, z)
    assert np.max(np.abs(first_order - command)) > 0.5  # 1.2 N short at 0.17 m
    # Without a u-dependent effect the motor command is inverse_force, bit for bit.
    linear = Plant(effects=(CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0)),))
    assert np.array_equal(linear.motor_command(y, z, z), linear.inverse_force(y, z, z))


def test_the_motor_command_inverts_the_ripple_exactly():
    """Force ripple alone: the command holds u (1 + rho) = rest (1e-12 N), where inverse_force
    (u fed with the rest) is off by rho^2 rest."""
    from clm_sim.effects.position import ForceRipple

    y = np.linspace(-0.1, 0.1, 41)
    z = np.zeros_like(y)
    a = np.full_like(y, 3.0)
    plant = Plant(effects=(ForceRipple(amplitude=0.01, period=0.024),))
    rest = Plant(effects=()).inverse_force(y, z, a)
    rho = 0.01 * np.sin(2 * np.pi * y / 0.024)
    np.testing.assert_allclose(plant.motor_command(y, z, a) * (1 + rho), rest, rtol=0, atol=1e-12)
    assert np.max(np.abs(plant.inverse_force(y, z, a) * (1 + rho) - rest)) > 1e-4


@pytest.mark.parametrize("key, value", [("start", 0.0), ("coil_length", -0.1),
                                        ("fringe", float("nan")), ("fringe", 0.07)])
def test_bad_parameters_are_refused_naming_the_key(key, value):
    with pytest.raises(UserError, match=f"^track_end: {key} must be"):
        TrackEnd(**{key: value})


def test_a_bad_parameter_in_a_config_names_the_file_and_exits_2(tmp_path, capsys):
    from experiments import cli

    path = tmp_path / "bad.yaml"
    path.write_text("plant:\n  effects:\n    - {type: track_end, fringe: 0}\n")
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.yaml" in err and "fringe" in err


def test_the_variant_config_loads():
    from experiments.studies.mechanism.settings import load_mechanism

    _, st = load_mechanism(ROOT / "experiments" / "configs" / "lambda0_mechanism_track_end.yaml")
    assert any(isinstance(e, TrackEnd) for e in st.cases["track_end"])
    assert st.records >= 5 and st.draws >= 2


@pytest.mark.slow
def test_mechanism_study_runs_on_the_track_end_variant(tmp_path):
    """A tiny design (two records, one draw, a 3-neuron network, 5 iterations) on a plant whose
    track ends 12 mm out, with r2 reaching 20 mm: the study runs, reports the case, and its true
    dwell force is the motor command, 10 y / g(y), not the first-order 10 y (2 - g)."""
    from experiments.studies.mechanism.study import STUDY
    from experiments.studies.runner import run

    path = tmp_path / "m.yaml"
    path.write_text(tiny_mechanism(cases=(
        "  cases:\n    track_end:\n"
        "      - {type: cable_slab, coefficients: [0.0, 10.0]}\n"
        "      - {type: track_end, start: 0.012, coil_length: 0.02, fringe: 0.001}\n")))
    summary = run(STUDY, path, tmp_path / "out", workers=1, quiet=True)
    g = TrackEnd(start=0.012, coil_length=0.02, fringe=0.001).overlap(np.array(0.02))
    assert g < 0.7
    assert summary.cases["track_end"].truth_dwell_force_n == pytest.approx(0.2 / g,
                                                                                  rel=1e-9)
    lip = summary.cases["track_end"].lip
    assert lip.need_along_rms_n > 0 and np.isfinite(lip.error_along_rms_n)
    text = (tmp_path / "out" / "report.md").read_text()
    assert "| track_end | λ = 0 |" in text and "The force along r2 beyond the range" in text


def test_a_lip_given_the_plant_only_effect_refuses_in_one_line():
    from controllers.lip import LIPFeedforward

    t = np.arange(20000) * 1e-4
    y, u = 0.05 * np.sin(2 * np.pi * t), 30 * np.cos(2 * np.pi * t)
    with pytest.raises(UserError, match="^track_end is plant-only"):
        LIPFeedforward(effects=(TrackEnd(),)).fit(y=y, u=u, ts=1e-4)
