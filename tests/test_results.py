"""Typed results: a PGNN's FitRecord, a seed's result and a table row keep the files' keys."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from controllers.pgnn import FitRecord, PGNNFeedforward, TrainingData
from experiments.config import FeedforwardSpec
from experiments.results import ReferenceMetrics, SeedFit, SeedResult, TableRow, theta_drift


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    phi = np.column_stack([rng.normal(0, 3, 400), rng.normal(0, 0.2, 400),
                           np.sign(rng.normal(size=400)), rng.normal(0, 0.05, 400)])
    target = phi @ np.array([2.0, 40.0, 5.0, 100.0]) + np.sin(30 * phi[:, 3])
    return TrainingData(phi, target + 0.05 * rng.normal(size=400), 1e-4)


def _lip(data):
    return dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))


@pytest.fixture(scope="module")
def fitted(data):
    return PGNNFeedforward(hidden=3, max_iter=4).fit_data(data=data, theta_lip=_lip(data),
                                                          rng=0)


def test_fit_record_is_frozen_and_round_trips_through_its_json(fitted):
    f = fitted.fit_
    assert isinstance(f, FitRecord)
    with pytest.raises(AttributeError):
        f.stop = "converged"
    text = json.dumps(f.to_json())
    assert FitRecord.from_json(json.loads(text)) == f
    # The file keys stay the file's: lambda spelled out, theta_path flat.
    assert "continuation_lambda" in f.to_json() and "continuation_lam" not in f.to_json()
    assert set(f.to_json()["theta_path"][0]) == {"iteration", "data_cost", *THETA_NAMES}
    assert f.iterations_total == sum(s.iterations for s in f.starts)
    assert f.restarts == len(f.starts) >= 1
    assert f.data_cost == fitted.cost_.data


def test_a_pinned_fit_records_what_it_held(data, fitted):
    model = PGNNFeedforward(hidden=3, max_iter=3).fit_pinned(
        data=data, theta_lip=_lip(data), beta0=fitted.network_.get_nonlinear(),
        pinned={"mass": 2.0})
    f = model.fit_
    assert f.pinned == {"mass": 2.0} and f.starts == () and f.restarts == 1
    assert FitRecord.from_json(json.loads(json.dumps(f.to_json()))) == f


@pytest.mark.parametrize("bad", [[1], {"stop": "converged"}, {"stop": "x", "iterations": "a"}])
def test_a_broken_fit_section_is_one_user_error(bad):
    with pytest.raises(UserError, match=r"^fit: not a fit record"):
        FitRecord.from_json(bad)
    assert FitRecord.from_json(None) is None


def test_a_saved_model_with_a_broken_fit_section_is_refused_naming_it(fitted, tmp_path):
    fitted.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m.json").read_text())
    (tmp_path / "m.json").write_text(json.dumps({**doc, "fit": [1]}))
    with pytest.raises(UserError, match="cannot read PGNN model .fit: not a fit record"):
        PGNNFeedforward.load(tmp_path / "m")


def test_history_is_typed_and_the_file_keeps_its_keys(fitted, tmp_path):
    from controllers.pgnn.fit_record import Iterate

    h = fitted.history_
    assert all(isinstance(e, Iterate) for e in h) and len(h) >= 2
    assert [e.iteration for e in h] == list(range(len(h)))
    assert h[-1].data == pytest.approx(fitted.cost_.data)
    fitted.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m.json").read_text())
    assert list(doc["history"][0]) == ["iteration", "cost", "data", "deviation", "pinn",
                                       "orthogonal", "weight_decay", "theta"]
    back = PGNNFeedforward.load(tmp_path / "m")
    assert back.history_ == h
    assert json.dumps(back.to_json(), indent=1) == (tmp_path / "m.json").read_text()


@pytest.mark.parametrize("bad", [{"iteration": 0}, [1], {"iteration": 0, "cost": "x",
                                                        "theta": {}}])
def test_a_saved_model_with_a_broken_history_is_refused_naming_it(fitted, tmp_path, bad):
    fitted.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m.json").read_text())
    (tmp_path / "m.json").write_text(json.dumps({**doc, "history": [bad]}))
    with pytest.raises(UserError, match="cannot read PGNN model .history: "):
        PGNNFeedforward.load(tmp_path / "m")


def test_table_row_from_seed_results(fitted):
    spec = FeedforwardSpec.pgnn_row(training="simultaneous", lam=0.01, hidden=3, settings={})
    lip = {"mass": 2.0, "viscous": 40.0, "coulomb": 0.0, "stiffness": 50.0}
    drift = theta_drift(fitted.theta_, lip)
    # coulomb's LIP value is 0: left out of the relative drift.
    assert drift == max(abs(fitted.theta_[k] - lip[k]) / abs(lip[k])
                        for k in ("mass", "viscous", "stiffness"))
    seeds = tuple(SeedResult({"r1": ReferenceMetrics(m, 2 * m, 3 * m, 1.0, b)},
                             SeedFit(s, fitted.fit_, drift))
                  for s, (m, b) in enumerate([(1e-6, 0.5), (3e-6, 1.5)]))
    row = TableRow(spec, seeds, (fitted.theta_, fitted.theta_)).to_json()
    assert row["mae"]["r1"] == {"mean": 2e-6, "std": pytest.approx(np.sqrt(2) * 1e-6)}
    assert row["mae_per_seed"] == {"r1": [1e-6, 3e-6]}
    assert row["network_peak_beyond_n"]["r1"]["mean"] == 1.0
    assert [f["seed"] for f in row["fits"]] == [0, 1]
    assert row["fits"][0]["theta_drift"] == drift
    assert row["converged"] == 2 * fitted.fit_.converged
    assert row["regularizers"]["lambda"] == 0.01
    # Feedback only: no fits, no theta.
    none = TableRow(FeedforwardSpec(kind="none"), (SeedResult({"r1": ReferenceMetrics(
        1e-5, 2e-5, 3e-5)}),)).to_json()
    assert "fits" not in none and none["theta_phy"] is None


def test_figures_take_results_and_never_run_a_model():
    """No figure module calls a model: whoever computed a result hands it to the figure."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    modules = [root / "experiments" / "plots.py",
               *sorted((root / "experiments" / "studies").rglob("figures.py"))]
    assert len(modules) >= 2
    for path in modules:
        calls = {node.func.attr for node in ast.walk(ast.parse(path.read_text("utf-8")))
                 if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)}
        ran = calls & {"predict", "predict_parts", "feedforward", "network", "fit", "fit_data"}
        assert not ran, f"{path.name} calls {sorted(ran)}"


def test_cost_terms_are_typed_and_the_file_keeps_its_keys(fitted, tmp_path):
    from controllers.pgnn.cost import TERMS, CostTerms

    c = fitted.cost_
    assert isinstance(c, CostTerms) and list(c.to_json()) == list(TERMS)
    assert c.total == pytest.approx(c.data + c.regularization, rel=1e-15)
    assert fitted.fit_.reg_cost == c.regularization  # one sum, in one order
    assert CostTerms.from_json({"data": 1.5}) == CostTerms(1.5)  # an older file: the rest 0
    fitted.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["cost"] == c.to_json() and PGNNFeedforward.load(tmp_path / "m").cost_ == c
    for bad, key in (([1.0], "cost"), ({"data": "x"}, "cost.data"),
                     ({"data": 1.0, "pinn": True}, "cost.pinn")):
        (tmp_path / "m.json").write_text(json.dumps({**doc, "cost": bad}))
        with pytest.raises(UserError, match=f"cannot read PGNN model .{key}: expected"):
            PGNNFeedforward.load(tmp_path / "m")


def test_a_model_holds_its_options_in_settings_and_its_file_names_them_as_before(data,
                                                                                tmp_path):
    from controllers.pgnn_settings import CONSTRAINTS, PGNNSettings

    model = PGNNFeedforward(hidden=[3, 2], lam=0.01, settings=PGNNSettings(
        max_iter=2, lam_diag={"mass": 0.5}, continuation_lam=0.0, validation_fraction=0.2))
    model.fit_data(data=data, theta_lip=_lip(data), rng=1).save(tmp_path / "m")
    settings = json.loads((tmp_path / "m.json").read_text())["settings"]
    # The file's keys: every setting, in the table's order, lambda spelled out where it was.
    assert list(settings) == [{"lam_diag": "lambda_diag", "continuation_lam":
                               "continuation_lambda"}.get(k, k) for k in CONSTRAINTS]
    assert settings["hidden"] == [3, 2] and settings["lambda_diag"] == {"mass": 0.5}
    back = PGNNFeedforward.load(tmp_path / "m")
    assert back.settings == model.settings and back.widths() == (3, 2) and back.lam == 0.01


def test_a_start_cache_gives_a_later_fit_its_outcome_without_running_it(data, monkeypatch):
    """A fit that finds its start in the cache runs no optimization and has the same bits; the
    cache is passed in (the model keeps no private copy of it), and copies in and out."""
    from controllers import optim
    from controllers.pgnn.starts import StartCache

    cache, lip = StartCache(), _lip(data)
    first = PGNNFeedforward(hidden=3, max_iter=4).fit_data(data=data, theta_lip=lip, rng=5,
                                                           reuse=cache)
    # lambda = 0 with a continuation: the draw, the lambda = 0.01 fit from it and the
    # continuation from that solution.
    assert [s.start for s in first.fit_.starts] == ["draw", "continuation"]
    assert len(cache) == 3 and set(vars(first)) == set(vars(PGNNFeedforward())) | {
        "network_", "theta_", "theta_lip_", "history_", "best_iteration_", "cost_",
        "n_samples_", "ts_", "fit_"}
    ran, lm = [], optim.levenberg_marquardt
    monkeypatch.setattr(optim, "levenberg_marquardt", lambda *a, **k: ran.append(1) or lm(*a, **k))
    again = PGNNFeedforward(hidden=3, max_iter=4).fit_data(data=data, theta_lip=lip, rng=5,
                                                           reuse=cache)
    assert ran == [] and again.fit_ == first.fit_ and again.history_ == first.history_
    assert again.network_ is not first.network_
    for k, v in again.network_.state_dict().items():
        assert np.array_equal(v.numpy(), first.network_.state_dict()[k].numpy()), k
    again.network_.mlp.out.bias.data += 1.0  # the cache holds its own copy
    third = PGNNFeedforward(hidden=3, max_iter=4).fit_data(data=data, theta_lip=lip, rng=5,
                                                           reuse=cache)
    assert ran == [] and third.theta_ == first.theta_
    assert np.array_equal(third.network_.mlp.out.bias.detach().numpy(),
                          first.network_.mlp.out.bias.detach().numpy())
    other = PGNNFeedforward(hidden=3, max_iter=4).fit_data(data=data, theta_lip=lip, rng=6,
                                                           reuse=cache)
    assert ran and len(cache) == 6 and other.theta_ != first.theta_


def test_a_start_cache_keeps_the_latest():
    from controllers.pgnn.starts import StartCache

    cache = StartCache(kept=2)
    for key in "abc":
        cache.keep(key, {"outcome": key})
    cache.keep(None, {"outcome": "random"})  # an outcome of the random stream is never held
    assert len(cache) == 2 and "a" not in cache and cache.take("c") == {"outcome": "c"}
    assert cache.take(None) is None and cache.take("a") is None
    with pytest.raises(ValueError, match="kept"):
        StartCache(kept=0)


def test_a_table_row_reads_back_from_its_json_as_it_was_written(fitted):
    """``Row.from_json`` is the reader of ``TableRow.to_json``: the row read back writes the
    same JSON, key for key and in order (a sweep writes its table from rows read back)."""
    from experiments.table import Row, read_row

    spec = FeedforwardSpec.pgnn_row(training="simultaneous", lam=0.01, hidden=3, settings={})
    seeds = tuple(SeedResult({"r1": ReferenceMetrics(m, 2 * m, 3 * m, 1.0, 0.5)},
                             SeedFit(s, fitted.fit_, 0.1)) for s, m in enumerate([1e-6, 3e-6]))
    text = json.dumps(TableRow(spec, seeds, (fitted.theta_, fitted.theta_)).to_json())
    row = read_row(json.loads(text))
    assert isinstance(row, Row) and row.lam == 0.01 and row.fits[1].seed == 1
    assert json.dumps(row.to_json()) == text
    swept = row.with_extra(seed=3, task="t", row=0)
    assert list(swept.to_json())[-3:] == ["seed", "task", "row"] and swept.value("seed") == 3
