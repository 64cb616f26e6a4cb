"""Hostile input, generated: malformed CSV, NPZ and MAT records and configs built by hypothesis.

Records go to ``identify`` and ``export``, configs to ``run`` (its pipeline stubbed: the property
is about reading, checking and writing, not the simulation) and to the config reader. Every
generated input must end in success or in exit code 2 with one stderr line; never a traceback
(here: an exception out of ``main`` or the reader), never a warning of a library (a second stderr
line), never a half-written folder or a temporary file left beside it.

The fast tier runs a fixed set of 30 examples per test (``derandomize``: the same in CI as here);
``HYPOTHESIS_PROFILE=long`` runs 500 with a fresh seed each time.
"""

from __future__ import annotations

import io
import json
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import scipy.sparse
from small_config import SMALL_CONFIG

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from clm_sim.errors import UserError  # noqa: E402
from experiments.cli import main  # noqa: E402

N = 600
TS = 1e-4


def _signals(n: int = N) -> dict[str, np.ndarray]:
    """A record identify accepts: motion both ways, force = mass * acceleration + friction."""
    t = np.arange(n) * TS
    r = 0.01 * np.sin(2 * np.pi * 5 * t)
    a = -(2 * np.pi * 5) ** 2 * r
    return {"t": t, "r": r, "y": r + 1e-6 * np.cos(2 * np.pi * 50 * t), "u": 18.8 * a}


# What may replace a signal: values of every kind a foreign file can hold.
ODD_VALUES = st.sampled_from([
    "scalar", "text", "bytes", "structured", "complex", "real complex", "bool", "int",
    "empty", "matrix", "row", "short", "long", "nan", "inf", "huge", "tiny", "negative",
    "constant", "zeros",
])


def _odd(kind: str, x: np.ndarray) -> np.ndarray:
    n = len(x)
    return {
        "scalar": lambda: np.array(1.5),
        "text": lambda: np.array(["a"] * n),
        "bytes": lambda: np.array([b"a"] * n),
        "structured": lambda: np.zeros(n, dtype=[("a", float), ("b", int)]),
        "complex": lambda: x * (1 + 1j),
        "real complex": lambda: x + 0j,
        "bool": lambda: x > 0,
        "int": lambda: (x * 1e6).astype(np.int64),
        "empty": lambda: np.zeros(0),
        "matrix": lambda: np.column_stack([x, x]),
        "row": lambda: x[None, :],
        "short": lambda: x[: n // 2],
        "long": lambda: np.r_[x, x],
        "nan": lambda: np.where(np.arange(n) == n // 3, np.nan, x),
        "inf": lambda: np.where(np.arange(n) == n // 3, np.inf, x),
        "huge": lambda: x * 1e300,
        "tiny": lambda: x * 1e-300,
        "negative": lambda: -x,
        "constant": lambda: np.full(n, 0.5),
        "zeros": lambda: np.zeros(n),
    }[kind]()


@st.composite
def records(draw) -> tuple[str, bytes]:
    """A record file (name, bytes): valid signals mutated, written as CSV, NPZ or MAT, maybe
    truncated."""
    base = _signals(draw(st.sampled_from([N, N, N, 250, 3])))
    sig = dict(base)
    for name in draw(st.lists(st.sampled_from(["t", "r", "y", "u"]), max_size=2)):
        sig[name] = _odd(draw(ODD_VALUES), base[name])
    if draw(st.integers(0, 3)) == 0:
        sig["t"] = base["t"] * draw(st.sampled_from([1e-12, 1e-6, 1e3, -1.0, 0.0]))
    if draw(st.integers(0, 3)) == 0:
        sig.pop(draw(st.sampled_from(sorted(sig))))
    fmt = draw(st.sampled_from(["csv", "npz", "mat"]))
    if fmt == "csv":
        header = ",".join(sig)
        if draw(st.booleans()):
            header = draw(st.sampled_from(["\ufeff", '"', "# ", ""])) + header
        try:
            rows = np.column_stack([np.broadcast_to(np.asarray(v, dtype=float).ravel()[:N],
                                                    (N,)) for v in sig.values()])
            buf = io.StringIO()
            np.savetxt(buf, rows, delimiter=",", fmt="%.17g")
            body = buf.getvalue()
        except (ValueError, TypeError):
            body = draw(st.text(max_size=200))
        content = (header + "\n" + body).encode("utf-8", "surrogatepass")
    elif fmt == "npz":
        buf = io.BytesIO()
        meta = draw(st.sampled_from([None, "{}", "[1]", "nope", '{"seed": 1}']))
        np.savez(buf, **sig, **({} if meta is None else {"meta": np.array(meta)}))
        content = buf.getvalue()
    else:
        extra = draw(st.sampled_from([{}, {"gtau": 35.15}, {"gtau": "volts"},
                                      {"gtau": {"k": 1.0}},
                                      {"u": scipy.sparse.csc_matrix(np.ones((N, 1)))},
                                      {"u": np.array([[np.ones(2)]], dtype=object)}]))
        buf = io.BytesIO()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                scipy.io.savemat(buf, {**{k: v for k, v in sig.items() if np.size(v)},
                                       **extra})
            except (ValueError, TypeError):
                buf = io.BytesIO(b"MATLAB 5.0 MAT-file")
        content = buf.getvalue()
    if draw(st.integers(0, 5)) == 0:
        content = content[: draw(st.integers(0, len(content)))]
    return f"rec.{fmt}", content


SCALES = st.sampled_from([None, "u=2", "u=gtau", "u=0", "u=nan", "u=inf", "x=1", "u=",
                          "y=0.001", "u=missing", "t=1e-12"])


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*")
            if ".partial" in p.name or p.name.endswith(".lock") or ".tmp" in p.name]


def _outcome(argv, capsys) -> tuple[int, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert not caught, [str(w.message) for w in caught]  # each would be a stderr line
    return code, err


@given(record=records(), scale=SCALES, command=st.sampled_from(["identify", "export"]))
def test_generated_records_end_in_success_or_one_line(record, scale, command, capsys):
    name, content = record
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        data = tmp / name
        data.write_bytes(content)
        out = tmp / "out"
        if command == "identify":
            argv = ["identify", str(data), "--out", str(out)]
            if scale:
                argv += ["--scale", scale]
        else:
            argv = ["export", str(data), "--to", "csv", "--out", str(out) + ".csv"]
        code, err = _outcome(argv, capsys)
        hypothesis.event(f"{command} exit {code}")
        assert code in (0, 2), err
        if code == 2:
            assert len(err) == 1 and err[0].startswith("clm-sim: error: "), err
            assert sorted(p.name for p in tmp.iterdir()) == [name]  # nothing written
        else:
            assert all(line.startswith("clm-sim: warning: ") for line in err), err
            if command == "identify":
                text = (out / "lip.json").read_text()
                json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in lip.json"))
        assert _leftovers(tmp) == []


# Config mutations: a key path and a value of the wrong kind, size or sign.
KEYS = st.sampled_from([
    ("seed",), ("ts",), ("name",), ("plant", "mass"), ("plant", "effects"),
    ("references", "r1", "points_m"), ("references", "r1", "dwell_s"),
    ("references", "r2", "max_velocity"), ("references", "r2", "max_jerk"),
    ("training", "repeats"), ("training", "dither", "hold_samples"),
    ("training", "dither", "std_n"), ("features", "regression_lowpass_hz"),
    ("feedforwards",), ("replay",), ("controller", "crossover_hz"), ("truth",),
])
VALUES = st.one_of(
    st.sampled_from([-1, 0, 1, 10 ** 12, 1e-12, 1e9, -1e300, True, None, "x", "", [], {},
                     [[[[]]]], [0.0, 1e6], {"type": "cogging"},
                     [{"kind": "pgnn", "training": "sequential", "hidden": 100000}],
                     [{"kind": "lip", "seeds": 100000}]]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
    st.sampled_from([10 ** 400, -(10 ** 400), 5e-324, 1e-300, 1e300]),
    st.text(max_size=20),
)


def _stub_run(config, out, progress, config_path):
    """Stands for the pipeline (seconds to minutes): writes a result as the runner does, so the
    generated configs exercise the CLI and the output folder, not the simulation."""
    import yaml

    from experiments.config import resolved

    (out / "config.resolved.yaml").write_text(yaml.safe_dump(resolved(config)))
    (out / "table.md").write_text("")  # the command prints what the run wrote
    (out / "table.json").write_text('{"rows": [], "comparisons": []}')
    return []


@given(edits=st.lists(st.tuples(KEYS, VALUES), max_size=3),
       tail=st.sampled_from(["", "extra: 1\n", "[", "a: &a [1, 1]\nb: [*a, *a]\n",
                             "x: " + "[" * 100 + "]" * 100 + "\n"]))
def test_generated_configs_end_in_success_or_one_line(edits, tail, capsys):
    """``clm-sim run`` on a generated config (the pipeline stubbed): exit 0, or 2 with one
    line that names the file; the output folder whole or absent, nothing temporary beside it."""
    from unittest import mock

    import yaml

    data = yaml.safe_load(SMALL_CONFIG)
    for path, value in edits:
        node = data
        for key in path[:-1]:
            node = node.setdefault(key, {}) if isinstance(node.get(key, {}), dict) else {}
        node[path[-1]] = value
    with tempfile.TemporaryDirectory() as tmp, \
            mock.patch("experiments.runner._run", _stub_run):
        tmp = Path(tmp)
        cfg = tmp / "gen.yaml"
        cfg.write_text(yaml.safe_dump(data) + tail)
        code, err = _outcome(["run", str(cfg), "--out", str(tmp / "out"), "--quiet"], capsys)
        hypothesis.event(f"run exit {code}")
        assert code in (0, 2), err
        if code == 2:
            assert len(err) == 1 and err[0].startswith(f"clm-sim: error: {cfg}: "), err
            assert len(err[0]) <= 1100, err[0][:200]
            assert sorted(p.name for p in tmp.iterdir()) == ["gen.yaml"]
        else:
            assert all(line.startswith("clm-sim: warning: ") for line in err), err
            assert (tmp / "out" / "config.resolved.yaml").exists()
        assert _leftovers(tmp) == []


@given(edits=st.lists(st.tuples(KEYS, VALUES), max_size=3),
       tail=st.sampled_from(["", "extra: 1\n", "[", "a: &a [1, 1]\nb: [*a, *a]\n",
                             "x: " + "[" * 100 + "]" * 100 + "\n"]))
def test_generated_configs_are_read_or_refused_in_one_line(edits, tail):
    """The config reader (everything ``run`` checks before its work): a config or one
    ``UserError`` line, whatever the values."""
    import yaml

    from experiments.config import load_config
    from experiments.runner import preflight

    data = yaml.safe_load(SMALL_CONFIG)
    for path, value in edits:
        node = data
        for key in path[:-1]:
            node = node.setdefault(key, {}) if isinstance(node.get(key, {}), dict) else {}
        node[path[-1]] = value
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "gen.yaml"
        cfg.write_text(yaml.safe_dump(data) + tail)
        try:
            config = load_config(cfg)
            hypothesis.event("config read")
        except UserError as exc:
            text = str(exc)
            assert "\n" not in text and len(text) < 2000 and text.startswith(str(cfg)), text
            return
        try:
            preflight(config)  # run_experiment puts the file name before its messages
        except UserError as exc:
            assert "\n" not in str(exc) and len(str(exc)) < 2000, str(exc)
