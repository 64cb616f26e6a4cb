"""One set of record guards for every command that identifies from a record:
``identify``, ``diagnose`` and ``run`` with a ``data:`` section refuse in one line a record that
identifies nothing and warn where the result is suspect; the quantization warning's bias
estimate is checked against the bias it predicts; the top-level guard turns an internal error
into one line, exit 1."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from clm_sim.records.write import save_npz
from clm_sim.run import Run
from experiments.cli import main

EMPS = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "emps"


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """4 s of r1 at 10 kHz under the PID alone, with the training dither's excitation (the
    default CLM: 18.8 kg, 0.1 um encoder)."""
    from experiments.testbed import Testbed

    tb = Testbed()
    run = tb.training_run()
    return run.slice(0, 40000)


def _save(tmp_path, run, **changes) -> str:
    signals = {k: getattr(run, k) for k in ("t", "r", "y", "u")}
    signals.update(changes)
    path = tmp_path / "rec.npz"
    save_npz(Run(**signals), path)
    return str(path)


def _cli(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip().splitlines()


@pytest.mark.parametrize("change, expected", [
    ({"u": 0.0}, "u is zero in every sample"),
    ({"u": 3.0}, "u is constant (3 N"),
    ({"y": 0.01}, "y is constant"),
])
@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_a_record_that_identifies_nothing_is_refused(record, tmp_path, capsys, change,
                                                     expected, command):
    (name, value), = change.items()
    data = _save(tmp_path, record, **{name: np.full(len(record), value)})
    code, out, err = _cli([command, data, "--out", tmp_path / "out"], capsys)
    assert code == 2 and len(err) == 1 and expected in err[0] and data in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("q", [5e-6, 1e-5])
def test_quantized_position_warns_with_the_bias_it_has(record, tmp_path, capsys, q):
    """y quantized to q: the warning's bias estimate is within 0.1 (absolute) of the bias the
    fit shows against the fine record; the fine record gives no warning."""
    fine = _cli(["identify", _save(tmp_path, record), "--out", tmp_path / "a"], capsys)
    assert fine[0] == 0 and fine[2] == [], fine[2]
    m_fine = json.loads((tmp_path / "a" / "lip.json").read_text())["mass"]
    code, out, err = _cli(["identify", _save(tmp_path, record, y=np.round(record.y / q) * q),
                           "--out", tmp_path / "b"], capsys)
    m_q = json.loads((tmp_path / "b" / "lip.json").read_text())["mass"]
    actual = 1 - m_q / m_fine
    assert code == 0 and len(err) == 1 and f"steps of {q:.3g} m" in err[0], err
    said = float(err[0].split("by about ")[1].split("%")[0]) / 100
    assert actual > 0.3 and abs(said - actual) < 0.1, (actual, said)


def test_a_mass_that_is_not_physical_is_a_warning_whatever_its_error(record, tmp_path, capsys):
    """One sample of y at 1 m (a glitch) leaves a mass near zero, below it by less than three
    standard errors: no force-sign warning, but a feedforward from it is wrong. One line; the
    result is still written."""
    y = record.y.copy()
    y[5000] = 1.0
    code, out, err = _cli(["identify", _save(tmp_path, record, y=y), "--out", tmp_path / "o"],
                          capsys)
    mass = json.loads((tmp_path / "o" / "lip.json").read_text())["mass"]
    assert code == 0 and mass <= 0.01, mass
    assert len(err) == 1 and "not a physical mass" in err[0], err


@pytest.mark.skipif(not (EMPS / "DATA_EMPS.mat").exists(), reason="no EMPS records beside")
def test_emps_quantized_to_10_um_warns_and_the_original_does_not(tmp_path, capsys):
    import scipy.io

    d = scipy.io.loadmat(EMPS / "DATA_EMPS.mat")
    t, y, r = (d[k].ravel() for k in ("t", "qm", "qg"))
    u = d["vir"].ravel() * float(d["gtau"].ravel()[0])
    for q, warned in ((None, False), (1e-5, True)):
        path = tmp_path / "emps.npz"
        save_npz(Run(t=t, r=r, y=y if q is None else np.round(y / q) * q, u=u), path)
        code, out, err = _cli(["identify", path, "--out", tmp_path / "o"], capsys)
        assert code == 0 and (len(err) == 1 and "biases the mass low" in err[0]) == warned, err


def test_sampling_jitter_behind_uniform_time_stamps_is_a_warning(record, tmp_path, capsys):
    """y sampled 30 us (rms) off its 100 us time stamps: the mass is biased by more than 5 %
    against the record without jitter, and the warning says so (the mass moves when the band
    is halved); 1 us of jitter biases it by 0.05 % and is not said."""
    masses = {}
    for sigma in (0.0, 1e-6, 3e-5):
        jitter = np.random.default_rng(5).normal(0.0, sigma, len(record))
        y = np.interp(record.t + jitter, record.t, record.y)
        code, out, err = _cli(["identify", _save(tmp_path, record, y=y), "--out",
                               tmp_path / "o"], capsys)
        masses[sigma] = json.loads((tmp_path / "o" / "lip.json").read_text())["mass"]
        warned = any("at 125 Hz" in line for line in err)
        assert code == 0 and warned == (abs(masses[sigma] / masses[0.0] - 1) > 0.05), \
            (sigma, masses, err)
    assert abs(masses[3e-5] / masses[0.0] - 1) > 0.05  # the case that warns is a real bias


@pytest.mark.parametrize("cutoff, expected", [(4900.0, "of the record's Nyquist"),
                                              (0.01, "passes only drift")])
def test_a_cutoff_near_nyquist_or_absurdly_low_is_a_warning(record, tmp_path, capsys, cutoff,
                                                            expected):
    code, out, err = _cli(["identify", _save(tmp_path, record), "--out", tmp_path / "o",
                           "--regression-lowpass-hz", cutoff], capsys)
    assert any(expected in line for line in err), err
    assert code == 0 or (code == 2 and len(err) == 1)


def _data_config(tmp_path, data, window=None, features=None, scale=None, pgnn=False):
    ffs = [{"kind": "lip"}]
    if pgnn:
        ffs.append({"kind": "pgnn", "training": "simultaneous", "lambda": 0.01, "hidden": 2,
                    "seeds": 1, "pgnn": {"max_iter": 2}})
    doc = {"seed": 1, "data": {"training": data, "window": window or {}}, "feedforwards": ffs}
    if scale:
        doc["data"]["scale"] = scale
    if features:
        doc["features"] = features
    path = tmp_path / "data.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("window, expected", [
    ({"position_m": [0.05, 0.05001]}, "the training window keeps"),  # a few samples
    ({"position_m": [5.0, 6.0]}, "keeps 0 of"),  # no sample
])
@pytest.mark.parametrize("pgnn", [False, True])
def test_run_with_data_refuses_a_window_that_identifies_nothing(record, tmp_path, capsys, window,
                                                                expected, pgnn):
    config = _data_config(tmp_path, _save(tmp_path, record), window=window, pgnn=pgnn)
    code, out, err = _cli(["run", config, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and expected in err[0] and "data.training" in err[0], err


@pytest.mark.parametrize("change, expected", [({"u": 0.0}, "u is zero"),
                                              ({"y": 0.02}, "y is constant")])
def test_run_with_data_refuses_a_record_that_identifies_nothing(record, tmp_path, capsys, change,
                                                                expected):
    (name, value), = change.items()
    data = _save(tmp_path, record, **{name: np.full(len(record), value)})
    config = _data_config(tmp_path, data, pgnn=True)
    code, out, err = _cli(["run", config, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and expected in err[0], err


@pytest.mark.parametrize("options, expected", [
    ({"scale": {"u": -1.0}}, "the fitted mass is"),  # a force of the wrong sign
    ({"features": {"regression_lowpass_hz": 0.01}}, "passes only drift"),
])
def test_run_with_data_warns_where_the_result_is_suspect(record, tmp_path, capsys, options,
                                                         expected):
    config = _data_config(tmp_path, _save(tmp_path, record), **options)
    code, out, err = _cli(["run", config, "--out", tmp_path / "out", "--quiet"], capsys)
    if code == 2:  # the offset column is collinear with what a drift-only filter leaves
        assert len(err) == 1 and expected in err[0] and "data.training" in err[0], err
        return
    warnings = [line for line in err if line.startswith("clm-sim: warning: data.training")]
    assert code == 0 and any(expected in line for line in warnings), err
    doc = json.loads((tmp_path / "out" / "table.json").read_text())
    assert any(expected in line for line in doc["warnings"])


def test_an_internal_error_is_one_line_exit_1(monkeypatch, tmp_path, capsys):
    """A bug (here: an injected ZeroDivisionError) names the command, the input and the error,
    exit 1, no traceback; with --debug the traceback too."""
    import experiments.cli.identify

    def broken(*args, **kwargs):
        raise ZeroDivisionError("injected")

    monkeypatch.setattr(experiments.cli.identify, "identify", broken)
    data = tmp_path / "x.csv"
    data.write_text("t,r,y,u\n")
    code, out, err = _cli(["identify", data], capsys)
    assert code == 2  # a bad record stays a user error (exit 2), before the bug is reached
    t = np.arange(300) * 1e-3
    save_npz(Run(t=t, r=np.sin(t), y=np.sin(t), u=np.cos(t)), tmp_path / "ok.npz")
    code, out, err = _cli(["identify", tmp_path / "ok.npz", "--out", tmp_path / "o"], capsys)
    assert code == 1 and len(err) == 1, err
    assert "internal error in 'identify'" in err[0] and "ok.npz" in err[0]
    assert "ZeroDivisionError: injected" in err[0] and "report" in err[0]
    code, out, err = _cli(["--debug", "identify", tmp_path / "ok.npz", "--out", tmp_path / "o"],
                          capsys)
    assert code == 1 and any("Traceback" in line for line in err) and len(err) > 1



def test_an_internal_error_in_a_real_process_is_one_line_exit_1(tmp_path):
    """The same through a real process (signals received in their own thread, the exit
    without interpreter shutdown): stderr is the one line, exit 1."""
    import subprocess
    import sys

    t = np.arange(300) * 1e-3
    save_npz(Run(t=t, r=np.sin(t), y=np.sin(t), u=np.cos(t)), tmp_path / "ok.npz")
    code = ("import sys, experiments.cli.identify as m\n"
            "def boom(*a, **k): raise KeyError('injected')\n"
            "m.identify = boom\n"
            "from experiments.cli import main\n"
            "sys.argv = ['clm-sim', 'identify', sys.argv[1], '--out', sys.argv[2]]\n"
            "sys.exit(main())\n")
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "ok.npz"),
                           str(tmp_path / "o")], capture_output=True, text=True, cwd=root,
                          env={**os.environ, "PYTHONPATH": str(root)}, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert "internal error in 'identify'" in lines[0] and "KeyError" in lines[0]


def test_a_fit_that_is_not_finite_is_refused_in_one_line(record):
    """A run built in Python (no ``load_record`` scale check) whose force is so small that the
    residual's squares underflow: the relative error 0/0 is a ``UserError`` naming the source,
    not a NumPy warning and an internal error when ``lip.json`` refuses NaN."""
    import warnings

    from clm_sim.errors import UserError
    from controllers.idim import IDIMProtocol
    from experiments.cli.identify import identify

    tiny = Run(t=record.t, r=record.r, y=record.y, u=record.u * 1e-200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning would be a second stderr line
        with pytest.raises(UserError, match="^src: the fit gives non-finite .*relative error"):
            identify(tiny, IDIMProtocol(), source="src")
