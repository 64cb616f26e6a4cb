"""Every model file is validated on load: a lip.json, a PGNN's .json and .pt
and a diagnosis.json that cannot be a model are refused in one line (exit 2) by every consumer
(``export-ff``, ``diagnose --model``, the loaders of the Python API), before any work and
before a network is allocated."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
import torch

from clm_sim.errors import UserError
from clm_sim.records.write import save_npz
from clm_sim.run import Run
from controllers.lip import LIPFeedforward
from controllers.pgnn import PGNNFeedforward
from experiments.cli import main

TS = 1e-4


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A LIP and an n_l = 2 PGNN fitted quickly on the training run, saved as a run saves them."""
    from experiments.testbed import Testbed

    tb = Testbed()
    run = tb.training_run()
    lip = tb.fit_lip(run)
    pgnn = tb.fit_pgnn(run, hidden=2, lip=lip, max_iter=2)
    folder = tmp_path_factory.mktemp("models")
    lip.save(folder / "lip.json")
    pgnn.save(folder / "net")
    return folder


def _cli(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.err.strip().splitlines()


LIP_CASES = {
    "NaN mass": ('"mass": NaN', "not a number in strict JSON"),
    "boolean mass": (True, "mass: expected a number"),
    "text mass": ("1e-05", "mass: expected a number"),
    "ts 1e-300": (1e-300, "not a servo sample time"),
    "ts true": (True, "expected a number"),
    "effects a string": ("x", "effects: expected a list"),
    "effect type a list": ([{"type": [1]}], "unknown effect"),
    "features a list": ([1], "features: expected an object"),
    "a JSON list": (None, "expected a JSON object"),
    "deep nesting": (None, "nested too deeply"),
}


def _lip_file(folder, case, tmp_path):
    value, _ = LIP_CASES[case]
    data = json.loads((folder / "lip.json").read_text())
    path = tmp_path / "lip.json"
    if case == "NaN mass":
        text = json.dumps(data).replace(f'"mass": {json.dumps(data["mass"])}', value)
    elif case == "a JSON list":
        text = "[1, 2]"
    elif case == "deep nesting":
        text = "[" * 100_000 + "]" * 100_000
    else:
        key = {"boolean mass": "mass", "text mass": "mass", "ts 1e-300": "ts", "ts true": "ts",
               "effects a string": "effects", "effect type a list": "effects",
               "features a list": "features"}[case]
        text = json.dumps({**data, key: value})
    path.write_text(text)
    return path


@pytest.mark.parametrize("case", sorted(LIP_CASES))
@pytest.mark.parametrize("consumer", ["load", "export-ff", "diagnose --model"])
def test_a_bad_lip_file_is_refused_by_every_consumer(saved, tmp_path, capsys, case, consumer):
    path = _lip_file(saved, case, tmp_path)
    if consumer == "load":
        with pytest.raises(UserError) as err:
            LIPFeedforward.load(path)
        lines = [str(err.value)]
        assert str(path) in lines[0]
    else:
        argv = (["export-ff", path, "--to", "c", "--out", tmp_path / "out"]
                if consumer == "export-ff" else
                ["diagnose", "x.csv", "--model", path, "--out", tmp_path / "out"])
        if consumer != "export-ff":  # a record that passes its guards: the model is refused
            from clm_sim.records.write import save_npz
            from clm_sim.run import Run
            t = np.arange(20000) * 1e-3
            y = 0.1 * np.sin(2 * t)
            save_npz(Run(t=t, r=y, y=y, u=-4 * y + 0.2 * np.cos(2 * t)
                         + np.sign(np.cos(2 * t))), tmp_path / "x.npz")
            argv[1] = tmp_path / "x.npz"
        code, lines = _cli(argv, capsys)
        lines = [line for line in lines if "warning" not in line]
        assert code == 2 and len(lines) == 1, lines
        assert not (tmp_path / "out").exists()
    expected = LIP_CASES[case][1]
    if consumer == "diagnose --model" and case in ("boolean mass", "text mass", "ts true"):
        expected = "expected a number"  # as the plant's key, plant.mass
    assert expected in lines[0], lines[0]


def _pgnn_copy(folder, tmp_path, json_edit=None, pt=None):
    stem = tmp_path / "net"
    data = json.loads((folder / "net.json").read_text())
    if json_edit is not None:
        data = json_edit(data)
    (tmp_path / "net.json").write_text(json.dumps(data))
    if pt is None:
        shutil.copy(folder / "net.pt", tmp_path / "net.pt")
    else:
        pt(folder, tmp_path / "net.pt")
    return stem


def _state(edit):
    def write(folder, target):
        state = torch.load(folder / "net.pt", weights_only=True)
        edit(state)
        torch.save(state, target)
    return write


PGNN_CASES = {
    "hidden 1e8": (lambda d: {**d, "settings": {**d["settings"], "hidden": [100_000_000]}},
                   None, "settings.hidden: expected 1 to 8 layers"),
    "hidden 9 layers": (lambda d: {**d, "settings": {**d["settings"], "hidden": [2] * 9}},
                        None, "settings.hidden"),
    "hidden over the parameter limit": (
        lambda d: {**d, "settings": {**d["settings"], "hidden": [200, 200]}}, None,
        "parameters, above the limit"),
    "hidden true": (lambda d: {**d, "settings": {**d["settings"], "hidden": True}},
                    None, "settings.hidden"),
    "settings a list": (lambda d: {**d, "settings": [1]}, None, "settings: expected an object"),
    "no theta": (lambda d: {k: v for k, v in d.items() if k != "theta"}, None,
                 "theta.mass: expected a number"),
    "ts 1e-300": (lambda d: {**d, "ts": 1e-300}, None, "not a servo sample time"),
    "empty .pt": (None, lambda folder, target: target.write_bytes(b""),
                  "cannot read PGNN model"),
    "text .pt": (None, lambda folder, target: target.write_text("import os"),
                 "cannot read PGNN model"),
    "huge .pt": (None, lambda folder, target: target.write_bytes(b"\0" * (3 * 2 ** 20)),
                 "far more than the"),
    "NaN weight": (None, _state(lambda s: s[next(k for k in s if "weight" in k)].fill_(
        float("nan"))), "holds NaN or inf"),
    "input_std 0": (None, _state(lambda s: s["mlp.input_std"].zero_()), "must be positive"),
    # the json's widths and the .pt's tensors disagree: which tensor, expected and found
    "hidden wider than the .pt": (
        lambda d: {**d, "settings": {**d["settings"], "hidden": [3]}}, None,
        "net.pt: mlp.hidden.0.weight has shape (2, 4); net.json's hidden [3] expects (3, 4)"),
    "a layer more than the .pt": (
        lambda d: {**d, "settings": {**d["settings"], "hidden": [2, 2]}}, None,
        "net.pt: no tensor mlp.hidden.1.weight; net.json's hidden [2, 2] expects one of shape "
        "(2, 2)"),
    "a tensor the json has no place for": (
        None, _state(lambda s: s.__setitem__("mlp.hidden.9.weight", torch.zeros(2, 2))),
        "net.pt: mlp.hidden.9.weight is no tensor of net.json's hidden [2]"),
}


@pytest.mark.parametrize("case", sorted(PGNN_CASES))
def test_a_bad_pgnn_file_is_refused_on_load_and_by_export(saved, tmp_path, capsys, case):
    edit, pt, expected = PGNN_CASES[case]
    stem = _pgnn_copy(saved, tmp_path, edit, pt)
    with pytest.raises(UserError, match=re.escape(expected)):
        PGNNFeedforward.load(stem)
    code, lines = _cli(["export-ff", stem.with_suffix(".pt"), "--to", "c", "--ts", TS,
                        "--out", tmp_path / "out"], capsys)
    assert code == 2 and len(lines) == 1 and expected in lines[0], lines
    assert not (tmp_path / "out").exists()


def test_the_saved_models_load_unchanged(saved):
    """The checks refuse nothing the product writes."""
    lip = LIPFeedforward.load(saved / "lip.json")
    stored = json.loads((saved / "lip.json").read_text())
    assert lip.theta_ == {k: stored[k] for k in lip.theta_}
    pgnn = PGNNFeedforward.load(saved / "net")
    assert pgnn.network_.mlp.input_std.min() > 0


# A model file's controller: a linear law (b, a, reference_b, ts) or a PID design; what is wrong
# with it is said by key, from the form whose keys the file uses, never "expected one or the other".
CONTROLLER_CASES = {
    "a[0] zero": ("{b: [1.0], a: [0.0]}", ["controller", "a[0] must not be 0"]),
    "no b": ("{a: [1.0]}", ["controller.b: missing", "LinearController"]),
    "exponent without sign": ("{b: [1.0e30]}", ["controller.b[0]: expected a number",
                                                 "1.0e+30"]),
    "extra key": ("{b: [1.0], extra: 3}", ["controller.extra: unknown key"]),
    "empty b": ("{b: []}", ["controller", "b must be non-empty"]),
    "two forms mixed": ("{b: [1.0], crossover_hz: 30.0}", [
        "controller: keys of different forms mixed", "b (LinearController)",
        "crossover_hz (PIDDesign)"]),
    "unknown key of a PID": ("{crossover_hz: 30.0, extra: 1}", ["controller.extra: unknown key",
                                                                "crossover_hz"]),
}


@pytest.mark.parametrize("case", list(CONTROLLER_CASES))
def test_a_bad_controller_is_named_by_its_key(case, tmp_path, capsys):
    """The model file alone (load_model) and through diagnose --model: the same one line."""
    from experiments.model_files import load_model

    text, expected = CONTROLLER_CASES[case]
    path = tmp_path / "model.yaml"
    path.write_text(f"ts: 1.0e-4\nplant: {{mass: 18.8}}\ncontroller: {text}\n")
    with pytest.raises(UserError) as info:
        load_model(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "expected LinearController or" not in message
    for text in expected:
        assert text in message, message
    record = tmp_path / "rec.npz"
    t = np.arange(4000) * TS
    y = 0.01 * np.sin(2 * np.pi * 5 * t)
    save_npz(Run(t=t, r=y, y=y + 1e-7, u=10 * np.cos(2 * np.pi * 5 * t)), record)
    code, lines = _cli(["diagnose", record, "--model", path, "--out", tmp_path / "out"], capsys)
    assert code == 2 and lines == [f"clm-sim: error: {message}"], lines
    assert not (tmp_path / "out").exists()


def _moving_record(path):
    """A record that passes diagnose's guards (motion both ways, friction, a spring)."""
    t = np.arange(20000) * 1e-3
    y = 0.1 * np.sin(2 * t)
    save_npz(Run(t=t, r=y, y=y, u=-4 * y + 0.2 * np.cos(2 * t) + np.sign(np.cos(2 * t))), path)
    return path


def _diagnosis_json(path, ts=1e-3):
    """A diagnosis.json as ``clm-sim diagnose`` writes it (the keys that matter here)."""
    path.write_text(json.dumps({
        "findings": [], "unexplained": [], "gain": {},
        "model": {"name": "LIP from x.npz", "mass": 1.0, "viscous": 0.0, "coulomb": 0.0,
                  "stiffness": 0.0, "effects": []},
        "extended_model": {"mass": 0.05, "viscous": 0.2, "coulomb": 1.0, "stiffness": 4.0,
                           "effects": []},
        "record": {"source": "x.npz", "samples": 20000, "sample_time_s": ts}}))
    return path


def test_diagnose_takes_a_diagnosis_json_as_its_model(tmp_path, capsys):
    """As simulate does: a diagnosis.json as --model is its extended model (diagnosing again
    against it), not a model YAML with an unknown key 'findings'."""
    from experiments.model_files import load_model

    model = _diagnosis_json(tmp_path / "diagnosis.json")
    loaded = load_model(model)
    assert loaded.plant.mass == 0.05 and loaded.controller is None and loaded.ts == 1e-3
    assert str(model) in loaded.name
    record = _moving_record(tmp_path / "x.npz")
    code, _ = _cli(["diagnose", record, "--model", model, "--out", tmp_path / "out"], capsys)
    assert code == 0
    written = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert written["model"]["mass"] == 0.05 and str(model) in written["model"]["name"]


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".csv"])
@pytest.mark.parametrize("command", ["simulate", "diagnose --model", "export-ff", "run"])
def test_a_record_given_as_the_model_is_named_a_record(tmp_path, capsys, suffix, command):
    """Not 'cannot read (UnicodeDecodeError)': the file is a record, and a model (a config) is
    JSON or YAML."""
    from clm_sim.records.write import convert

    record = _moving_record(tmp_path / "x.npz")
    model = record if suffix == ".npz" else convert(record, suffix[1:],
                                                    tmp_path / f"m{suffix}")[0]
    argv = {"simulate": ["simulate", model, record],
            "diagnose --model": ["diagnose", record, "--model", model],
            "export-ff": ["export-ff", model, "--to", "c"],
            "run": ["run", model]}[command] + ["--out", tmp_path / "out"]
    code, lines = _cli(argv, capsys)
    assert code == 2 and len(lines) == 1, lines
    expected = {"export-ff": "not a clm-sim feedforward", "run": "not a YAML file"}.get(
        command, "not a model file")
    assert lines[0].startswith(f"clm-sim: error: {model}: a record ({suffix}), {expected}"), \
        lines[0]
    if command in ("simulate", "diagnose --model"):
        assert ".json" in lines[0] and ".yaml" in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("ts", [float("nan"), float("inf"), -1e-4])
def test_export_refuses_a_sample_time_that_is_no_number_even_beside_the_files(saved, tmp_path,
                                                                              ts):
    """A NaN ts contradicts no stored one: it was ignored silently where the model has its own."""
    from experiments.cli.export_ff import export

    with pytest.raises(UserError, match="ts: expected a sample time"):
        export(saved / "lip.json", "c", tmp_path / "out", ts=ts)
    assert not (tmp_path / "out").exists()
