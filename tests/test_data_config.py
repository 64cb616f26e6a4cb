"""``clm-sim run`` with a ``data:`` section: it reads the records, the feature map, the rows and
the seed, and nothing a simulation reads. What it would ignore is refused in one line naming the
key; a validation record at another rate than the training record is refused like ``identify
--validate`` refuses it; the result folder holds no empty folders."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from clm_sim.records.write import save_npz
from clm_sim.run import Run
from experiments.cli import main

TS = 1e-4


def _record(path, ts: float = TS, seconds: float = 4.0) -> str:
    """A record a LIP fits: 2 Hz motion both ways, force = mass * a + viscous * v + Coulomb."""
    t = np.arange(int(round(seconds / ts))) * ts
    w = 2 * np.pi * 2.0
    y = 0.01 * np.sin(w * t)
    v, a = 0.01 * w * np.cos(w * t), -w ** 2 * y
    save_npz(Run(t=t, r=y, y=y, u=18.8 * a + 30.0 * v + 5.0 * np.sign(v)), path)
    return str(path)


def _config(tmp_path, extra: str = "", rows: str = "  - kind: lip\n", **data) -> str:
    doc = {"training": _record(tmp_path / "train.npz"), **data}
    path = tmp_path / "data.yaml"
    path.write_text("name: d\nseed: 1\n" + yaml.safe_dump({"data": doc})
                    + "feedforwards:\n" + rows + extra)
    return str(path)


def _refused(argv, tmp_path, capsys, *expected) -> None:
    before = sorted(p.name for p in tmp_path.iterdir())
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1, captured.err
    assert lines[0].startswith("clm-sim: error: "), lines[0]
    for text in expected:
        assert text in lines[0], lines[0]
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_a_validation_record_at_another_rate_is_refused(tmp_path, capsys):
    """recD_half of the audit: every second sample of the training record (force rms 10.6 N
    against 0.5 N at the matching rate, with no word)."""
    config = _config(tmp_path, validation=_record(tmp_path / "half.npz", ts=2 * TS))
    _refused(["run", config, "--out", tmp_path / "out", "--quiet"], tmp_path, capsys,
             config, "data.validation", "sampled at 0.0002 s, the record at 0.0001 s")


SIMULATION_KEYS = {
    "ts": "ts: 0.001\n",
    "plant": "plant: {mass: 500.0}\n",
    "truth": "truth: {mass: 3.0}\n",
    "controller": "controller: {crossover_hz: 5}\n",
    "references": "references:\n  r1: {points_m: [0.0, 0.01, 0.0]}\n"
                  "  r2: {points_m: [0.0, 0.02, 0.0]}\n",
    "replay": "replay: [r1]\n",
    "training": "training: {repeats: 5}\n",
}


@pytest.mark.parametrize("key", list(SIMULATION_KEYS))
def test_a_key_a_data_run_ignores_is_refused(key, tmp_path, capsys):
    config = _config(tmp_path, extra=SIMULATION_KEYS[key])
    _refused(["run", config, "--out", tmp_path / "out", "--quiet"], tmp_path, capsys,
             config, f"{key}: has no effect with data:")


@pytest.mark.parametrize("grid", ["features.regression_lowpass_hz: [20.0, 30.0]",
                                  "plant.mass: [1.0, 2.0]"])
def test_a_sweep_of_a_data_config_is_refused_before_it_runs(grid, tmp_path, capsys):
    """A sweep's table holds the testbed's tracking errors; on measured records a task had none
    and the sweep ended in an internal error (KeyError 'mae') with a table.json half-written."""
    config = _config(tmp_path, extra=f"sweep:\n  grid:\n    {grid}\n")
    _refused(["sweep", config, "--out", tmp_path / "out", "--quiet", "--workers", "1"],
             tmp_path, capsys, config, "data: a sweep runs the simulated testbed")


def test_a_sweep_over_records_is_refused_before_it_runs(tmp_path, capsys):
    """The same, with ``data:`` as a swept key of a simulation config (the review found it past
    the base config's check)."""
    a, b = _record(tmp_path / "a.npz"), _record(tmp_path / "b.npz", seconds=3.0)
    config = tmp_path / "sweep.yaml"
    config.write_text("name: s\nseed: 1\nfeedforwards:\n  - kind: lip\nsweep:\n  grid:\n"
                      f"    data: [{{training: {a}}}, {{training: {b}}}]\n")
    _refused(["sweep", config, "--out", tmp_path / "out", "--quiet", "--workers", "1"],
             tmp_path, capsys, str(config), "sweep.grid.data: a sweep runs the simulated testbed")


def test_seeds_of_a_lip_row_are_refused(tmp_path, capsys):
    """The least-squares LIP of a record has one fit; the table showed 1 seed for ``seeds: 3``."""
    config = _config(tmp_path, rows="  - {kind: lip, seeds: 3}\n")
    _refused(["run", config, "--out", tmp_path / "out", "--quiet"], tmp_path, capsys,
             config, "feedforwards[0].seeds")


def test_a_lip_data_run_writes_what_it_computed_and_no_empty_folder(tmp_path, capsys):
    config = _config(tmp_path, validation=_record(tmp_path / "val.npz"))
    out = tmp_path / "out"
    assert main(["run", config, "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [".clm-sim-manifest.json",
                                                     "config.resolved.yaml", "table.json",
                                                     "table.md"]
    resolved = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert "ts" not in resolved and "plant" not in resolved  # no claim the records contradict
    row = json.loads((out / "table.json").read_text())["rows"][0]
    # the record is the LIP's model exactly, up to the filters' edges and the finite differences
    assert row["force_rms"]["validation"]["inside"]["mean"] < 1.0
