"""Budgets and files that never end: the work a config asks for is
bounded before it starts, with the estimate in the message; no record or config is read from a
device or pipe; rows whose names share a file are refused before the work."""

from __future__ import annotations

import os

import pytest
import yaml
from small_config import SMALL_CONFIG

from experiments.cli import main


def _cli(argv, capsys):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip().splitlines()


def _config(tmp_path, **changes) -> str:
    data = yaml.safe_load(SMALL_CONFIG)
    data.update(changes)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_samples_a_config_simulates_are_bounded_with_the_estimate(tmp_path, capsys):
    ffs = [{"kind": "lip", "seeds": 100, "name": f"LIP {i}"} for i in range(20)]
    refs = {"r1": {"points_m": [0.0, 0.1, -0.1, 0.1, -0.1, 0.0], "dwell_s": 0.25},
            "r2": {"points_m": [0.0, 1.0, 0.0, 1.0, 0.0], "dwell_s": 2.0}}
    code, err = _cli(["run", _config(tmp_path, feedforwards=ffs, references=refs,
                                     replay=["r1", "r2"]), "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "samples simulated" in err[0], err
    assert "2000 replays" in err[0] and "exceeds the limit of 2e+08" in err[0]
    assert not (tmp_path / "o").exists()


def test_the_parameters_of_a_network_are_bounded(tmp_path, capsys):
    ffs = [{"kind": "pgnn", "training": "sequential", "hidden": [1024, 1024]}]
    code, err = _cli(["run", _config(tmp_path, feedforwards=ffs), "--out", tmp_path / "o"],
                     capsys)
    assert code == 2 and len(err) == 1 and "network parameters" in err[0], err


@pytest.mark.parametrize("names", [("Net A", "net-a"), ("x" * 300,)])
def test_row_names_that_share_or_overflow_a_file_are_refused(tmp_path, capsys, names):
    from unittest import mock

    ffs = [{"kind": "pgnn", "training": "sequential", "hidden": 2, "name": n} for n in names]
    with mock.patch("experiments.runner._run", side_effect=AssertionError("ran")):
        code, err = _cli(["run", _config(tmp_path, feedforwards=ffs), "--out",
                          tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "feedforwards[" in err[0], err


@pytest.mark.parametrize("command", ["identify", "run"])
def test_a_link_to_a_device_is_not_read(tmp_path, capsys, command):
    name = "rec.csv" if command == "identify" else "c.yaml"
    os.symlink("/dev/zero", tmp_path / name)
    code, err = _cli([command, tmp_path / name, "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "not a regular file" in err[0], err


def test_a_network_whose_fit_needs_more_memory_than_is_free_is_refused_before(
        tmp_path, capsys, monkeypatch):
    """The memory of a fit (its Jacobian, the normal matrix) is checked against what the
    machine has free before anything is allocated: a network under the parameter limit can
    still need more than that (a 19,470-parameter network: several 3 GB square matrices)."""
    from controllers.pgnn import model

    asked = []
    monkeypatch.setattr(model, "available_memory_bytes",
                        lambda: asked.append(1) or 50 * 2 ** 20)  # 50 MB free
    ffs = [{"kind": "pgnn", "training": "sequential", "hidden": [64, 64]}]
    code, err = _cli(["run", _config(tmp_path, feedforwards=ffs), "--out", tmp_path / "o",
                      "--quiet"], capsys)
    assert asked and code == 2 and len(err) == 1, err
    assert "GB" in err[0] and "more than the 0.0488 GB this machine has free" in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("parameters, samples, optimizer, gb", [
    (19_470, 6250, "varpro", 6 * 19_470 ** 2 * 8 / 2 ** 30),  # the square matrices dominate
    (19_470, 6250, "adam", 8 * 6250 * 19_470 * 8 / 2 ** 30),  # no square matrix
])
def test_the_memory_estimate_grows_with_the_square_of_the_parameters(parameters, samples,
                                                                    optimizer, gb):
    from controllers.pgnn.model import fit_memory_bytes

    need = fit_memory_bytes(parameters, samples, optimizer) / 2 ** 30
    assert need >= gb and (optimizer == "adam" or need > 16)


def test_a_pgnn_fit_on_too_few_samples_is_refused(tmp_path, capsys):
    """A decimation that leaves one sample: a network 'converged' on it said nothing."""
    ffs = [{"kind": "pgnn", "training": "sequential", "hidden": 4,
            "pgnn": {"decimation": 100_000}}]
    code, err = _cli(["run", _config(tmp_path, feedforwards=ffs), "--out", tmp_path / "o",
                      "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and "the fit keeps 1 samples" in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("size", [2 ** 20 + 1, 10 * 2 ** 20])
def test_a_config_over_the_size_limit_is_refused_before_it_is_parsed(size, tmp_path, capsys,
                                                                     monkeypatch):
    from clm_sim import schema

    path = tmp_path / "big.yaml"
    path.write_text(SMALL_CONFIG + "# " + "x" * size + "\n")
    monkeypatch.setattr(schema, "_StrictLoader", None)  # any parse would fail loudly
    code, err = _cli(["run", path, "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "a config has at most 1048576" in err[0], err


def test_a_config_of_too_many_values_is_refused_before_it_is_composed(tmp_path, capsys,
                                                                      monkeypatch):
    from clm_sim import schema

    path = tmp_path / "many.yaml"
    path.write_text(SMALL_CONFIG + "notes: [" + ",".join(["1"] * 60_000) + "]\n")
    monkeypatch.setattr(schema, "_StrictLoader", None)  # refused by the libyaml count
    code, err = _cli(["run", path, "--out", tmp_path / "o"], capsys)
    assert code == 2 and len(err) == 1 and "more than 50000 values" in err[0], err
