"""Sweeps: grid expansion and checks, the task store, both backends, failures, and resuming after
SIGKILL with results identical to an uninterrupted run.

Tasks use a short reference (0.6 s moves of 1 cm, one training pass): the properties tested here
do not depend on the horizon, and a task then takes well under a second after its worker warms up.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
from build_once import build_once
from small_config import SMALL_CONFIG

import clm_sim
from clm_sim.errors import UserError
from clm_sim.outdir import atomic_write
from experiments.report import table_md
from experiments.table import Row
from experiments.sweeps.grid import MAX_TASKS, load_sweep, parse_path, set_path
from experiments.sweeps.store import ResultStore, code_version, result_sources, task_key
from experiments.sweeps.run import Outcome, execute, results_line, run_sweep
from experiments.sweeps.run import markdown as sweep_markdown
from experiments.stats.seeds import over_seeds, series

ROOT = Path(__file__).resolve().parents[1]

BASE = SMALL_CONFIG

# Four tasks: the 3 kHz crossover design is unstable (a task failure, recorded), 30 Hz is fine.
FAILING_GRID = BASE + """\
sweep:
  grid:
    controller.crossover_hz: [30.0, 3000.0]
    seed: [1, 2]
"""

# 24 tasks for the kill-and-resume tests. A warm worker runs one in about 0.1 s (its PID is
# designed once): after the third result about two seconds of task work remain for the signal
# to land in, as with the eight tasks of 0.4 s each that these were before.
RESUME_GRID = BASE + """\
sweep:
  grid:
    plant.encoder_resolution: {logspace: [1.0e-8, 1.0e-6, 2]}
    seed: {linspace: [1, 12, 12]}
"""


def _write(tmp_path: Path, text: str, name: str = "sweep.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "table.json").read_text())["rows"]


@pytest.mark.parametrize("text, parts", [
    ("seed", ["seed"]),
    ("plant.encoder_resolution", ["plant", "encoder_resolution"]),
    ("plant.effects[0].amplitude", ["plant", "effects", 0, "amplitude"]),
    ("feedforwards[2].lambda", ["feedforwards", 2, "lambda"]),
    ("references.r2.points_m[1]", ["references", "r2", "points_m", 1]),
])
def test_parse_path(text, parts):
    assert parse_path(text) == parts


@pytest.mark.parametrize("text", ["", "plant..mass", "plant.effects[x]", "feedforwards[-1]",
                                  "plant mass", "1plant"])
def test_parse_path_refuses_malformed(text):
    with pytest.raises(ValueError):
        parse_path(text)


def test_set_path_names_the_unknown_key():
    data = {"plant": {"mass": 1.0, "effects": [{"amplitude": 0.1}]}}
    set_path(data, ["plant", "effects", 0, "amplitude"], 0.2)
    assert data["plant"]["effects"][0]["amplitude"] == 0.2
    with pytest.raises(ValueError, match="'mas'"):
        set_path(data, ["plant", "mas"], 1.0)
    with pytest.raises(ValueError, match="index 3 out of range"):
        set_path(data, ["plant", "effects", 3, "amplitude"], 1.0)


def test_grid_expands_in_product_order_over_any_key(tmp_path):
    path = _write(tmp_path, BASE + """\
sweep:
  grid:
    plant.effects[0].amplitude: [0.0, 0.02]
    seed: {linspace: [1, 3, 3]}
    training.reference: [r1, r2]
""")
    sweep = load_sweep(path)
    assert len(sweep.tasks) == 2 * 3 * 2
    assert sweep.tasks[0].overrides == {"plant.effects[0].amplitude": 0.0, "seed": 1,
                                        "training.reference": "r1"}
    assert sweep.tasks[-1].overrides == {"plant.effects[0].amplitude": 0.02, "seed": 3,
                                         "training.reference": "r2"}
    for task in sweep.tasks:
        assert task.config["plant"]["effects"][0]["amplitude"] == \
            task.overrides["plant.effects[0].amplitude"]
        assert task.config["seed"] == task.overrides["seed"]
    assert len({t.key for t in sweep.tasks}) == len(sweep.tasks)  # distinct configs, keys


def test_logspace_axis_spans_the_stated_range(tmp_path):
    path = _write(tmp_path, BASE + "sweep:\n  grid:\n    plant.encoder_resolution: "
                                   "{logspace: [1.0e-9, 5.0e-6, 5]}\n")
    values = [t.overrides["plant.encoder_resolution"] for t in load_sweep(path).tasks]
    # The grid is geometric: rounded to 12 significant digits when stored.
    np.testing.assert_allclose(values, np.geomspace(1e-9, 5e-6, 5), rtol=1e-11)


def test_config_without_sweep_section_is_one_task(tmp_path):
    sweep = load_sweep(_write(tmp_path, BASE))
    assert len(sweep.tasks) == 1 and sweep.tasks[0].overrides == {}


def test_task_key_follows_config_and_code_version():
    config = {"seed": 1, "plant": {"mass": 18.8}}
    key = task_key(config, "0.6.0+aaaa")
    assert key == task_key(json.loads(json.dumps(config)), "0.6.0+aaaa")
    assert key != task_key({**config, "seed": 2}, "0.6.0+aaaa")
    assert key != task_key(config, "0.6.0+bbbb")
    assert code_version().startswith(clm_sim.__version__ + "+")


def test_code_version_hashes_the_sources_that_compute_results():
    """The hash must cover the physics, the controllers and the runner chain (once it covered
    nothing: a moved module left it hashing an empty list, so an edited source did not
    invalidate stored tasks)."""
    files = {f.relative_to(ROOT).as_posix() for f in result_sources()}
    for must in ("clm_sim/plant.py", "clm_sim/loop.py", "controllers/lip.py",
                 "controllers/pgnn/model.py", "experiments/runner.py", "experiments/testbed.py",
                 "experiments/table.py", "experiments/config.py"):
        assert must in files, must
    assert not any(f.startswith(("experiments/diagnosis", "experiments/sweeps")) for f in files)
    assert code_version() != "0.6.0+" + hashlib.sha256().hexdigest()[:12]


@pytest.mark.parametrize("grid, expected", [
    ("    plant.encoder_reslution: [1.0e-7]\n", "unknown key 'encoder_reslution'"),
    ("    feedforwards[5].lambda: [0.1]\n", "index 5 out of range"),
    ("    plant.encoder_resolution: [1.0e-7, -1.0]\n", "encoder_resolution"),
    ("    plant.mass: [10.0, heavy]\n", "plant.mass"),
    ("    seed: [1, 1]\n", "appears twice"),
    ("    seed: []\n", "non-empty list"),
    ("    plant.encoder_resolution: {logspace: [0.0, 1.0e-6, 4]}\n", "logspace"),
    ("    seed: {range: [1, 5]}\n", "logspace"),
    ("    training.reference: [r1, r7]\n", "r7"),
    ("    seed: {linspace: [1, 100000, 100000]}\n    plant.mass: [1.0, 2.0]\n", "exceed the limit"),
])
def test_bad_grid_is_one_line_error_naming_file_and_key(tmp_path, grid, expected):
    path = _write(tmp_path, BASE + "sweep:\n  grid:\n" + grid)
    with pytest.raises(UserError) as info:
        load_sweep(path)
    message = str(info.value)
    assert expected in message and str(path) in message and "\n" not in message


def test_huge_grid_is_refused_before_expansion(tmp_path):
    # 10^4 x 10^4 x 10^4 points: expanding them would never finish; the size check comes first.
    axis = "{linspace: [1, 10000, 10000]}"
    path = _write(tmp_path, BASE + f"sweep:\n  grid:\n    seed: {axis}\n    plant.mass: {axis}\n"
                                   f"    plant.viscous: {axis}\n")
    with pytest.raises(UserError, match=f"1000000000000 tasks exceed the limit of {MAX_TASKS}"):
        load_sweep(path)


def test_atomic_write_replaces_whole_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "r.json"
    atomic_write(target, b'{"a": 1}')
    atomic_write(target, b'{"a": 2}')
    assert json.loads(target.read_text()) == {"a": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_store_cleans_temporaries_of_a_killed_writer(tmp_path):
    (tmp_path / ".abc.json.tmp123").write_text('{"trunc')
    store = ResultStore(tmp_path).open()
    assert list(tmp_path.iterdir()) == [] and store.get("abc") is None


def test_execute_records_a_failure_instead_of_raising(tmp_path):
    config = load_sweep(_write(tmp_path, FAILING_GRID)).tasks[2].config  # crossover 3 kHz
    result = execute(config)
    assert result["status"] == "failed"
    assert "unstable closed loop" in result["error"] and "\n" not in result["error"]


def _typed(rows: list[dict]) -> list[Row]:
    return [Row.from_json(r) for r in rows]


def test_series_spread_is_sample_std_over_seeds():
    def row(x, seed, mae):
        return {"row": 0, "label": "LIP", "kind": "lip", "mae": {"r1": {"mean": mae, "std": 0.0}},
                "k": x, "seed": seed}
    rows = [row(1.0, s, m) for s, m in enumerate([1.0, 2.0, 4.0])] + [row(2.0, 0, 5.0)]
    data = series(_typed(rows), ["k", "seed"], "k")
    mean, spread, n = data[("LIP", "r1")][1.0]
    assert (mean, n) == (pytest.approx(7 / 3), 3)
    assert spread == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1))  # exact up to rounding
    assert data[("LIP", "r1")][2.0] == (5.0, 0.0, 1)


def test_row_that_the_swept_key_cannot_change_is_one_flat_series():
    lam, hidden = "feedforwards[0].lambda", "feedforwards[0].hidden"
    rows = []
    for lv in (0.0, 0.1):
        for h in (8, 16):
            for seed, lip_mae in ((1, 1.0), (2, 3.0)):
                common = {lam: lv, hidden: h, "seed": seed}
                rows.append({"row": 0, "label": f"PGNN {lv} {h}", "kind": "pgnn",
                             "training": "simultaneous",
                             "mae": {"r2": {"mean": lv + h, "std": 0.0}}, **common})
                rows.append({"row": 1, "label": "LIP", "kind": "lip",
                             "mae": {"r2": {"mean": lip_mae, "std": 0.0}}, **common})
    data = series(_typed(rows), [lam, hidden, "seed"], lam)
    assert set(data) == {("PGNN simultaneous, hidden=8", "r2"),
                         ("PGNN simultaneous, hidden=16", "r2"), ("LIP", "r2")}
    # The LIP of seeds 1 and 2 once each (not once per lambda and n_l), at every lambda.
    for lv in (0.0, 0.1):
        assert data[("LIP", "r2")][lv] == (2.0, pytest.approx(np.std([1.0, 3.0], ddof=1)), 2)
    assert data[("PGNN simultaneous, hidden=16", "r2")][0.1][0] == pytest.approx(16.1)


# ----------------------------------------------------------------------------- running sweeps

def _run_failing(tmp: Path) -> dict:
    out = tmp / "out"
    outcome = run_sweep(load_sweep(_write(tmp, FAILING_GRID)), out, workers=1, quiet=True)
    return {"config": str(tmp / "sweep.yaml"), "out": str(out), "outcome": asdict(outcome)}


@pytest.fixture(scope="session")
def failing_sweep(tmp_path_factory):
    """The four-task sweep with two unstable designs, run once on one local worker (once over
    xdist's workers: its tests only read its folder). One worker is one start-up of the product
    (seconds of imports) instead of two; the dask test then also compares across worker counts,
    and two local workers run in the resume tests."""
    built = build_once(tmp_path_factory, "failing_sweep", _run_failing)
    return load_sweep(Path(built["config"])), Path(built["out"]), Outcome(**built["outcome"])


def test_failed_tasks_are_recorded_and_the_others_finish(failing_sweep):
    sweep, out, outcome = failing_sweep
    assert outcome.exit_code == 1 and outcome.unfinished == 0
    assert [f["controller.crossover_hz"] for f in outcome.failures] == [3000.0, 3000.0]
    table = json.loads((out / "table.json").read_text())
    assert len(table["failures"]) == 2 and table["swept"] == ["controller.crossover_hz", "seed"]
    rows = table["rows"]
    assert len(rows) == 2 * 2  # two good tasks x (feedback only, LIP)
    for row in rows:  # the shared schema, plus the swept keys
        assert {"kind", "training", "lambda", "hidden", "n_seeds", "mae", "theta_phy"} <= set(row)
        assert row["controller.crossover_hz"] == 30.0 and row["seed"] in (1, 2)
    assert (out / "figures" / "mae_vs_controller_crossover_hz.png").stat().st_size > 0
    assert "2 failed task(s)" in (out / "table.md").read_text()
    assert len(list((out / "tasks").glob("*.json"))) == 4


def test_rerun_skips_finished_and_failed_tasks(failing_sweep, tmp_path):
    sweep, stored, first = failing_sweep
    out = shutil.copytree(stored, tmp_path / "out")  # the stored folder is shared: read only
    before = (out / "table.json").read_bytes()
    again = run_sweep(sweep, out, workers=2, quiet=True)
    assert (again.computed, again.reused) == (0, 4)
    assert (out / "table.json").read_bytes() == before


def test_dask_local_cluster_gives_the_local_results(failing_sweep, tmp_path):
    pytest.importorskip("dask.distributed")
    sweep, out, _ = failing_sweep
    outcome = run_sweep(sweep, tmp_path / "dask", backend="dask", workers=2, quiet=True)
    assert outcome.computed == 4 and len(outcome.failures) == 2
    # Same configs, same code, single-threaded tasks: the numbers are identical, bit for bit.
    assert _rows(tmp_path / "dask") == _rows(out)


def _run_resume_grid(tmp: Path) -> dict:
    out = tmp / "uninterrupted"
    run_sweep(load_sweep(_write(tmp, RESUME_GRID)), out, workers=2, quiet=True)
    return {"out": str(out)}


@pytest.fixture(scope="session")
def resume_reference(tmp_path_factory) -> Path:
    """The tasks of RESUME_GRID run without interruption on two local workers, once per
    test run (over xdist's workers too): what an interrupted and resumed sweep must give, bit
    for bit. Tests only read it."""
    return Path(build_once(tmp_path_factory, "resume_reference", _run_resume_grid)["out"])


def test_the_results_line_names_figures_only_where_the_sweep_drew_them(tmp_path,
                                                                        resume_reference):
    """The last line of a finished sweep names what it wrote: its figures where it drew any
    (RESUME_GRID sweeps the encoder resolution), none for a sweep over seeds alone (the line
    named a figures/ folder that was not there)."""
    assert (resume_reference / "figures").is_dir()
    assert results_line(resume_reference) == (f"results in {resume_reference}/ "
                                              "(table.md, table.json, table.csv, figures/)")
    assert results_line(tmp_path) == f"results in {tmp_path}/ (table.md, table.json, table.csv)"


def test_sweep_killed_by_sigkill_resumes_without_recomputing(tmp_path, resume_reference):
    path = _write(tmp_path, RESUME_GRID)
    sweep = load_sweep(path)
    reference = resume_reference

    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "experiments.cli", "sweep", str(path),
                             "--out", str(out), "--workers", "2", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    tasks, seen_bad = out / "tasks", []
    deadline = time.monotonic() + 120
    try:
        # Read every visible result while the sweep writes: each one must be a whole document.
        while time.monotonic() < deadline and proc.poll() is None:
            visible = [p for p in tasks.glob("*.json")] if tasks.exists() else []
            for p in visible:
                try:
                    json.loads(p.read_text())["status"]
                except (ValueError, KeyError, FileNotFoundError) as exc:
                    seen_bad.append((p.name, exc))
            if len(visible) >= 3:
                break
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the sweep finished before it could be killed"
    assert not seen_bad
    stored = {p.stem for p in tasks.glob("*.json")}
    assert 3 <= len(stored) < len(sweep.tasks)
    assert not (out / "table.json").exists()  # no table from a partial grid

    again = load_sweep(path)  # as a new command would
    versions = {json.loads((tasks / f"{k}.json").read_text())["code_version"] for k in stored}
    assert versions == {again.code_version}, "package sources changed during the test"
    # One worker: the reference ran on two, so the table must not depend on the worker count
    # either (and one worker is one start-up of the product, not two, for the few tasks left).
    resumed = run_sweep(again, out, workers=1, quiet=True)
    assert (resumed.reused, resumed.computed) == (len(stored), len(sweep.tasks) - len(stored))
    assert resumed.exit_code == 0
    assert _rows(out) == _rows(reference)
    assert (out / "table.json").read_bytes() == (reference / "table.json").read_bytes()


def test_sweep_stopped_by_sigterm_keeps_whole_results_and_resumes(tmp_path, resume_reference):
    """SIGTERM stops the workers like Ctrl-C: exit 143, no temporary file, no table; the next
    run reuses what was stored and gives the uninterrupted sweep's table."""
    path = _write(tmp_path, RESUME_GRID)
    total = len(load_sweep(path).tasks)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "experiments.cli", "sweep", str(path),
                             "--out", str(out), "--workers", "2", "--quiet"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while proc.poll() is None and not list((out / "tasks").glob("*.json")):
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1] == "clm-sim: terminated"
    stored = list((out / "tasks").glob("*.json"))
    assert 1 <= len(stored) < total and not list((out / "tasks").glob(".*"))
    assert not (out / "table.json").exists()
    resumed = run_sweep(load_sweep(path), out, workers=1, quiet=True)  # as in the test above
    assert (resumed.reused, resumed.computed, resumed.exit_code) == (len(stored),
                                                                     total - len(stored), 0)
    assert _rows(out) == _rows(resume_reference)
    assert (out / "table.json").read_bytes() == (resume_reference / "table.json").read_bytes()


def test_output_folder_of_something_else_is_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    sweep = load_sweep(_write(tmp_path / "..", BASE, f"{tmp_path.name}.yaml"))
    with pytest.raises(UserError, match="does not hold clm-sim sweep results"):
        run_sweep(sweep, tmp_path, workers=1, quiet=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def _seed_rows():
    rows = []
    for lam in (0.0, 0.1):
        for seed, mae in ((1, 1e-7), (2, 2e-7), (3, 6e-7)):
            rows.append({"row": 0, "kind": "pgnn", "training": "simultaneous", "lambda": lam,
                         "hidden": 8, "label": f"PGNN {lam}", "n_seeds": 1,
                         "mae": {"r1": {"mean": mae + lam * 1e-6, "std": 0.0}},
                         "theta_phy": {"mass": 18.0 + seed, "viscous": 1.0, "coulomb": 1.0,
                                       "stiffness": 1.0},
                         "feedforwards[0].lambda": lam, "seed": seed, "task": f"t{seed}"})
    return rows


def test_rows_over_seeds_are_mean_and_sample_std():
    swept = ["feedforwards[0].lambda", "seed"]
    merged = over_seeds(_typed(_seed_rows()), swept)
    assert [m.value("feedforwards[0].lambda") for m in merged] == [0.0, 0.1]
    for m, lam in zip(merged, (0.0, 0.1)):
        assert m.n_seeds == 3 and m.value("seed") is None
        assert m.mae["r1"].mean == pytest.approx(3e-7 + lam * 1e-6, rel=1e-12)
        assert m.mae["r1"].std == pytest.approx(np.std([1e-7, 2e-7, 6e-7], ddof=1), rel=1e-12)
        assert m.theta_phy["mass"] == pytest.approx(20.0)


def test_a_row_the_swept_keys_cannot_change_is_summarized_once():
    swept = ["feedforwards[0].lambda", "seed"]
    lip = [{**row, "row": 1, "kind": "lip", "label": "LIP", "lambda": None,
            "mae": {"r1": {"mean": row["seed"] * 1e-7, "std": 0.0}}} for row in _seed_rows()]
    merged = over_seeds(_typed(_seed_rows() + lip), swept)
    lips = [m for m in merged if m.label == "LIP"]
    assert len(lips) == 1 and lips[0].value("feedforwards[0].lambda") is None
    # Seeds 1, 2, 3 once each, not once per lambda.
    assert lips[0].n_seeds == 3 and lips[0].mae["r1"].mean == pytest.approx(2e-7)
    assert "| – | LIP | 3 | 0.200 ± 0.100 |" in table_md.to_markdown(merged, swept[:1])


def test_sweep_table_gives_mean_and_std_beside_the_per_seed_rows():
    swept = ["feedforwards[0].lambda", "seed"]
    text = sweep_markdown(_typed(_seed_rows()), swept, [])
    summary, every = text.split("## Every task")
    assert "Mean ± std over the 3 swept seeds" in summary
    # std of 0.1, 0.2, 0.6 µm; mass 19, 20, 21 kg over the seeds, the other parameters equal
    assert "| 0 | PGNN 0.0 | 3 | 0.300 ± 0.265 | 20 ± 1 | 1 | 1 | 1 |" in summary
    assert "| 0.1 | PGNN 0.1 | 3 | 0.400 ± 0.265 |" in summary
    assert sum(line.startswith("| 0") for line in every.splitlines()) == 6  # every task's row
    # Without a swept seed there is nothing to average: only the per-task table.
    assert "Mean" not in sweep_markdown(_typed(_seed_rows()[:1]), ["feedforwards[0].lambda"],
                                        [])
