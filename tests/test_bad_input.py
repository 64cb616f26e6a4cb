"""Bad input, tried systematically: every malformed config and data file below is fed to every
command that reads that kind of input, and each must give exactly one stderr line naming the
problem, exit code 2, nothing on stdout and no file written.

The commands come from the CLI parser at test time, so a new command fails
``test_every_command_is_covered`` until it is added to ``CONFIG_COMMANDS`` or ``DATA_COMMANDS``.
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import scipy.sparse

from clm_sim.records.write import save_npz
from clm_sim.run import Run
from experiments.cli import main, parser

ROOT = Path(__file__).resolve().parents[1]  # subprocesses run this checkout's code
TS = 1e-4
N = 400


def _signals(n: int = N) -> dict[str, np.ndarray]:
    t = np.arange(n) * TS
    r = 0.01 * np.sin(2 * np.pi * 5 * t)
    return {"t": t, "r": r, "y": r + 1e-7, "u": 10 * np.cos(2 * np.pi * 5 * t)}


def _csv(sig: dict[str, np.ndarray]) -> str:
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack(list(sig.values())), delimiter=",", fmt="%.17g",
               header=",".join(sig), comments="")
    return buf.getvalue()


def _with(**changes):
    sig = _signals()
    for name, edit in changes.items():
        sig[name] = edit(sig[name].copy())
    return _csv(sig)


def _set(index, value):
    def edit(x):
        x[index] = value
        return x
    return edit


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _npy_bytes(array) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _mat_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    scipy.io.savemat(buf, arrays)
    return buf.getvalue()


# name: (file name, content: str, bytes or None for a missing file, text the message must hold)
BAD_DATA = {
    "empty file": ("rec.csv", "", "empty file"),
    "header only": ("rec.csv", "t,r,y,u\n", "no data rows"),
    "truncated csv": ("rec.csv", _csv(_signals())[:-30], "cannot read as CSV"),
    "truncated npz": ("rec.npz", _npz_bytes(**_signals())[:900], "cannot read as NPZ"),
    "truncated mat": ("rec.mat", _mat_bytes(**_signals())[:700], "cannot read as MAT"),
    "binary garbage": ("rec.csv", bytes(range(256)) * 4, "cannot read as CSV"),
    "no header": ("rec.csv", _csv(_signals()).split("\n", 1)[1], "header"),
    "header and rows disagree": ("rec.csv", "t,r,y,u,e\n" + _csv(_signals()).split("\n", 1)[1],
                                 "header has 5 columns"),
    "missing column": ("rec.csv", _csv({k: v for k, v in _signals().items() if k != "u"}),
                       "missing column 'u'"),
    "NaN in position": ("rec.csv", _with(y=_set(17, np.nan)), "'y' holds NaN"),
    "inf in force": ("rec.csv", _with(u=_set(3, np.inf)), "'u' holds NaN or inf"),
    "duplicated time stamps": ("rec.csv", _with(t=_set(10, 9 * TS)), "strictly increasing"),
    "time going backwards": ("rec.csv", _with(t=lambda t: t[::-1].copy()), "strictly increasing"),
    "sample-time jump": ("rec.csv", _with(t=lambda t: np.where(t > 0.02, t + TS, t)),
                         "not uniformly sampled"),
    "time stamps in ms": ("rec.csv", _with(t=lambda t: t * 1e3), "in ms"),
    "position in mm": ("rec.csv", _with(y=lambda y: y * 1e4, r=lambda r: r * 1e4),  # 0.1 m
                       "positions must be in m"),
    "too short": ("rec.csv", _csv(_signals(50)), "too short"),
    "columns of unequal length": ("rec.npz", _npz_bytes(**{**_signals(), "u": np.zeros(N - 1)}),
                                  "'u' has 399 samples"),
    "pickled object array": ("rec.npz", _npz_bytes(**{**_signals(),
                                                      "u": np.array([object()] * N)}),
                             "cannot read as NPZ"),
    "matrix instead of a column": ("rec.mat", _mat_bytes(**{**_signals(), "y": np.ones((N, 2))}),
                                   "must be a vector"),
    "unknown format": ("rec.txt", _csv(_signals()), "unknown record format"),
    "scalar signal in npz": ("rec.npz", _npz_bytes(**{**_signals(), "y": np.array(0.1)}),
                             "single number"),
    "structured npz array": ("rec.npz", _npz_bytes(**{**_signals(), "u": np.zeros(
        N, dtype=[("a", float), ("b", int)])}), "struct or record"),
    "text signal in npz": ("rec.npz", _npz_bytes(**{**_signals(), "u": np.array(["x"] * N)}),
                           "holds text"),
    "complex force": ("rec.npz", _npz_bytes(**{**_signals(), "u": _signals()["u"] * (1 + 1j)}),
                      "complex"),
    "MAT char signal": ("rec.mat", _mat_bytes(**{**_signals(), "u": "volts"}), "holds text"),
    "MAT cell signal": ("rec.mat", _mat_bytes(**{**_signals(), "u": np.array(
        [[np.ones(3)], [np.zeros(2)]], dtype=object)}), "cells"),
    "MAT struct signal": ("rec.mat", _mat_bytes(**{**_signals(), "u": {"a": 1.0, "b": 2.0}}),
                          "struct"),
    "MAT sparse signal": ("rec.mat", _mat_bytes(**{**_signals(), "u": scipy.sparse.csc_matrix(
        _signals()["u"][:, None])}), "dense numeric"),
    "time step of 1e-12 s": ("rec.csv", _with(t=lambda t: t * 1e-8), "faster than any servo"),
    "force of 1e308": ("rec.csv", _with(u=_set(7, 1e308)), "must be a force in N"),
    "missing file": ("rec.csv", None, "not found"),
    "npy renamed npz": ("rec.npz", _npy_bytes(_signals()["u"]), "not an .npz archive"),
    # a European spreadsheet's CSV: the separator and the decimal mark are named
    "decimal commas and semicolons": ("rec.csv", _csv(_signals()).replace(",", ";")
                                      .replace(".", ","), ["line 1", "';'",
                                                           "line 2 has decimal commas ('9,9999999999999995e-08')"]),
    "semicolons": ("rec.csv", _csv(_signals()).replace(",", ";"), ["line 1", "';'"]),
    "a cell that is no number": ("rec.csv", _csv(_signals()).replace("\n", "\n0.0005,0,0,1.5x\n", 1),
                                 ["line 2, column 4 (u)", "'1.5x' is not a number"]),
    "decimal commas and commas": ("rec.csv", "t,r,y,u\n" + "0,0,0,2,5\n" * N,
                                  ["header has 4 columns, rows have 5", "decimal commas"]),
}

# Config parts that every config command reads (diagnose reads only plant and controller).
SHORT = ("references:\n  r1: {points_m: [0.0, 0.01, 0.0], dwell_s: 0.05}\n"
         "  r2: {points_m: [0.0, 0.02, 0.0], dwell_s: 0.05}\ntraining: {repeats: 1}\n")
# name: (content, text the message must hold, commands: "all", "experiment" = run and sweep
# (the parts an experiment reads beyond plant and controller), or "sweep" (a sweep: section))
BAD_CONFIGS = {
    "unknown top-level key": ("name: x\nsede: 3\n", "sede", "all"),
    "unknown nested key": ("name: x\nplant:\n  mas: 18.8\n", "plant.mas", "all"),
    "wrong type": ("name: x\nplant:\n  mass: heavy\n", "plant.mass", "all"),
    "number without a dot": ("name: x\nplant:\n  mass: 2e1\n", "write 2.0e+1", "all"),
    "negative mass": ("name: x\nplant:\n  mass: -18.8\n", "mass must be > 0", "all"),
    "zero mass": ("name: x\nplant:\n  mass: 0\n", "mass must be > 0", "all"),
    "negative viscous friction": ("name: x\nplant:\n  viscous: -1.0\n", "viscous", "all"),
    "NaN parameter": ("name: x\nplant:\n  coulomb: .nan\n", "finite", "all"),
    "encoder resolution in um given as m": ("name: x\nplant:\n  encoder_resolution: 1\n",
                                            "encoder_resolution", "all"),
    "negative sample time": ("ts: -1.0e-4\n", "ts", "all"),
    "zero sample time": ("ts: 0\n", "ts", "all"),
    "empty file": ("", "expected a mapping", "all"),
    "truncated YAML": ("name: x\nplant:\n  mass: [18.8, \n", "invalid YAML", "all"),
    "python object tag": ('!!python/object/apply:os.system ["echo owned"]\n',
                          "could not determine a constructor", "all"),
    "python object in a value": ("plant: !!python/object:clm_sim.plant.Plant {mass: 1}\n",
                                 "could not determine a constructor", "all"),
    "duplicated key": ("name: x\nseed: 1\nseed: 2\n", "duplicate key 'seed'", "all"),
    "list instead of mapping": ("- r1\n- r2\n", "expected a mapping", "all"),
    "binary garbage": (bytes(range(128, 256)) * 4, "cannot read", "all"),
    "missing file": (None, "not found", "all"),
    "unknown effect type": ("name: x\nplant:\n  effects:\n    - type: magnetism\n", "magnetism",
                            "all"),
    "zero effect period": ("name: x\nplant:\n  effects:\n    - {type: cogging, amplitude: 1.0, "
                           "period: 0.0}\n", "period", "all"),
    "friction dip below zero": ("name: x\nplant:\n  coulomb: 2.0\n  effects:\n    - {type: "
                                "stribeck, peak: -3.0, velocity: 0.01}\n", "stribeck peaks",
                                "all"),
    "unknown feedforward kind": ("feedforwards:\n  - kind: magic\n", "feedforwards[0].kind",
                                 "all"),
    "pgnn without neurons": ("feedforwards:\n  - {kind: pgnn, training: sequential}\n",
                             "hidden", "all"),
    "negative dither": ("training:\n  dither:\n    std_n: -5.0\n", "std_n", "all"),
    "seed not an integer": ("seed: 1.5\n", "seed", "all"),
    "zero repeats": ("training:\n  repeats: 0\n", "repeats", "all"),
    "undefined reference": ("training:\n  reference: r3\n", "r3", "all"),
    "negative crossover": ("name: x\ncontroller:\n  crossover_hz: -30.0\n", "crossover_hz",
                           "all"),
    "filter above Nyquist of ts": ("ts: 1.0e-3\nfeatures:\n  regression_lowpass_hz: 600.0\n",
                                   "Nyquist", "experiment"),
    "reference points in mm": ("references:\n  r1: {points_m: [0.0, 100.0, 0.0]}\n"
                               "  r2: {points_m: [0.0, 170.0, 0.0]}\n", "in mm",
                               "experiment"),
    "open training reference repeated": ("references:\n  r1: {points_m: [0.0, 0.1]}\n"
                                         "  r2: {points_m: [0.0, 0.2]}\n",
                                         "must end where it starts", "experiment"),
    "negative seed": ("seed: -1\n", "non-negative", "all"),
    "dither held for 1e12 samples": ("training:\n  dither: {hold_samples: 1000000000000}\n",
                                     "hold_samples", "experiment"),
    "crawling reference": ("references:\n  r1: {points_m: [0.0, 0.1, 0.0], max_velocity: "
                           "1.0e-9}\n  r2: {points_m: [0.0, 0.1]}\n", "training",
                           "experiment"),
    "dwell of 1e9 s": ("references:\n  r1: {points_m: [0.0, 0.1, 0.0], dwell_s: 1.0e+9}\n"
                       "  r2: {points_m: [0.0, 0.1]}\n", "exceeds the limit", "experiment"),
    "jerk of 1e-12": ("references:\n  r1: {points_m: [0.0, 0.1, 0.0]}\n  r2: {points_m: "
                      "[0.0, 0.1, 0.0], max_jerk: 1.0e-12}\n", "references.r2",
                      "experiment"),
    "1000 repeats of a long reference": ("training: {repeats: 1000}\n", "training",
                                         "experiment"),
    "100000 seeds": ("feedforwards:\n  - {kind: lip, seeds: 100000}\n", "seeds",
                     "experiment"),
    "1e9 iterations": ("feedforwards:\n  - {kind: pgnn, training: sequential, hidden: 4, "
                       "pgnn: {max_iter: 1000000000}}\n", "max_iter", "experiment"),
    "1e6 restarts": ("feedforwards:\n  - {kind: pgnn, training: sequential, hidden: 4, "
                     "pgnn: {restarts: 1000000}}\n", "restarts", "experiment"),
    "100000 neurons": ("feedforwards:\n  - {kind: pgnn, training: sequential, "
                       "hidden: 100000}\n", "hidden", "experiment"),
    "20000 nested brackets": ("name: " + "[" * 20000 + "]" * 20000 + "\n", "nesting deeper",
                              "all"),
    "alias bomb under a known key": (
        "a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
        "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
        "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]\n"
        "g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f]\nh: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g]\n"
        "name: *h\n", "aliases are expanded", "all"),
    # 5000 values: their text (25 kB) is 25 times the 1000 characters a CLI line may hold, so
    # the excerpt is what keeps the line short; pure-Python YAML reads about 0.1 ms a value
    # (50000 took 2-5 s per command, twice for a study, which reads its config twice)
    "long wrong value": ("name: x\nplant:\n  mass: [" + ", ".join(["1.0"] * 5000) + "]\n",
                         "plant.mass: expected a number, got list [1.0, 1.0, 1.0, 1.0, ...]",
                         "all"),
    "huge grid": (SHORT + "sweep:\n  grid:\n    seed: {linspace: [1, 100000, 100000]}\n"
                  "    plant.mass: {linspace: [1, 10, 1000]}\n", "exceed the limit", "sweep"),
    "unknown grid key": (SHORT + "sweep:\n  grid:\n    plant.mas: [1.0, 2.0]\n",
                         "unknown key 'mas'", "sweep"),
    "bad grid value": (SHORT + "sweep:\n  grid:\n    plant.encoder_resolution: [1.0e-7, -1.0]\n",
                       "encoder_resolution", "sweep"),
    "grid index out of range": (SHORT + "sweep:\n  grid:\n    feedforwards[4].lambda: [0.1]\n",
                                "index 4 out of range", "sweep"),
    "unknown sweep key": (SHORT + "sweep:\n  grdi:\n    seed: [1, 2]\n", "sweep.grdi", "sweep"),
    "grid not a mapping": (SHORT + "sweep:\n  grid: [seed, 1, 2]\n", "sweep.grid", "sweep"),
}


@pytest.fixture(scope="session")
def valid_record(tmp_path_factory) -> Path:
    """A record every data command accepts (needed where the config is the bad input)."""
    path = tmp_path_factory.mktemp("valid") / "record.npz"
    save_npz(Run(**_signals(4000)), path)
    return path


# How each command is given a bad config (cfg) or a bad data file (data); out: where it would
# write. ``valid`` is a good record for commands that need one besides the bad config.
CONFIG_COMMANDS = {
    "run": lambda cfg, out, valid: ["run", cfg, "--out", out, "--quiet"],
    "sweep": lambda cfg, out, valid: ["sweep", cfg, "--out", out, "--quiet", "--workers", "1"],
    "diagnose": lambda cfg, out, valid: ["diagnose", valid, "--model", cfg, "--out", out],
    "study": lambda cfg, out, valid: ["study", cfg, "--out", out, "--quiet"],
}
DATA_COMMANDS = {
    "identify": lambda data, out: ["identify", data, "--out", out],
    "export": lambda data, out: ["export", data, "--out", out + ".csv"],
    "diagnose": lambda data, out: ["diagnose", data, "--out", out],
    "simulate": lambda data, out: ["simulate", str(Path(__file__).resolve().parents[1]
                                                   / "experiments"
                                                   / "configs" / "emps_model.yaml"),
                                   data, "--out", out],
}


# Commands that read a saved model (export-ff), and bad model files: (name, content, text).
MODEL_COMMANDS = {
    "export-ff": lambda model, out: ["export-ff", model, "--to", "c", "--out", out],
}
_LIP = '"kind": "lip", "mass": 18.8, "viscous": 30.0, "coulomb": 5.0, "stiffness": 0.0'
BAD_MODELS = {
    "missing model": ("lip.json", None, "no such model file"),
    "empty model": ("lip.json", "", "not a clm-sim feedforward"),
    "model is a list": ("lip.json", "[1, 2]", "not a clm-sim feedforward"),
    "record as model": ("rec.csv", _csv(_signals()), "not a clm-sim feedforward"),
    "lip without mass": ("lip.json", '{"kind": "lip", "viscous": 1, "coulomb": 1, '
                         '"stiffness": 0, "ts": 0.0001}', "mass"),
    "unknown effect": ("lip.json", "{" + _LIP + ', "ts": 0.0001, "effects": [{"type": "warp"}]}',
                       "unknown effect 'warp'"),
    "pre-sliding effect": ("lip.json", "{" + _LIP + ', "ts": 0.0001, "effects": '
                           '[{"type": "presliding"}]}', "pre-sliding"),
    "sample time out of range": ("lip.json", "{" + _LIP + ', "ts": 5}', "sample time"),
    "no sample time": ("lip.json", "{" + _LIP + "}", "--ts"),
    "pt without json": ("net.pt", bytes(range(256)), "needs net.json"),
    # a feedforward with a mass <= 0 pushes the machine the wrong way on every acceleration
    "negative mass": ("lip.json", "{" + _LIP.replace("18.8", "-18.8") + ', "ts": 0.0001}',
                      "mass -18.8 kg"),
    "zero mass": ("lip.json", "{" + _LIP.replace("18.8", "0") + ', "ts": 0.0001}', "mass 0 kg"),
    "parameters disagree with coefficients": (
        "lip.json", "{" + _LIP.replace("18.8", "99") + ', "ts": 0.0001, "coefficients": '
        '{"mass": 18.8, "viscous": 30.0, "coulomb": 5.0, "stiffness": 0.0}}', "coefficients.mass"),
    "offset disagrees with its coefficient": (
        "lip.json", "{" + _LIP + ', "ts": 0.0001, "effects": [{"type": "force_offset", '
        '"force": 2.5}], "coefficients": {"mass": 18.8, "viscous": 30.0, "coulomb": 5.0, '
        '"stiffness": 0.0, "offset": -1.0}}', "coefficients.offset"),
}
# Commands that write nothing: given bad files they must still answer in one line.
COMPARE_CASES = {
    "missing files": (None, None, "cannot read"),
    "garbage table.json": ("| a |\n", bytes(range(256)), "cannot read"),
    "json that is not a table": ("| a |\n", "[1, 2]", "not a clm-sim table.json"),
}


def _parser_commands() -> set[str]:
    action = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    return set(action.choices)


PRESENT = _parser_commands()


# Commands whose inputs are neither an experiment config nor a record, with where their bad input
# is tested.
OTHER_COMMANDS = {"compare": "tests/test_reproducibility.py::test_compare_refuses_bad_files"}


def test_every_command_is_covered():
    assert PRESENT <= (set(CONFIG_COMMANDS) | set(DATA_COMMANDS) | set(MODEL_COMMANDS)
                       | set(OTHER_COMMANDS)), \
        "a new CLI command: say how it reads configs or data files in this module"


def _write(path: Path, content) -> None:
    if content is None:
        return
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)


def _check_refused(argv, tmp_path, capsys, expected: str | list[str], name: str) -> str:
    before = sorted(p.name for p in tmp_path.iterdir())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning would be a second stderr line in a terminal
        code = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2, captured.err
    assert len(lines) == 1, lines
    assert lines[0].startswith("clm-sim: error: ") and name in lines[0], lines[0]
    for text in [expected] if isinstance(expected, str) else expected:
        assert text in lines[0], lines[0]
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no partial output at all
    return lines[0]


def _config_cases():
    for case, (_, _, scope) in BAD_CONFIGS.items():
        commands = {"all": ("run", "sweep", "diagnose", "study"),
                    "experiment": ("run", "sweep", "study"),
                    "sweep": ("sweep",)}[scope]
        for command in commands:
            if command in PRESENT:
                yield pytest.param(case, command, id=f"{command}-{case}")


def _data_cases():
    for case in BAD_DATA:
        for command in DATA_COMMANDS:
            if command in PRESENT:
                yield pytest.param(case, command, id=f"{command}-{case}")


@pytest.mark.parametrize("case, command", list(_config_cases()))
def test_bad_config_is_refused(case, command, tmp_path, capsys, monkeypatch, valid_record):
    content, expected, _ = BAD_CONFIGS[case]
    cfg = tmp_path / "bad.yaml"
    _write(cfg, content)
    monkeypatch.chdir(tmp_path)  # defaults relative to the current folder would land here too
    argv = CONFIG_COMMANDS[command](str(cfg), str(tmp_path / "out"), str(valid_record))
    _check_refused(argv, tmp_path, capsys, expected, str(cfg))


@pytest.mark.parametrize("case, command", list(_data_cases()))
def test_bad_data_is_refused(case, command, tmp_path, capsys, monkeypatch):
    name, content, expected = BAD_DATA[case]
    data = tmp_path / name
    _write(data, content)
    monkeypatch.chdir(tmp_path)
    argv = DATA_COMMANDS[command](str(data), str(tmp_path / "out"))
    _check_refused(argv, tmp_path, capsys, expected, str(data))


@pytest.mark.parametrize("case, command", [pytest.param(case, command, id=f"{command}-{case}")
                                           for case in BAD_MODELS for command in MODEL_COMMANDS
                                           if command in PRESENT])
def test_bad_model_is_refused(case, command, tmp_path, capsys, monkeypatch):
    name, content, expected = BAD_MODELS[case]
    model = tmp_path / name
    _write(model, content)
    monkeypatch.chdir(tmp_path)
    argv = MODEL_COMMANDS[command](str(model), str(tmp_path / "out"))
    _check_refused(argv, tmp_path, capsys, expected, str(model))


@pytest.mark.parametrize("case", [c for c, v in BAD_CONFIGS.items() if v[2] == "sweep"][:1])
def test_run_refuses_a_sweep_config_and_points_to_sweep(case, tmp_path, capsys):
    cfg = tmp_path / "grid.yaml"
    cfg.write_text(BAD_CONFIGS[case][0])
    _check_refused(["run", str(cfg), "--out", str(tmp_path / "out")], tmp_path, capsys,
                   "clm-sim sweep", str(cfg))


@pytest.mark.parametrize("case", list(COMPARE_CASES))
def test_compare_answers_bad_files_in_one_line(case, tmp_path, capsys):
    expected_md, fresh, text = COMPARE_CASES[case]
    _write(tmp_path / "expected.md", expected_md)
    _write(tmp_path / "table.json", fresh)
    _check_refused(["compare", str(tmp_path / "expected.md"), str(tmp_path / "table.json")],
                   tmp_path, capsys, text, str(tmp_path))


def test_suite_is_large_enough():
    assert len(BAD_CONFIGS) + len(BAD_DATA) >= 30


@pytest.mark.parametrize("command, case", [("identify", "header only"), ("run", "python object tag"),
                                           ("sweep", "huge grid")])
def test_real_process_prints_one_line_and_exits_2(command, case, tmp_path):
    """The installed entry point, not just ``main``: no traceback, no warning lines."""
    if command in DATA_COMMANDS:
        name, content, expected = BAD_DATA[case]
        path = tmp_path / name
        argv = DATA_COMMANDS[command](str(path), str(tmp_path / "out"))
    else:
        content, expected, _ = BAD_CONFIGS[case]
        path = tmp_path / "bad.yaml"
        argv = CONFIG_COMMANDS[command](str(path), str(tmp_path / "out"), "unused")
    _write(path, content)
    proc = subprocess.run([sys.executable, "-m", "experiments.cli", *argv], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], proc.stderr
    assert proc.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]


@pytest.mark.parametrize("variable, content", [
    ("gtau", "volts"), ("gtau", np.array([[np.ones(2)]], dtype=object)),
    ("gtau", {"k": 35.0}), ("gtau", np.ones(3)), ("missing", None)])
def test_scale_by_a_variable_that_is_not_a_number_is_refused(variable, content, tmp_path,
                                                             capsys):
    """``--scale u=VAR`` naming text, a cell, a struct, a vector or nothing in a MAT file."""
    data = tmp_path / "rec.mat"
    extra = {} if content is None else {"gtau": content}
    data.write_bytes(_mat_bytes(**_signals(), **extra))
    _check_refused(["identify", str(data), "--scale", f"u={variable}", "--out",
                    str(tmp_path / "out")], tmp_path, capsys, "not a scalar number", str(data))


@pytest.mark.parametrize("name, content", [
    ("bom.csv", "\ufeff" + _csv(_signals())),  # Excel's "CSV UTF-8"
    ("meta_list.npz", _npz_bytes(**_signals(), meta=np.array("[1, 2]"))),
    ("meta_bad.npz", _npz_bytes(**_signals(), meta=np.array("{not json"))),
    ("real_complex.npz", _npz_bytes(**{**_signals(), "u": _signals()["u"] + 0j})),
])
def test_odd_but_valid_records_are_read(name, content, tmp_path):
    """Records that are unusual but hold what is needed are read, not refused."""
    from clm_sim.records.read import load_record

    path = tmp_path / name
    _write(path, content)
    run = load_record(path)
    np.testing.assert_array_equal(run.u, _signals()["u"])  # exact: a copy, no arithmetic


# An --out that cannot take the results: refused in one line before any work.
BAD_OUT = {
    "an existing file": (lambda tmp: tmp / "afile", "is a file, not a folder"),
    "the current folder": (lambda tmp: Path("."), "is the current folder"),
    "below a file": (lambda tmp: tmp / "afile" / "sub", "is a file, not a folder"),
}


@pytest.mark.parametrize("command", ["run", "sweep", "identify", "diagnose"])
@pytest.mark.parametrize("case", list(BAD_OUT))
def test_unusable_out_is_refused_before_the_work(case, command, tmp_path, capsys, monkeypatch,
                                                 valid_record):
    from small_config import SMALL_CONFIG

    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder")
    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL_CONFIG + ("sweep:\n  grid:\n    seed: [1, 2]\n"
                                   if command == "sweep" else ""))
    make, expected = BAD_OUT[case]
    out = str(make(tmp_path))
    argv = (CONFIG_COMMANDS[command](str(cfg), out, str(valid_record)) if command in
            ("run", "sweep") else DATA_COMMANDS[command](str(valid_record), out))
    _check_refused(argv, tmp_path, capsys, expected, out)


# --columns and --scale that cannot mean what they say, on a record holding t, r, y, u and also
# qm (a position) and gtau (a gain): (options, texts the one line must hold).
BAD_MAPS = {
    "misspelled signal": (["--columns", "Y=qm"], ["'Y'", "t, r, y, y_true, u"]),
    "unknown signal": (["--columns", "q=y"], ["'q'", "t, r, y, y_true, u"]),
    "column not in the file": (["--columns", "u_ff=pulsez"], ["'pulsez'", "u_ff"]),
    "scaled column not in the file": (["--columns", "u_ff=pulsez", "--scale", "u_ff=gtau"],
                                      ["'pulsez'"]),
    "signal mapped twice": (["--columns", "y=qm,y=y"], ["--columns", "'y' given twice"]),
    "signal scaled twice": (["--scale", "u=2,u=1"], ["--scale", "'u' given twice"]),
    "scale of an unknown signal": (["--scale", "x=2"], ["'x'", "t, r, y, y_true, u"]),
    "scale of a signal the file lacks": (["--scale", "u_ff=2"], ["'u_ff'", "no column"]),
    "scale that underflows": (["--scale", "u=1e-200"], ["scale for 'u'", "1e-200"]),
    "scale that overflows": (["--scale", "u=1e308"], ["scale for 'u'", "1e+308"]),
}


@pytest.fixture(scope="session")
def mapped_record(tmp_path_factory) -> Path:
    """A valid record with an extra position column ``qm`` and a scalar gain ``gtau``."""
    path = tmp_path_factory.mktemp("mapped") / "rec.npz"
    sig = _signals(4000)
    path.write_bytes(_npz_bytes(**sig, qm=sig["y"], gtau=np.array(35.15)))
    return path


@pytest.mark.parametrize("command", [c for c in DATA_COMMANDS if c != "export"])
@pytest.mark.parametrize("case", list(BAD_MAPS))
def test_a_column_map_that_cannot_be_meant_is_refused(case, command, tmp_path, capsys,
                                                       monkeypatch, mapped_record):
    """A misspelled signal or column, a duplicate or a scale out of float range is one line
    naming it, never ignored (a typo in ``u_ff`` ran the twin without its known input)."""
    options, texts = BAD_MAPS[case]
    monkeypatch.chdir(tmp_path)
    argv = DATA_COMMANDS[command](str(mapped_record), str(tmp_path / "out")) + options
    name = "--" if case.endswith("twice") else str(mapped_record)
    _check_refused(argv, tmp_path, capsys, texts, name)


@pytest.mark.parametrize("section, expected", [
    ("columns: {yy: y}", ["'yy'", "t, r, y, y_true, u"]),
    ("columns: {u_ff: pulsez}", ["missing column 'pulsez'"]),
    ("scale: {u: 1.0e-200}", ["scale for 'u'"])])
def test_a_run_config_maps_columns_as_strictly_as_the_options(section, expected, tmp_path, capsys,
                                                              monkeypatch, valid_record):
    """``data: {columns: ...}`` goes through the same check as ``--columns``."""
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "dat.yaml"
    cfg.write_text(f"name: dat\nseed: 1\ndata:\n  training: {valid_record}\n  {section}\n"
                   f"feedforwards:\n  - kind: lip\n")
    _check_refused(["run", str(cfg), "--out", str(tmp_path / "out"), "--quiet"], tmp_path,
                   capsys, expected, str(valid_record))


# An input inside the --out folder it would replace: the earlier result there (its marker file)
# is deleted with everything beside it, the input included. (command, marker, argv from
# (input folder = out, valid record, input file)).
_LIP_MODEL = "{" + _LIP + ', "ts": 0.0001}'
INPUT_INSIDE_OUT = {
    "run": ("config.resolved.yaml", "my.yaml", None,
            lambda out, rec, inp: ["run", inp, "--out", out, "--quiet"]),
    "study": ("mechanism.json", "my.yaml", "mechanism",
              lambda out, rec, inp: ["study", inp, "--out", out, "--quiet"]),
    "simulate": ("scores.json", "lip.json", "lip",
                 lambda out, rec, inp: ["simulate", inp, rec, "--out", out]),
    "diagnose": ("diagnosis.json", "lip.json", "lip",
                 lambda out, rec, inp: ["diagnose", rec, "--model", inp, "--out", out]),
    "diagnose-record": ("diagnosis.json", "rec.npz", "record",
                        lambda out, rec, inp: ["diagnose", inp, "--out", out]),
    "export-ff": ("export.json", "mymodel.json", "lip",
                  lambda out, rec, inp: ["export-ff", inp, "--to", "c", "--out", out]),
}


@pytest.mark.parametrize("case", list(INPUT_INSIDE_OUT))
def test_an_input_inside_the_out_it_would_replace_is_refused(case, tmp_path, capsys,
                                                             monkeypatch, valid_record):
    from small_config import SMALL_CONFIG, tiny_mechanism

    monkeypatch.chdir(tmp_path)
    marker, name, kind, make = INPUT_INSIDE_OUT[case]
    out = tmp_path / "out"
    out.mkdir()
    (out / marker).write_text("{}")  # an earlier result of this command
    (out / "notes.txt").write_text("mine")
    inp = out / name
    _write(inp, {None: SMALL_CONFIG, "mechanism": tiny_mechanism(), "lip": _LIP_MODEL,
                 "record": valid_record.read_bytes()}[kind])
    before = sorted(p.name for p in out.iterdir())
    _check_refused(make(str(out), str(valid_record), str(inp)), tmp_path, capsys,
                   f"holds the input {inp}", str(out))
    assert sorted(p.name for p in out.iterdir()) == before  # nothing deleted


# A folder that merely holds the file name of a result (an earlier "marker"), beside a user's
# file: clm-sim did not write it (no manifest of its files), so it is not replaced and nothing
# in it is deleted. (command, the result's file name, argv from (out, record, config, model)).
NOT_CLM_SIMS = {
    "run": ("config.resolved.yaml", lambda out, rec, cfg, model: ["run", cfg, "--out", out,
                                                                  "--quiet"]),
    "simulate": ("scores.json", lambda out, rec, cfg, model: ["simulate", model, rec, "--out",
                                                              out]),
    "identify": ("lip.json", lambda out, rec, cfg, model: ["identify", rec, "--out", out]),
    "diagnose": ("diagnosis.json", lambda out, rec, cfg, model: ["diagnose", rec, "--model",
                                                                 model, "--out", out]),
    "export-ff": ("export.json", lambda out, rec, cfg, model: ["export-ff", model, "--to", "c",
                                                               "--out", out]),
    "study": ("mechanism.json", lambda out, rec, cfg, model: ["study", cfg.replace(
        "small", "mech"), "--out", out, "--quiet"]),
}


@pytest.mark.parametrize("case", list(NOT_CLM_SIMS))
@pytest.mark.parametrize("extra", ["precious.txt", "figures/mine.png", ".hidden"])
def test_a_folder_clm_sim_did_not_write_is_never_replaced(case, extra, tmp_path, capsys,
                                                          monkeypatch, valid_record):
    from small_config import SMALL_CONFIG, tiny_mechanism

    monkeypatch.chdir(tmp_path)
    marker, make = NOT_CLM_SIMS[case]
    (tmp_path / "small.yaml").write_text(SMALL_CONFIG)
    (tmp_path / "mech.yaml").write_text(tiny_mechanism())
    (tmp_path / "lip.json").write_text("{" + _LIP + ', "ts": 0.0001}')
    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)
    (out / marker).write_text("{}")
    (out / extra).write_text("mine")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    _check_refused(make(str(out), str(valid_record), str(tmp_path / "small.yaml"),
                        str(tmp_path / "lip.json")), tmp_path, capsys,
                   "not written by clm-sim", str(out))
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("to", ["csv", "mat"])
@pytest.mark.parametrize("target", ["input", "other file", "sidecar"])
def test_export_writes_over_no_file(to, target, tmp_path, capsys, monkeypatch, valid_record):
    """``export x.csv`` with the default --out would write over its own input (and lose its
    columns beyond the signals); no existing file is ever written over."""
    monkeypatch.chdir(tmp_path)
    source = tmp_path / f"rec.{'mat' if to == 'csv' else 'csv'}"
    mine = tmp_path / f"mine.{to}"
    mine.write_text("mine")
    if target == "input":
        source = tmp_path / f"rec.{to}"
        assert main(["export", str(valid_record), "--to", to, "--out", str(source)]) == 0
        capsys.readouterr()
        argv = ["export", str(source), "--to", to]
        sidecar = source.with_name(source.name + ".meta.json")
        sidecar.unlink(missing_ok=True)
    else:
        assert main(["export", str(valid_record), "--to", "mat" if to == "csv" else "csv",
                     "--out", str(source)]) == 0
        capsys.readouterr()
        if target == "sidecar" and to == "csv":
            (tmp_path / "new.csv.meta.json").write_text("mine")
            argv = ["export", str(source), "--to", to, "--out", str(tmp_path / "new.csv")]
        else:
            argv = ["export", str(source), "--to", to, "--out", str(mine)]
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    _check_refused(argv, tmp_path, capsys, "clm-sim export", "")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("command", ["run", "simulate", "export-ff", "diagnose", "identify"])
def test_an_out_that_is_a_loop_of_links_is_refused(command, tmp_path, capsys, monkeypatch,
                                                   valid_record):
    from small_config import SMALL_CONFIG

    monkeypatch.chdir(tmp_path)
    (tmp_path / "loopA").symlink_to("loopB")
    (tmp_path / "loopB").symlink_to("loopA")
    cfg, model = tmp_path / "small.yaml", tmp_path / "lip.json"
    cfg.write_text(SMALL_CONFIG)
    model.write_text(_LIP_MODEL)
    out = str(tmp_path / "loopA")
    argv = {"run": ["run", str(cfg), "--out", out, "--quiet"],
            "simulate": ["simulate", str(model), str(valid_record), "--out", out],
            "export-ff": ["export-ff", str(model), "--to", "c", "--out", out],
            "diagnose": ["diagnose", str(valid_record), "--out", out],
            "identify": ["identify", str(valid_record), "--out", out]}[command]
    _check_refused(argv, tmp_path, capsys, "loop of symbolic links", out)


@pytest.mark.parametrize("argv, option", [
    (["sweep", "x.yaml", "--workers", "0"], "--workers"),
    (["study", "x.yaml", "--workers", "0"], "--workers"),
    (["export-ff", "m.json", "--to", "c", "--out", "o", "--count-m", "-1e-12"], "--count-m"),
    # a NaN --ts was ignored where the model has its own (NaN contradicts nothing)
    (["export-ff", "m.json", "--to", "c", "--out", "o", "--ts", "nan"], "--ts"),
    (["export-ff", "m.json", "--to", "c", "--out", "o", "--ts", "inf"], "--ts"),
    (["export", "run.npz", "--to", "npz"], "--to"),
    (["identify", "rec.npz", "--filter-order", "four"], "--filter-order"),
    (["identify"], "data"),
    (["frobnicate"], "frobnicate"),
    ([], "command"),
])
def test_an_option_error_is_one_line(argv, option, tmp_path, capsys):
    """argparse's errors as every other mistake: one line naming the option, no usage block."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert info.value.code == 2
    assert len(lines) == 1, lines
    assert lines[0].startswith("clm-sim: error: ") and option in lines[0], lines[0]
    assert captured.out == ""


def test_a_scheduler_without_the_dask_backend_is_refused(tmp_path, capsys):
    """--scheduler is a Dask address: with the local backend it was silently ignored."""
    from small_config import SMALL_CONFIG

    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL_CONFIG)
    _check_refused(["sweep", str(cfg), "--scheduler", "tcp://127.0.0.1:8786", "--out",
                    str(tmp_path / "out"), "--quiet"], tmp_path, capsys,
                   ["--scheduler tcp://127.0.0.1:8786", "--backend dask"], "--scheduler")


def _stamped(t: np.ndarray, path: Path) -> Path:
    """A record at ``t`` (any dtype, any offset): a 5 Hz sine with its force."""
    s = np.arange(len(t)) * TS
    r = 0.01 * np.sin(2 * np.pi * 5 * s)
    path.write_bytes(_npz_bytes(t=t, r=r, y=r + 1e-7, u=10 * np.cos(2 * np.pi * 5 * s)))
    return path


# Time stamps that are uniform but rounded by their type: float32 (a logger's single precision,
# 2 s at 10 kHz: its spacing there is 0.24 % of the step) and Unix-epoch seconds in float64
# (spacing 2.4e-7 s at 1.7e9 s: 0.24 % of 0.1 ms); a step judged against 0.1 % alone refused them.
ROUNDED_STAMPS = {
    "float32": lambda t: t.astype(np.float32),
    "Unix epoch": lambda t: 1.7e9 + t,
    "Unix epoch, 20 s": lambda t: 1.7e9 + 10 * t,  # 1 ms: half a second's resolution anyway
}


@pytest.mark.parametrize("case", list(ROUNDED_STAMPS))
def test_time_stamps_rounded_by_their_type_are_read(case, tmp_path):
    from clm_sim.records.read import load_record

    step = 10 * TS if case.endswith("20 s") else TS
    run = load_record(_stamped(ROUNDED_STAMPS[case](np.arange(20000) * TS), tmp_path / "r.npz"))
    assert run.ts == pytest.approx(step, rel=1e-6)  # the mean step: the rounding averages out


# Time stamps that cannot show a uniform sampling, or are not uniform: refused, the dtype or the
# offset named where it is the cause.
COARSE_STAMPS = {
    "float32 at 40 s": (lambda t: (40.0 + t).astype(np.float32),  # 3.8e-6 s apart there
                        ["float32", "3.8 % of the", "float64"]),
    "epoch at 100 kHz": (lambda t: 1.7e9 + 0.1 * t, ["1.7e+09 s", "t - t[0]"]),
    "float16": (lambda t: t.astype(np.float16), ["strictly increasing", "float16"]),
    "float32 with a jump": (lambda t: np.where(t > 1.0, t + TS, t).astype(np.float32),
                            ["not uniformly sampled"]),
    # 0.3 % jitter in the first 0.1 s, where float32 resolves 0.007 % of the step; its stamps
    # reach 2 s, where the type's spacing is 0.24 %: judged step by step, not by the largest.
    "float32, jitter early": (lambda t: np.where((t < 0.1) & (np.arange(len(t)) % 2 == 1),
                                                 t + 0.003 * TS, t).astype(np.float32),
                              ["not uniformly sampled"]),
    "constant": (lambda t: np.zeros_like(t), ["strictly increasing"]),
    "decreasing": (lambda t: -t, ["strictly increasing"]),
}


@pytest.mark.parametrize("case", list(COARSE_STAMPS))
def test_time_stamps_too_coarse_or_uneven_are_refused(case, tmp_path, capsys):
    edit, expected = COARSE_STAMPS[case]
    data = _stamped(edit(np.arange(20000) * TS), tmp_path / "r.npz")
    line = _check_refused(["identify", str(data), "--out", str(tmp_path / "out")], tmp_path,
                          capsys, expected, str(data))
    if case in ("float32 with a jump", "float32, jitter early", "constant", "decreasing"):
        assert "float32" not in line and "%" not in line, line  # not blamed on the type


def test_integer_epoch_nanoseconds_scaled_to_seconds_are_read(tmp_path):
    """int64 nanoseconds since 1970 (1.7e18, beyond float64's exact integers) scaled by 1e-9:
    uniform but for float64's rounding of them, and read (the review found them refused)."""
    from clm_sim.records.read import load_record

    ns = 1_700_000_000_000_000_000 + np.arange(20000, dtype=np.int64) * 100_000
    run = load_record(_stamped(ns, tmp_path / "r.npz"), scale={"t": 1e-9})
    assert run.ts == pytest.approx(TS, rel=1e-6)


def test_a_missing_column_among_hundreds_is_named_in_a_short_line(tmp_path, capsys):
    """A .mat-like file with 500 variables: the missing-column line lists 30 of them and how
    many more, not all (a line of thousands of characters is no longer one line to read)."""
    sig = _signals(4000)
    extra = {f"var{k:03d}": np.arange(4000.0) for k in range(500)}
    data = tmp_path / "wide.npz"
    data.write_bytes(_npz_bytes(**sig, **extra))
    line = _check_refused(["identify", str(data), "--columns", "u=force", "--out",
                           str(tmp_path / "out")], tmp_path, capsys,
                          ["missing column 'force'", "more)"], str(data))
    assert len(line) < 1000, len(line)
