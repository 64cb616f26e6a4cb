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
