"""Hostile model files, generated: a LIP parameter file (``lip.json``) or a model YAML
(``plant:``, effects, controller) with keys mutated by hypothesis, given to ``simulate`` the way
a user would (``diagnose --model`` and ``export-ff`` read a model file through the same
loaders: :func:`experiments.model_files.load_model`, :mod:`clm_sim.modelfile`).

Every generated file must end in one of three outcomes: success (exit 0), success with warnings
(stderr holds only warning lines), or exit 2 with one ``clm-sim: error:`` line (after the
warning lines, if any); never an internal error (exit 1),
a traceback, a library's warning, a result folder half-written or a temporary file left. The
fast tier runs the fixed examples of the ``fast`` profile (tests/conftest.py: ``derandomize``,
the same here as in CI); ``HYPOTHESIS_PROFILE=long`` runs 500 fresh ones.
"""

from __future__ import annotations

import json
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from experiments.cli import main  # noqa: E402

TS = 1e-4
N = 4000
LIP = {"kind": "lip", "mass": 18.8, "viscous": 170.0, "coulomb": 7.0, "stiffness": 0.0,
       "ts": TS, "features": {"regression_lowpass_hz": 250.0, "position_lowpass_hz": None,
                              "lowpass_order": 4, "edge_samples": 200},
       "effects": [], "source": "rec.csv"}
MODEL_YAML = {"ts": TS, "plant": {"mass": 18.8, "viscous": 170.0, "coulomb": 7.0,
                                  "effects": [{"type": "cogging", "amplitude": 1.0,
                                               "period": 0.03}]}}

# What may replace a value in a model file: every kind JSON or YAML can hold, and numbers of
# every size and sign.
ODD = st.one_of(
    st.sampled_from([None, True, False, "", "18.8", "x", [], {}, [1.0], {"a": 1}, 0, -1, 1,
                     10 ** 400, -(10 ** 400), 2 ** 63, 5e-324, 1e-300, 1e300, -1e300, 1e-4,
                     [{"type": "cogging"}], [{"type": "zzz", "x": 1}], [5],
                     [{"type": "cogging", "amplitude": 1e300, "period": 1e-300}]]),
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.text(max_size=8),
)
LIP_KEYS = st.sampled_from([("kind",), ("mass",), ("viscous",), ("coulomb",), ("stiffness",),
                            ("ts",), ("features",), ("features", "regression_lowpass_hz"),
                            ("features", "position_lowpass_hz"), ("features", "lowpass_order"),
                            ("features", "edge_samples"), ("effects",), ("source",),
                            ("extra",)])
YAML_KEYS = st.sampled_from([("ts",), ("plant",), ("plant", "mass"), ("plant", "viscous"),
                             ("plant", "coulomb"), ("plant", "stiffness"),
                             ("plant", "encoder_resolution"), ("plant", "effects"),
                             ("controller",), ("controller", "crossover_hz"), ("extra",)])


def _record(path: Path) -> None:
    """A record ``simulate`` accepts: a slow sine both ways under the LIP's own force."""
    t = np.arange(N) * TS
    r = 0.005 * np.sin(2 * np.pi * 2 * t)
    v = np.gradient(r, TS)
    a = np.gradient(v, TS)
    u = 18.8 * a + 170.0 * v + 7.0 * np.tanh(v / 1e-3)
    np.savetxt(path, np.column_stack([t, r, r, u]), delimiter=",", header="t,r,y,u",
               comments="", fmt="%.17g")


def _edit(base: dict, edits) -> dict:
    data = json.loads(json.dumps(base))
    for path, value in edits:
        node = data
        for key in path[:-1]:
            if not isinstance(node.get(key), dict):
                node[key] = {}
            node = node[key]
        node[path[-1]] = value
    return data


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*")
            if ".partial" in p.name or p.name.endswith(".lock") or ".tmp" in p.name]


@pytest.fixture(scope="module")
def record(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("record") / "rec.csv"
    _record(path)
    return path


@given(kind=st.sampled_from(["json", "yaml"]), data=st.data())
def test_generated_model_files_end_in_success_a_warning_or_one_line(kind, data, record, capsys):
    keys = LIP_KEYS if kind == "json" else YAML_KEYS
    edits = data.draw(st.lists(st.tuples(keys, ODD), min_size=1, max_size=3), label="edits")
    model = _edit(LIP if kind == "json" else MODEL_YAML, edits)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        path = tmp / ("lip.json" if kind == "json" else "model.yaml")
        # Written as a user's editor would: JSON with its integers in full, YAML likewise.
        path.write_text(json.dumps(model) if kind == "json" else yaml.safe_dump(model))
        out = tmp / "out"
        argv = ["simulate", str(path), str(record), "--out", str(out)]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        hypothesis.event(f"simulate {kind} exit {code}")
        assert not caught, [str(w.message) for w in caught]  # each would be a stderr line
        assert code in (0, 2), err
        said = [line for line in err if not line.startswith("clm-sim: warning: ")]
        if code == 2:
            assert len(said) == 1 and said == err[-1:], err
            assert err[-1].startswith("clm-sim: error: "), err
            assert sorted(p.name for p in tmp.iterdir()) == [path.name]  # nothing written
        else:
            assert said == [], err
            assert (out / ".clm-sim-manifest.json").is_file()
        assert _leftovers(tmp) == []
