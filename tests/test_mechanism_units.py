"""The pieces of the hardening-carrier study: the reading's prediction from the plant's force
law, the unit-by-unit view and its intervention, the outcome against the pre-registered
criteria, and the per-effect force beyond the range."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clm_sim.effects.position import CableSlab, CableTaut
from clm_sim.errors import UserError
from experiments.studies.mechanism import prediction as mp
from experiments.studies.mechanism import units
from small_config import tiny_mechanism


def test_a_continued_cubic_is_the_cubic_cable_itself_and_overshoots_a_taut_one():
    cubic = (CableSlab(coefficients=(0.0, 10.0, 0.0, 2000.0)),)
    y = np.linspace(-0.17, 0.17, 35)
    assert np.allclose(mp.continued(cubic, y, 0.1, 3), mp.static_force(cubic, y), atol=1e-9)
    line = mp.continued(cubic, y, 0.1, 1)
    assert line[-1] < mp.static_force(cubic, y)[-1] - 5.0  # a line misses the cubic's rise
    taut = (CableTaut(pull=3.271, reach=0.11782),)
    far = mp.continued(taut, np.array([0.17]), 0.1, 3)[0]
    assert far > mp.static_force(taut, np.array([0.17]))[0] + 2.0  # the cubic overshoots
    edge = np.array([0.1, 0.1 + 1e-9])  # continuous at the range's edge
    assert abs(np.diff(mp.continued(taut, edge, 0.1, 3))[0]) < 1e-6


class _Model:
    """A fitted PGNN's network, built by hand: one tanh layer of three units."""

    def __init__(self, w, b, w_out):
        from controllers.pgnn.network import PGNNNetwork

        self.network_ = PGNNNetwork(hidden=(3,))
        with torch.no_grad():
            self.network_.mlp.hidden[0].weight.copy_(torch.tensor(w, dtype=torch.float64))
            self.network_.mlp.hidden[0].bias.copy_(torch.tensor(b, dtype=torch.float64))
            self.network_.mlp.out.weight.copy_(torch.tensor([w_out], dtype=torch.float64))


def test_the_view_names_units_that_stay_near_linear_and_the_intervention_removes_their_remainder():
    # unit 0 sees 0.5*y_scaled (near-linear), unit 1 5*y_scaled (saturates), unit 2 0.2*y (tiny)
    m = _Model([[0, 0, 0, 0.5], [0, 0, 0, 5.0], [0, 0, 0, 0.2]], [0.0, 0.0, 0.0], [10.0, 1.0, 3.0])
    phi = np.zeros((201, 4))
    phi[:, 3] = np.linspace(-1, 1, 201)
    beyond = np.zeros((21, 4))
    beyond[:, 3] = np.linspace(1.2, 2.0, 21)
    v = units.view(m, phi, beyond, near_linear=1.0)
    assert v["named"] == [0, 2] and v["control"] == [1]
    shares = [u["linear_share_training"] for u in v["units"]]
    assert shares[0] > 0.99 > shares[1]
    assert v["units"][1]["range_training"] == pytest.approx([-5.0, 5.0])
    fl = np.asarray(v["lines"])
    # with every unit linearized the network is a line in y; with none it is the network
    every = units.network_with_lines(m, beyond, [0, 1, 2], fl)
    assert np.allclose(np.diff(every, 2), 0.0, atol=1e-12)
    none = units.network_with_lines(m, beyond, [], fl)
    with torch.no_grad():
        net = m.network_.mlp(torch.from_numpy(beyond)).numpy()
    assert np.allclose(none, net, atol=1e-12)


def test_the_outcome_holds_an_amount_within_its_factor_and_a_sign_beside_its_interval():
    from experiments.studies.mechanism.summary import outcome

    pred = {"mae_diff_um": -0.4, "mae_diff_calibrated_um": -0.1, "error_beyond_lambda0_n": 2.0,
            "error_beyond_lambda_n": 0.5, "factor": 2.0}
    o = outcome(pred, -0.15e-6, [-0.25e-6, -0.05e-6], (3.9, 1.1))
    assert o.sign_held and not o.amount_held and o.calibrated_amount_held
    assert o.error_beyond_lambda0_held and not o.error_beyond_lambda_held
    assert not outcome(pred, -0.15e-6, [-0.25e-6, +0.01e-6], (3.9, 1.1)).sign_held


def test_a_prediction_names_a_case_and_its_keys(tmp_path):
    from experiments.studies.mechanism.settings import load_mechanism

    path = tmp_path / "p.yaml"
    path.write_text(tiny_mechanism() + "  prediction:\n    cable_cubic: {mae_diff_um: 0.1}\n")
    with pytest.raises(UserError, match=r"prediction.cable_cubic: expected the keys"):
        load_mechanism(path)
    path.write_text(tiny_mechanism() + "  prediction:\n    nope: {mae_diff_um: 0.1}\n")
    with pytest.raises(UserError, match=r"prediction.nope: not a case"):
        load_mechanism(path)
    path.write_text(tiny_mechanism() + "  near_linear: 0\n")
    with pytest.raises(UserError, match=r"near_linear"):
        load_mechanism(path)


@pytest.mark.slow
def test_a_study_with_the_view_reports_units_effects_and_the_prediction(tmp_path):
    from experiments.studies.mechanism.study import STUDY
    from experiments.studies.runner import run

    path = tmp_path / "m.yaml"
    path.write_text(tiny_mechanism() + "  near_linear: 1.0\n  prediction:\n    cable_cubic: "
                    "{mae_diff_um: 0.1, error_beyond_lambda0_n: 1, error_beyond_lambda_n: 1, "
                    "factor: 2}\n")
    s = run(STUDY, path, tmp_path / "out", workers=1, quiet=True)
    text = (tmp_path / "out" / "report.md").read_text()
    assert "**Unit by unit**" in text and "written before the run (cable_cubic)" in text
    eb = s.cases["cable_linear"].effects_beyond
    assert list(eb) == ["0:cable_slab"] and eb["0:cable_slab"].beyond_rms_n < 1e-9
    assert s.cases["cable_cubic"].effects_beyond["0:cable_slab"].inside_rms_n > 0
