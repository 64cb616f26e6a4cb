"""The Python API's contract: sample times owned by controllers and fitted models, the error
types, saving a LIP, and the small conveniences (reprs, ``--version``)."""

from __future__ import annotations

import numpy as np
import pytest

import clm_sim
from clm_sim.errors import NotFittedError, UserError
from clm_sim.loop import simulate
from clm_sim.plant import Plant
from controllers.lip import LIPFeedforward
from controllers.pid import PIDDesign, design_pid

TS = 1e-4


def _pid(ts: float):
    p = Plant()
    return design_pid(mass=p.mass, viscous=p.viscous, stiffness=p.stiffness, design=PIDDesign(),
                      ts=ts)


def _sine_record(ts: float = TS, seconds: float = 2.0):
    """Positions (m) of a 1 Hz, 50 mm sine and the force (N) of the rigid-body model on them."""
    t = np.arange(int(seconds / ts)) * ts
    w = 2 * np.pi
    y = 0.05 * np.sin(w * t)
    v = 0.05 * w * np.cos(w * t)
    a = -0.05 * w**2 * np.sin(w * t)
    u = 18.8 * a + 172.0 * v + 7.2 * np.sign(v) + 30.0 * y
    return y, u


@pytest.fixture(scope="module")
def lip() -> LIPFeedforward:
    y, u = _sine_record()
    return LIPFeedforward().fit(y=y, u=u, ts=TS)


def test_user_error_is_a_value_error():
    assert issubclass(UserError, ValueError)
    assert issubclass(NotFittedError, ValueError) and issubclass(NotFittedError, AttributeError)


def test_pid_refuses_a_loop_at_another_rate():
    pid = _pid(1e-4)
    r = np.zeros(500)
    with pytest.raises(ValueError, match=r"0\.0001 s.*0\.001 s") as info:
        simulate(Plant(), pid, r, 1e-3)
    assert isinstance(info.value, UserError)
    assert len(simulate(Plant(), pid, r, 1e-4)) == 500  # its own rate runs


@pytest.mark.parametrize("method", ["predict", "feedforward"])
def test_lip_refuses_use_before_fit(method):
    model = LIPFeedforward()
    call = (lambda: model.predict(y=np.zeros(500), ts=TS)) if method == "predict" else \
        (lambda: model.feedforward(np.zeros(500), TS))
    with pytest.raises(NotFittedError, match="fit"):
        call()


def test_lip_carries_its_rate_and_refuses_another(lip):
    assert lip.ts_ == TS
    y, _ = _sine_record()
    np.testing.assert_array_equal(lip.predict(y=y), lip.predict(y=y, ts=TS))  # default: own
    with pytest.raises(UserError, match=r"0\.0001 s.*0\.001 s"):
        lip.predict(y=y[::10], ts=1e-3)
    with pytest.raises(ValueError, match="1000 Hz"):
        lip.feedforward(y[::10], 1e-3)


def test_lip_save_load_round_trip(lip, tmp_path):
    lip.save(tmp_path / "lip.json")
    back = LIPFeedforward.load(tmp_path / "lip.json")
    assert back.ts_ == lip.ts_ == TS
    assert back.theta_ == lip.theta_ and back.features == lip.features
    y, _ = _sine_record()
    np.testing.assert_array_equal(back.feedforward(y), lip.feedforward(y, TS))
    with pytest.raises(UserError, match="1000 Hz"):
        back.predict(y=y[::10], ts=1e-3)


def test_lip_load_refuses_another_file(tmp_path):
    (tmp_path / "x.json").write_text('{"kind": "pgnn"}')
    with pytest.raises(UserError, match="x.json"):
        LIPFeedforward.load(tmp_path / "x.json")


def test_reprs_are_short():
    from clm_sim.run import Run
    from experiments.testbed import Testbed

    tb = Testbed()
    run = simulate(tb.plant, tb.pid, np.zeros(1000), tb.ts, meta=tb.meta(run="repr"))
    for text in (repr(run), repr(tb), repr(Run(t=[0.0], r=[0.0], y=[0.0], u=[0.0]))):
        assert len(text) < 300, text
    assert "1000 samples" in repr(run) and "ts=0.0001 s" in repr(run)
    assert "30 Hz" in repr(tb)


def test_version_and_help(capsys):
    from experiments.cli import main

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"clm-sim {clm_sim.__version__}"
    with pytest.raises(SystemExit):
        main(["--help"])
    description = capsys.readouterr().out.split("\n\n")[1]
    assert description.rstrip().endswith(".")  # a whole sentence, not the docstring's first line


def test_facade_exports_the_settings_classes():
    for name in ("Dither", "Training", "PGNNSettings", "DiagnosisSettings", "NotFittedError",
                 "UserError"):
        assert name in clm_sim.__all__ and getattr(clm_sim, name).__name__ == name


def test_a_progress_line_per_pgnn_fit():
    from experiments.config import ExperimentConfig, FeedforwardSpec, Training
    from experiments.testbed import Testbed

    lines = []
    tb = Testbed(ExperimentConfig(training=Training(repeats=1)), progress=lines.append)
    run = tb.training_run()
    lip = tb.fit_lip(run)
    spec = FeedforwardSpec.pgnn_row(training="sequential", lam=None, hidden=4, seeds=1,
                                    settings={"max_iter": 2, "decimation": 400})
    models = tb.fit_row(spec, run, lip)
    done = [x for x in lines if "done" in x]
    assert len(models) == 1 and len(done) == 1
    assert done[0].endswith(f"fit 1/1 done ({models[0].fit_.stop}, "
                            f"{models[0].fit_.iterations} it)")


def test_pgnn_settings_declared_once():
    """One table: the model's own settings (a row's hidden, training, lambda) and the options of
    ``PGNNSettings`` (the config's pgnn:, declared there only) are its keys, the activations the
    network's, and the config, the model and the settings refuse alike."""
    import dataclasses
    import inspect

    from controllers.pgnn import PGNNFeedforward
    from controllers.activations import ACTIVATION_NAMES, ACTIVATIONS
    from controllers.pgnn_settings import CONSTRAINTS, PGNNSettings
    from experiments.config import FeedforwardSpec

    options = {f.name for f in dataclasses.fields(PGNNSettings)}
    params = inspect.signature(PGNNFeedforward).parameters
    own = {k for k, v in params.items() if v.kind is v.KEYWORD_ONLY} - {"settings", "features"}
    assert own == {"hidden", "training", "lam"} and not own & options
    assert own | options == set(CONSTRAINTS)
    model = PGNNFeedforward()
    assert set(vars(model)) == own | {"settings", "features"}  # no option is an attribute
    assert model.settings == PGNNSettings() and set(ACTIVATION_NAMES) == set(ACTIVATIONS)
    # An option by name replaces that of settings=; the others are settings='s.
    base = PGNNSettings(max_iter=7, weight_decay=1e-5)
    assert PGNNFeedforward(settings=base, max_iter=3).settings == dataclasses.replace(
        base, max_iter=3)
    with pytest.raises(TypeError, match="unknown setting.*max_iters"):
        PGNNFeedforward(max_iters=3)
    y, u = _sine_record(seconds=1.0)
    for bad, key in ((dict(max_iter=0), "pgnn.max_iter"), (dict(ftol=1.0), "pgnn.ftol"),
                     (dict(activation="elu"), "pgnn.activation"),
                     (dict(init="random"), "pgnn.init"),
                     (dict(lam_diag={"mas": 1.0}), "pgnn.lambda_diag")):
        with pytest.raises(UserError, match=key):
            PGNNSettings(**bad)
        with pytest.raises(UserError, match=key):
            FeedforwardSpec.pgnn_row(training="sequential", lam=None, hidden=4, settings=bad)
        with pytest.raises(UserError, match=key):
            PGNNFeedforward(**bad).fit(y=y, u=u, ts=TS, theta_lip=dict.fromkeys(
                ("mass", "viscous", "coulomb", "stiffness"), 1.0), rng=0)
    for bad, key in ((dict(hidden=0), "hidden"), (dict(lam=-1.0), "lambda"),
                     (dict(training="joint"), "training")):
        spec = dict(training="simultaneous", lam=0.0, hidden=4) | bad
        with pytest.raises(UserError, match=key):
            FeedforwardSpec(kind="pgnn", **spec)
        with pytest.raises(UserError, match=key):
            PGNNFeedforward(**spec)
        model = PGNNFeedforward(hidden=4, training="sequential")
        for name, value in bad.items():  # set after construction: fit checks again
            setattr(model, name, value)
        with pytest.raises(UserError, match=key):
            model.fit(y=y, u=u, ts=TS, theta_lip=dict.fromkeys(
                ("mass", "viscous", "coulomb", "stiffness"), 1.0), rng=0)


def test_pgnn_fit_needs_a_seed_and_keeps_its_rate(tmp_path):
    from controllers.pgnn import PGNNFeedforward

    y, u = _sine_record(seconds=1.0)
    theta = {"mass": 18.8, "viscous": 172.0, "coulomb": 7.2, "stiffness": 30.0}
    small = dict(hidden=2, max_iter=2, decimation=40, training="sequential")
    with pytest.raises(UserError, match="rng="):
        PGNNFeedforward(**small).fit(y=y, u=u, ts=TS, theta_lip=theta)
    model = PGNNFeedforward(**small).fit(y=y, u=u, ts=TS, theta_lip=theta, rng=3)
    again = PGNNFeedforward(**small).fit(y=y, u=u, ts=TS, theta_lip=theta,
                                         rng=np.random.default_rng(3))
    assert model.ts_ == TS and model.theta_ == again.theta_  # an int seed is default_rng(seed)
    with pytest.raises(UserError, match=r"0\.0001 s.*0\.001 s"):
        model.feedforward(y[::10], 1e-3)
    model.save(tmp_path / "m")
    back = PGNNFeedforward.load(tmp_path / "m")
    assert back.ts_ == TS
    np.testing.assert_array_equal(back.feedforward(y), model.feedforward(y, TS))
    with pytest.raises(ValueError, match="1000 Hz"):
        back.predict(y=y[::10], ts=1e-3)


def _moving_csv(path, ts: float = TS, n: int = 60000) -> None:
    """Two sines (1 Hz, 20 mm and 3.3 Hz, 5 mm) with their exact rigid-body force."""
    t = np.arange(n) * ts
    w1, w2 = 2 * np.pi * 1.0, 2 * np.pi * 3.3
    y = 0.02 * np.sin(w1 * t) + 0.005 * np.sin(w2 * t)
    v = 0.02 * w1 * np.cos(w1 * t) + 0.005 * w2 * np.cos(w2 * t)
    a = -0.02 * w1**2 * np.sin(w1 * t) - 0.005 * w2**2 * np.sin(w2 * t)
    u = 12 * a + 90 * v + 4 * np.sign(v) + 30 * y
    np.savetxt(path, np.column_stack([t, y, y, u]), delimiter=",", header="t,r,y,u",
               comments="", fmt="%.17g")


def test_one_filter_setting_from_identify_to_the_diagnosis(tmp_path):
    """``--regression-lowpass-hz`` (the config's ``features.regression_lowpass_hz``) reaches the
    identified model and the diagnosis; the old ``--lowpass-hz`` of identify still works."""
    import json

    from experiments.cli import main

    _moving_csv(tmp_path / "rec.csv")
    assert main(["identify", str(tmp_path / "rec.csv"), "--out", str(tmp_path / "id"),
                 "--regression-lowpass-hz", "120"]) == 0
    lip = json.loads((tmp_path / "id" / "lip.json").read_text())
    assert lip["features"]["regression_lowpass_hz"] == 120.0 and lip["ts"] == pytest.approx(TS)
    assert main(["identify", str(tmp_path / "rec.csv"), "--out", str(tmp_path / "old"),
                 "--lowpass-hz", "80"]) == 0
    old = json.loads((tmp_path / "old" / "lip.json").read_text())
    assert old["features"]["regression_lowpass_hz"] == 80.0
    assert main(["diagnose", str(tmp_path / "rec.csv"), "--model",
                 str(tmp_path / "id" / "lip.json"),
                 "--out", str(tmp_path / "d"), "--regression-lowpass-hz", "150"]) == 0
    report = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    assert report["record"]["regression_lowpass_hz"] == 150.0
    assert "parallel low-pass 150 Hz" in (tmp_path / "d" / "report.md").read_text()


def test_diagnosis_model_carries_its_rate(tmp_path, lip):
    """A model file's ts sets its controller's rate (no record needed); a file without one takes
    the rate it is given (the record's); the diagnosis refuses a record at another rate."""
    from experiments.diagnosis import diagnose
    from experiments.model_files import load_model
    from clm_sim.run import Run

    path = tmp_path / "m.yaml"
    path.write_text("ts: 0.001\nplant: {mass: 18.8, viscous: 172.0}\n"
                    "controller: {crossover_hz: 30.0}\n")
    model = load_model(path)
    assert model.ts == 1e-3 and model.controller.ts == 1e-3
    y, u = _sine_record()
    record = Run(t=np.arange(len(y)) * TS, r=y, y=y, u=u, meta={"source": "rec"})
    with pytest.raises(UserError, match=r"rec: the model's controller .*0\.001 s.*0\.0001 s"):
        diagnose(record, model)
    path.write_text("plant: {mass: 18.8, viscous: 172.0}\ncontroller: {crossover_hz: 30.0}\n")
    assert load_model(path, TS).controller.ts == TS  # an older file: the record's rate
    with pytest.raises(UserError, match="ts:"):
        load_model(path)
    lip.save(tmp_path / "lip.json")
    assert load_model(tmp_path / "lip.json").ts == TS
