"""The taut cable carrier's force law: cubic near its centre, hardening up to 0.849 reach,
flattening beyond to its pull; read from a config like every effect."""

from __future__ import annotations

import numpy as np
import pytest

from clm_sim.effects.position import CableTaut
from clm_sim.errors import UserError
from clm_sim.schema import build_effect


def test_the_force_is_the_cubic_near_the_centre_and_the_pull_far_from_it():
    e = CableTaut(pull=3.0, reach=0.1, center=0.01)
    y = 0.01 + np.array([-0.002, 0.001, 0.003])
    cubic = 3.0 / 0.1**3 * (y - 0.01) ** 3
    assert np.allclose(e.force(y, 0 * y, 0 * y), cubic, rtol=1e-6)
    far = e.force(np.array([0.01 - 0.3, 0.01 + 0.3]), np.zeros(2), np.zeros(2))
    assert np.allclose(far, [-3.0, 3.0], rtol=1e-9)


def test_it_hardens_inside_its_steepest_point_and_flattens_beyond():
    e = CableTaut(pull=3.0, reach=0.1)
    y = np.linspace(0.0, 0.3, 30001)
    slope = np.gradient(e.force(y, 0 * y, 0 * y), y)
    steepest = y[np.argmax(slope)]
    assert abs(steepest - 0.0849) < 2e-4
    assert np.all(np.diff(slope[(y > 0.001) & (y < 0.084)]) > 0)  # hardening
    assert np.all(np.diff(slope[(y > 0.086) & (y < 0.2)]) < 0)    # flattening


def test_a_config_builds_it_and_refuses_a_reach_of_zero():
    e = build_effect({"type": "cable_taut", "pull": 2.0, "reach": 0.12}, "plant.effects[0]")
    assert e == CableTaut(pull=2.0, reach=0.12, center=0.0)
    assert build_effect(e.as_config(), "x") == e
    with pytest.raises(UserError, match="reach"):
        CableTaut(pull=2.0, reach=0.0)


def test_its_lip_column_rebuilds_it():
    e = CableTaut(pull=2.5, reach=0.12, center=-0.01)
    y = np.linspace(-0.2, 0.2, 11)
    col = e.regressors(y, 0 * y, 0 * y)["cable_taut"]
    back = e.from_coefficients({"cable_taut": 2.5})
    assert back == e
    assert np.allclose(2.5 * col, e.force(y, 0 * y, 0 * y), rtol=0, atol=1e-15)
