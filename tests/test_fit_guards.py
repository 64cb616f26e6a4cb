"""Every fit behind the same guards, whatever feeds it, and the input mistakes that used to end
as internal errors: each ends in success with a true result, a warning, or one line with
exit 2 (never a silent wrong number, an internal error or a file written)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from small_config import SMALL_CONFIG

from clm_sim.errors import UserError
from clm_sim.run import Run
from experiments.cli import main


def _cli(argv, capsys):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip().splitlines()


def _config(tmp_path, **changes):
    data = yaml.safe_load(SMALL_CONFIG)
    data.update(changes)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("cutoff", [0.01, 0.3, 1.0, 3.0])
def test_a_filter_that_leaves_no_signal_is_refused_on_a_simulated_run(cutoff, tmp_path,
                                                                      capsys):
    """A cut-off that passes only drift gave a mass of -3.3e8 kg and an MAE of 30 m, exit 0:
    the fit (a negative mass, or a force on the reference far beyond the run's) is refused."""
    path = _config(tmp_path, features={"regression_lowpass_hz": cutoff},
                   feedforwards=[{"kind": "lip"}])
    code, err = _cli(["run", path, "--out", tmp_path / "o", "--quiet"], capsys)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"clm-sim: error: {path}: training run: ") and \
        "features.regression_lowpass_hz" in err[0], err
    assert not (tmp_path / "o").exists()


def test_a_fit_far_from_the_machine_is_warned_in_the_result(tmp_path, capsys):
    """No regression filter: quantization noise in the acceleration biases the mass low (1.7
    against 18.8 kg); said on stderr and in every row of table.json."""
    path = _config(tmp_path, features={"regression_lowpass_hz": None},
                   feedforwards=[{"kind": "none"}, {"kind": "lip"}])
    code, err = _cli(["run", path, "--out", tmp_path / "o", "--quiet"], capsys)
    assert code == 0, err
    assert any("far from the simulated machine's" in line for line in err), err
    rows = json.loads((tmp_path / "o" / "table.json").read_text())["rows"]
    assert all(any("far from" in w for w in row["warnings"]) for row in rows)


def test_a_good_fit_carries_no_warning(tmp_path, capsys):
    path = _config(tmp_path, feedforwards=[{"kind": "lip"}])
    code, err = _cli(["run", path, "--out", tmp_path / "o", "--quiet"], capsys)
    assert code == 0 and err == [], err
    row = json.loads((tmp_path / "o" / "table.json").read_text())["rows"][0]
    assert "warnings" not in row and 0.8 < row["theta_phy"]["mass"] / 18.8 < 1.25


def test_a_record_fit_whose_force_is_far_beyond_the_records_is_warned():
    from clm_sim.features import FeatureMap
    from experiments.records.guards import fit_warnings

    t = np.arange(20000) * 1e-4
    r = 0.01 * np.sin(2 * np.pi * t)
    run = Run(t=t, r=r, y=r, u=20 * np.cos(2 * np.pi * t))
    theta = {"mass": 18.8, "viscous": 1e6, "coulomb": 5.0, "stiffness": 0.0}
    lines = fit_warnings(run, FeatureMap(), theta, None, option="--x")
    assert any("times the record's peak force" in line for line in lines), lines
    lines = fit_warnings(run, FeatureMap(), {**theta, "viscous": 10.0}, None, option="--x")
    assert not any("peak force" in line for line in lines), lines


def test_simulated_fit_checks_refuse_a_mass_not_above_zero():
    from clm_sim.features import FeatureMap
    from experiments.records.guards import simulated_fit_checks

    t = np.arange(5000) * 1e-4
    run = Run(t=t, r=0.01 * np.sin(t), y=0.01 * np.sin(t), u=np.cos(t))
    theta = {"mass": -2.0, "viscous": 1.0, "coulomb": 1.0, "stiffness": 0.0}
    std = dict.fromkeys(theta, 0.1)
    with pytest.raises(UserError, match="a mass of -2 kg"):
        simulated_fit_checks(run, FeatureMap(), theta, std, machine_mass=18.8, samples=4600)
    with pytest.raises(UserError, match="keeps 100 of 5000 samples"):
        simulated_fit_checks(run, FeatureMap(), {**theta, "mass": 18.8}, std,
                             machine_mass=18.8, samples=100)
    with pytest.raises(UserError, match="non-finite"):
        simulated_fit_checks(run, FeatureMap(), {**theta, "mass": np.nan}, std,
                             machine_mass=18.8, samples=4600)


BIG = "1" + "0" * 400

# Input mistakes that ended as internal errors (exit 1, "a bug of clm-sim").
def _lip(mass=18.8, ts="0.0001", extra=""):
    return ('{"kind": "lip", "mass": %s, "viscous": 30.0, "coulomb": 5.0, "stiffness": 0.0, '
            '"ts": %s%s}' % (mass, ts, extra))


MISTAKES = {
    "400-digit mass in a model file": ("lip.json", _lip(mass=BIG), "beyond the range"),
    "400-digit sample time": ("lip.json", _lip(ts=BIG), "beyond the range"),
    "400-digit negative mass": ("lip.json", _lip(mass="-" + BIG), "beyond the range"),
    "400-digit key in effects": ("lip.json", _lip(extra=', "effects": ' + BIG),
                                 "beyond the range"),
    "mass 1e308": ("lip.json", _lip(mass="1e308"), "beyond any machine"),
    "viscous 1e300": ("lip.json", _lip().replace("30.0", "1e300"), "beyond any machine"),
    "mass 1e-300": ("lip.json", _lip(mass="1e-300"), "lighter than any moving part"),
    "400-digit mass in a model YAML": ("model.yaml", f"ts: 0.0001\nplant: {{mass: {BIG}}}\n",
                                       "beyond the range"),
}


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    from clm_sim.records.write import save_npz
    from clm_sim.run import Run

    t = np.arange(8000) * 1e-4
    r = 0.005 * np.sin(2 * np.pi * 2 * t)
    u = 18.8 * np.gradient(np.gradient(r, 1e-4), 1e-4)
    path = tmp_path_factory.mktemp("rec") / "rec.npz"
    save_npz(Run(t=t, r=r, y=r, u=u, u_fb=u, u_ff=0 * u, dither=0 * u, e=0 * u), path)
    return path


@pytest.mark.parametrize("case", list(MISTAKES))
@pytest.mark.parametrize("command", ["simulate", "export-ff"])
def test_a_model_file_mistake_is_one_line(case, command, tmp_path, capsys, record):
    name, text, expected = MISTAKES[case]
    if command == "export-ff" and (name.endswith(".yaml") or "range" not in expected):
        pytest.skip("export-ff reads fitted feedforwards (no plant); its bounds are its own")
    path = tmp_path / name
    path.write_text(text)
    argv = (["simulate", path, record, "--out", tmp_path / "o"] if command == "simulate"
            else ["export-ff", path, "--to", "c", "--out", tmp_path / "o"])
    code, err = _cli(argv, capsys)
    assert code == 2 and len(err) == 1 and expected in err[0], err
    assert not (tmp_path / "o").exists()


CONFIG_MISTAKES = {
    "400-digit seed": ({"seed": int(BIG)}, "beyond the range"),
    "400-digit mass": ({"plant": {"mass": int(BIG)}}, "beyond the range"),
    "400-digit dwell": ({"references": {"r1": {"points_m": [0, 0.01], "dwell_s": int(BIG)},
                                        "r2": {"points_m": [0, 0.01]}}}, "beyond the range"),
    "jerk too small for the move": ({"references": {
        "r1": {"points_m": [0, 0.01], "max_jerk": 1e-300}, "r2": {"points_m": [0, 0.01]}}},
        "would take forever"),
    "cut-off no filter can have": ({"features": {"regression_lowpass_hz": 1e-300}},
                                   "no digital filter"),
    "mass beyond any machine": ({"plant": {"mass": 1e200}}, "beyond any machine"),
}


@pytest.mark.parametrize("case", list(CONFIG_MISTAKES))
def test_a_config_mistake_is_one_line(case, tmp_path, capsys):
    changes, expected = CONFIG_MISTAKES[case]
    path = _config(tmp_path, **changes)
    code, err = _cli(["run", path, "--out", tmp_path / "o", "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and expected in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("option", [["--regression-lowpass-hz", "1e-320"],
                                    ["--position-lowpass-hz", "1e-300"]])
def test_a_cut_off_no_filter_can_have_is_one_line(option, tmp_path, capsys, record):
    code, err = _cli(["identify", record, "--out", tmp_path / "o", *option], capsys)
    assert code == 2 and len(err) == 1 and "no digital filter" in err[0], err


@pytest.mark.parametrize("epoch", [BIG, "-1", "99999999999999", "1e5", "", "12 34"])
def test_source_date_epoch_out_of_range_is_one_line(epoch, tmp_path, capsys, monkeypatch):
    path = tmp_path / "lip.json"
    path.write_text(_lip())
    monkeypatch.setenv("SOURCE_DATE_EPOCH", epoch)
    code, err = _cli(["export-ff", path, "--to", "c", "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "SOURCE_DATE_EPOCH" in err[0], err
    assert not (tmp_path / "o").exists()
