"""The ``clm-sim`` command: bad records for ``identify``, ``export``, the end-to-end baseline."""

from __future__ import annotations

import contextlib
import json
import numbers
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from build_once import build_once
from sessions import session_processes, survivors
from small_config import SMALL_CONFIG

from clm_sim.records.read import load_record
from clm_sim.records.write import save_npz
from experiments.cli import main
from experiments.config import load_config
from experiments.studies.extrapolation.result import ExtrapolationResult

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / "experiments" / "configs" / "lip_baseline.yaml"


def _cli(args, capsys) -> tuple[int, str, list[str]]:
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip().splitlines()


# --------------------------------------------------------------------------------------------
# identify: malformed records
# --------------------------------------------------------------------------------------------

def _table(n=1000, ts=1e-4):
    t = np.arange(n) * ts
    return {"t": t, "r": 0.01 * np.sin(t), "y": 0.01 * np.sin(t), "u": np.cos(t)}


def _write_csv(path, cols):
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[k] for k in names]), delimiter=",",
               header=",".join(names), comments="", fmt="%.17g")


def _without(key):
    return lambda c: {k: v for k, v in c.items() if k != key}


def _nan_in_y(c):
    c["y"][500] = np.nan
    return c


def _backwards_time(c):
    c["t"][400], c["t"][401] = c["t"][401], c["t"][400]
    return c


def _jittered_time(c):
    c["t"][300:] += 0.5e-4
    return c


def _short(c):
    return {k: v[:100] for k, v in c.items()}


# name: (how the good table is spoiled, text the message must contain)
BAD_RECORDS = {
    "missing column u": (_without("u"), "'u'"),
    "missing column t": (_without("t"), "'t'"),
    "NaN in y": (_nan_in_y, "'y'"),
    "time not increasing": (_backwards_time, "'t'"),
    "time not uniform": (_jittered_time, "'t'"),
    "too short": (_short, "too short"),
}


@pytest.mark.parametrize("case", list(BAD_RECORDS))
def test_identify_bad_record(case, tmp_path, capsys):
    spoil, text = BAD_RECORDS[case]
    data = tmp_path / "record.csv"
    _write_csv(data, spoil(_table()))
    out = tmp_path / "out"
    code, _, err = _cli(["identify", data, "--out", out], capsys)
    assert code == 2
    assert len(err) == 1 and err[0].startswith("clm-sim: error: ")
    assert str(data) in err[0] and text in err[0]
    assert not out.exists()  # nothing written for a refused record


@pytest.mark.parametrize("name, content, text", [
    ("absent.csv", None, "not found"),
    ("record.txt", "t,r,y,u\n0,0,0,0\n", "format"),
    ("numbers.csv", "0,0,0,0\n1,0,0,0\n", "header"),
    ("ragged.csv", "t,r,y,u\n0,0,0\n", "columns"),
    ("broken.npz", "not a zip file", "cannot read"),
])
def test_identify_unreadable_file(name, content, text, tmp_path, capsys):
    data = tmp_path / name
    if content is not None:
        data.write_text(content)
    code, _, err = _cli(["identify", data, "--out", tmp_path / "out"], capsys)
    assert code == 2 and len(err) == 1 and str(data) in err[0] and text in err[0]
    assert not (tmp_path / "out").exists()


def test_identify_refuses_a_record_without_motion(tmp_path, capsys):
    data = tmp_path / "still.csv"
    c = _table(5000)
    c["y"][:] = 0.0
    c["r"][:] = 0.0
    _write_csv(data, c)
    code, _, err = _cli(["identify", data, "--out", tmp_path / "out"], capsys)
    assert code == 2 and len(err) == 1 and "excite" in err[0]


# --------------------------------------------------------------------------------------------
# End to end: the shipped baseline config
# --------------------------------------------------------------------------------------------

def _run_baseline(folder: Path) -> dict:
    out = folder / "lip_baseline"
    return {"code": main(["run", str(BASELINE), "--out", str(out), "--quiet"]), "out": str(out)}


@pytest.fixture(scope="session")
def baseline(tmp_path_factory):
    """The baseline run, once (over xdist's workers too: its tests only read it)."""
    built = build_once(tmp_path_factory, "baseline", _run_baseline)
    return built["code"], Path(built["out"])


def check_table_schema(doc: dict, refs=("r1", "r2")) -> None:
    """``table.json`` as the issue fixes it (extra keys after the fixed ones are allowed)."""
    assert set(doc) == {"rows", "environment"} and doc["rows"]  # no comparisons without PGNNs
    assert {"versions", "cpu", "kernels"} <= set(doc["environment"])
    for row in doc["rows"]:
        assert row["kind"] in ("none", "lip", "pgnn")
        assert row["training"] in (None, "sequential", "simultaneous", "pinn")
        assert row["lambda"] is None or isinstance(row["lambda"], numbers.Real)
        assert row["hidden"] is None or (isinstance(row["hidden"], int)
                                         and not isinstance(row["hidden"], bool))
        assert isinstance(row["n_seeds"], int) and row["n_seeds"] >= 1
        assert set(row["mae"]) == set(refs)
        for stat in row["mae"].values():
            assert set(stat) == {"mean", "std"}
            assert 0 < stat["mean"] < 1e-3 and stat["std"] >= 0  # metres, a sane loop
        theta = row["theta_phy"]
        assert theta is None or set(theta) == {"mass", "viscous", "coulomb", "stiffness"}
        assert (theta is None) == (row["kind"] == "none")
        assert list(row)[:7] == ["kind", "training", "lambda", "hidden", "n_seeds", "mae",
                                 "theta_phy"]


@pytest.mark.slow
def test_baseline_run_writes_everything(baseline):
    code, out = baseline
    assert code == 0
    for name in ("config.resolved.yaml", "runs/training.npz", "params/lip.json", "table.md",
                 "table.csv", "table.json"):
        assert (out / name).is_file(), name
    figures = sorted(p.name for p in (out / "figures").glob("*.png"))
    assert {"tracking_r1.png", "tracking_r2.png"} <= set(figures)
    assert all((out / "figures" / f).stat().st_size > 1000 for f in figures)
    assert not list(out.parent.glob(".*partial*"))  # the temporary folder is gone
    # The resolved config reads back as the same experiment.
    assert load_config(out / "config.resolved.yaml") == load_config(BASELINE)


@pytest.mark.slow
def test_baseline_table_schema_and_lip_beats_feedback(baseline):
    code, out = baseline
    assert code == 0
    doc = json.loads((out / "table.json").read_text())
    check_table_schema(doc)
    rows = {row["kind"]: row for row in doc["rows"]}
    assert set(rows) == {"none", "lip"}
    for ref in ("r1", "r2"):
        assert rows["lip"]["mae"][ref]["mean"] < rows["none"]["mae"][ref]["mean"]
        print(f"\nMAE {ref}: feedback {rows['none']['mae'][ref]['mean'] * 1e6:.3f} um, "
              f"LIP {rows['lip']['mae'][ref]['mean'] * 1e6:.3f} um")
    lip = json.loads((out / "params" / "lip.json").read_text())
    for k, v in rows["lip"]["theta_phy"].items():
        assert v == lip[k]  # the table reports the identified parameters, not a copy of them
    md = (out / "table.md").read_text().splitlines()
    assert len(md) == 2 + len(doc["rows"])
    csv = (out / "table.csv").read_text().splitlines()
    assert len(csv) == 1 + len(doc["rows"]) and "mae_r1_mean_m" in csv[0]


@pytest.mark.slow
def test_identify_on_the_logged_training_run_repeats_the_runner_fit(baseline, tmp_path, capsys):
    """``clm-sim identify runs/training.npz`` gives the runner's LIP: same data, same defaults."""
    code, out = baseline
    assert code == 0
    code, printed, _ = _cli(["identify", out / "runs" / "training.npz", "--out", tmp_path],
                            capsys)
    assert code == 0 and "mass" in printed
    mine = json.loads((tmp_path / "lip.json").read_text())
    runner = json.loads((out / "params" / "lip.json").read_text())
    for k in ("mass", "viscous", "coulomb", "stiffness"):
        # Same arithmetic on the same doubles read back from NPZ: equal to round-off.
        assert mine[k] == pytest.approx(runner[k], rel=1e-12, abs=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["csv", "mat"])
def test_export_round_trips_a_logged_run(baseline, fmt, tmp_path, capsys):
    code, out = baseline
    assert code == 0
    source = tmp_path / "part.npz"  # 2 s of the training run: CSV text of 527k rows is slow
    save_npz(load_record(out / "runs" / "training.npz").slice(0, 20000), source)
    target = tmp_path / f"part.{fmt}"
    code, _, _ = _cli(["export", source, "--to", fmt, "--out", target], capsys)
    assert code == 0
    a, b = load_record(source), load_record(target)
    for name, value in a.signals().items():
        # CSV is written with %.17g (round-trips float64); MAT is binary float64.
        np.testing.assert_allclose(getattr(b, name), value, rtol=1e-15, atol=0, err_msg=name)


# --------------------------------------------------------------------------------------------
# identify: column names and units, where it writes, and its lip.json as a diagnose model
# --------------------------------------------------------------------------------------------

def _moving_record(n=60000, ts=1e-4):
    """A stage moving through two sines (1 Hz, 20 mm and 3.3 Hz, 5 mm: acceleration not
    proportional to position) with the exact rigid-body force (m 12 kg, fv 90 N*s/m, fc 4 N,
    fk 30 N/m): motion in both directions that excites every LIP parameter."""
    t = np.arange(n) * ts
    w1, w2 = 2 * np.pi * 1.0, 2 * np.pi * 3.3
    y = 0.02 * np.sin(w1 * t) + 0.005 * np.sin(w2 * t)
    v = 0.02 * w1 * np.cos(w1 * t) + 0.005 * w2 * np.cos(w2 * t)
    a = -0.02 * w1**2 * np.sin(w1 * t) - 0.005 * w2**2 * np.sin(w2 * t)
    return {"t": t, "r": y, "y": y, "u": 12 * a + 90 * v + 4 * np.sign(v) + 30 * y}


def test_identify_reads_renamed_columns_in_mm_like_the_si_record(tmp_path, capsys):
    si = _moving_record()
    _write_csv(tmp_path / "si.csv", si)
    # The same record as a logger might write it: other names, positions in mm, force in V.
    _write_csv(tmp_path / "logger.csv", {"time": si["t"], "ref_mm": si["r"] * 1e3,
                                         "pos_mm": si["y"] * 1e3, "volts": si["u"] / 35.0})
    code, _, _ = _cli(["identify", tmp_path / "si.csv", "--out", tmp_path / "a"], capsys)
    assert code == 0
    code, _, err = _cli(["identify", tmp_path / "logger.csv", "--out", tmp_path / "b",
                         "--columns", "t=time,r=ref_mm,y=pos_mm,u=volts",
                         "--scale", "r=0.001,y=0.001,u=35"], capsys)
    assert code == 0, err
    a = json.loads((tmp_path / "a" / "lip.json").read_text())
    b = json.loads((tmp_path / "b" / "lip.json").read_text())
    for k in ("mass", "viscous", "coulomb", "stiffness"):
        # Same doubles up to the rounding of *1e3*1e-3 and /35*35: far below any fit error.
        assert b[k] == pytest.approx(a[k], rel=1e-9), k
    assert a["mass"] == pytest.approx(12.0, rel=0.01)  # and the fit itself is sane


def test_identify_writes_under_results_never_into_the_current_folder(tmp_path, capsys,
                                                                    monkeypatch):
    _write_csv(tmp_path / "rec.csv", _moving_record())
    monkeypatch.chdir(tmp_path)
    code, printed, _ = _cli(["identify", "rec.csv"], capsys)
    assert code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv", "results"]
    assert (tmp_path / "results" / "identify" / "rec" / "lip.json").is_file()
    assert "results/identify/rec/lip.json" in printed


def test_a_command_computes_on_one_thread_whatever_the_thread_variables(tmp_path):
    """A clm-sim process sets every library's thread count to 1 before they load, whatever the
    caller's OPENBLAS_NUM_THREADS and OMP_NUM_THREADS: a sum split over threads comes out in
    another order, and a command's last digits then followed the machine (the EMPS benchmark
    study's did). After `identify` in a process started with both at 4, every BLAS library runs
    one thread and every thread variable (OpenMP's, which torch reads, among them) is 1."""
    _write_csv(tmp_path / "rec.csv", _moving_record())
    script = ("import json, sys\n"
              "from experiments import cli\n"
              "code = cli.main(sys.argv[1:])\n"
              "import os, threadpoolctl\n"
              "from clm_sim.numerics import THREAD_VARIABLES\n"
              "print(json.dumps([code, sorted({i['num_threads'] for i in "
              "threadpoolctl.threadpool_info()}), sorted({os.environ[k] for k in "
              "THREAD_VARIABLES})]))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "4",
           "OMP_NUM_THREADS": "4"}
    out = subprocess.run([sys.executable, "-c", script, "identify", str(tmp_path / "rec.csv"),
                          "--out", str(tmp_path / "o")], capture_output=True, text=True,
                         env=env, timeout=120)
    code, threads, variables = json.loads(out.stdout.strip().splitlines()[-1])
    assert code == 0, out.stderr
    assert threads == [1] and variables == ["1"], (threads, variables)


def test_identify_bad_column_option_is_one_line(tmp_path, capsys):
    _write_csv(tmp_path / "rec.csv", _moving_record())
    code, _, err = _cli(["identify", tmp_path / "rec.csv", "--out", tmp_path / "o",
                         "--columns", "y"], capsys)
    assert code == 2 and len(err) == 1 and "--columns" in err[0]
    code, _, err = _cli(["identify", tmp_path / "rec.csv", "--out", tmp_path / "o",
                         "--columns", "y=pos"], capsys)
    assert code == 2 and len(err) == 1 and "'pos'" in err[0]
    assert not (tmp_path / "o").exists()


def test_lip_json_of_identify_is_a_diagnose_model(tmp_path, capsys):
    _write_csv(tmp_path / "rec.csv", _moving_record())
    code, _, _ = _cli(["identify", tmp_path / "rec.csv", "--out", tmp_path / "id"], capsys)
    assert code == 0
    lip = json.loads((tmp_path / "id" / "lip.json").read_text())
    code, _, err = _cli(["diagnose", tmp_path / "rec.csv", "--model",
                         tmp_path / "id" / "lip.json", "--out", tmp_path / "diag"], capsys)
    assert code == 0, err
    report = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert "LIP from" in (tmp_path / "diag" / "report.md").read_text()
    # The model is the identified LIP: on its own record it leaves (nearly) nothing to find.
    assert report["gain"]["residual_rms_before"] < 0.05 * np.std(_moving_record()["u"])
    assert lip["kind"] == "lip"


def test_a_lip_file_without_parameters_is_refused_as_model(tmp_path, capsys):
    _write_csv(tmp_path / "rec.csv", _moving_record())
    bad = tmp_path / "lip.json"
    bad.write_text('{"kind": "lip", "mass": 12.0}')
    code, _, err = _cli(["diagnose", tmp_path / "rec.csv", "--model", bad, "--out",
                         tmp_path / "d"], capsys)
    assert code == 2 and len(err) == 1 and str(bad) in err[0] and "viscous" in err[0]
    assert not (tmp_path / "d").exists()


# --------------------------------------------------------------------------------------------
# run and study on each other's configs; SIGTERM
# --------------------------------------------------------------------------------------------

SMALL = SMALL_CONFIG


def test_study_refuses_a_config_without_study_section(tmp_path, capsys):
    cfg = tmp_path / "plain.yaml"
    cfg.write_text(SMALL)
    code, out, err = _cli(["study", cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and out == "" and len(err) == 1
    assert str(cfg) in err[0] and "'study:' section" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain.yaml"]


def test_study_trains_every_seed_it_reports(tmp_path, capsys, monkeypatch):
    import experiments.processes.workers

    # The fits in this process, not on a pool of spawned workers that each import torch (two
    # processes, seconds of CPU apiece): the pool gives the same bits (test_pgnn.py::
    # test_worker_pool_gives_the_same_bits) and is not what this test is about.
    monkeypatch.setattr(experiments.processes.workers, "cores", lambda: 1)
    cfg = tmp_path / "study.yaml"
    # Five LM iterations: the test is about which seeds the summary reports, not the fits.
    # SMALL without its feedforwards: a study trains its own models and refuses them.
    cfg.write_text(SMALL.split("feedforwards:")[0]
                   + "study:\n  lambdas: [0, 0.01]\n  hidden: 4\n  seeds: 2\n"
                   "  outside: [r2]\n  pgnn: {max_iter: 5}\n")
    code, stdout, err = _cli(["study", cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 0, err
    # the screen: the report's findings, then where the full report is (not the whole report)
    report = (tmp_path / "out" / "report.md").read_text()
    assert stdout.splitlines()[0] == report.splitlines()[0]
    assert stdout.splitlines()[-2].startswith(f"Full report: {tmp_path / 'out' / 'report.md'}")
    assert "## Findings" in stdout and "## Table" not in stdout and "## Table" in report
    summary = json.loads((tmp_path / "out" / "study.json").read_text())
    assert ExtrapolationResult.from_json(summary).to_json() == summary
    for key in ("sequential", "lambda=0", "lambda=0.01"):
        variant = summary["variants"][key]
        assert len(variant["theta_phy_per_seed"]) == 2, key
        assert all(len(m["per_seed"]) == 2 for m in variant["mae"].values()), key


def test_run_ends_its_output_with_the_table_the_comparisons_in_brief_and_the_report(
        tmp_path, capsys, monkeypatch):
    """stdout is the results table, one line per compared quantity and setting, and where the
    full report is; each comparison in full is in table.md, not on the screen."""
    import experiments.processes.workers

    # as in the study test above
    monkeypatch.setattr(experiments.processes.workers, "cores", lambda: 1)
    cfg = tmp_path / "pair.yaml"
    cfg.write_text(SMALL + "".join(
        f"  - {{kind: pgnn, training: simultaneous, lambda: {lam}, hidden: 4, seeds: 2, "
        "pgnn: {max_iter: 5, continuation_lambda: 0}}\n" for lam in (0, 0.01)))
    code, stdout, err = _cli(["run", cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 0, err
    out = tmp_path / "out"
    table_md = (out / "table.md").read_text()
    lines = stdout.splitlines()
    assert stdout.startswith(table_md.split("\n\n")[0])  # the table, as table.md has it
    assert any(line.startswith("  MAE on r2, varies lambda: ") and " of 1 hold" in line
        for line in lines), lines
    assert lines[-2].startswith(f"Full report: {out / 'table.md'}")
    assert lines[-1] == f"Figures: {out / 'figures'}/"
    assert not any(line.startswith("- mae") for line in lines)
    assert sum(line.startswith("- mae") for line in table_md.splitlines()) >= 2


def test_run_refuses_a_study_config_and_names_the_study_command(tmp_path, capsys):
    cfg = tmp_path / "study.yaml"
    cfg.write_text(SMALL + "study:\n  seeds: 1\n")
    code, out, err = _cli(["run", cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and out == "" and len(err) == 1
    assert f"clm-sim study {cfg}" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.yaml"]


def _default_signals() -> None:
    """The signals a terminal sends, at their default action in the child: a test run started
    in the background (``nohup``, ``&`` in a script) ignores SIGHUP, SIGINT or SIGQUIT, and the
    command rightly keeps a signal it was started with ignored."""
    for sig in (signal.SIGHUP, signal.SIGINT, signal.SIGQUIT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)


def _clm(args, cwd) -> subprocess.Popen:
    """``clm-sim ARGS`` in a real process of its own session, running this checkout's code."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "experiments.cli", *map(str, args)],
                            cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=env, preexec_fn=_default_signals)


def _wait_for(proc, cond) -> bool:
    while proc.poll() is None and not cond():
        time.sleep(0.005)
    return cond()


def _partial(folder: Path) -> list[Path]:
    return list(folder.glob(".*.partial*"))


def _finish(proc) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated"),
                                             (signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGHUP, 129, "hung up"),
                                             (signal.SIGQUIT, 131, "quit")])
def test_signal_during_run_cleans_up(sig, code, word, tmp_path):
    """A real process: SIGTERM, or Ctrl-C (SIGINT to the whole process group, as a terminal
    sends it), a closed terminal (SIGHUP) or Ctrl-\\ (SIGQUIT), once the temporary result
    folder exists: the exit code, one stderr line, no traceback, no temporary folder or lock,
    no process of the command left."""
    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL)
    proc = _clm(["run", cfg, "--out", tmp_path / "out", "--quiet"], tmp_path)
    seen = _wait_for(proc, lambda: bool(_partial(tmp_path)))
    os.killpg(proc.pid, sig)
    _, err = _finish(proc)
    assert seen, "the run finished before it could be interrupted"
    assert proc.returncode == code, err
    assert err.strip().splitlines() == [f"clm-sim: {word}"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.yaml"]
    assert survivors(proc.pid) == {}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_command_started_with_ctrl_c_ignored_runs_through_it(tmp_path):
    """Started with SIGINT ignored (a background job of a script, which a Ctrl-C meant for the
    script must not stop), the command leaves it ignored, as Python and the POSIX tools do: it
    finishes, exit 0, nothing on stderr, the result folder whole. SIGTERM still ends it."""
    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def start(out):
        return subprocess.Popen(
            [sys.executable, "-m", "experiments.cli", "run", str(cfg), "--out", str(out),
             "--quiet"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, start_new_session=True, env=env,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))

    proc = start(tmp_path / "out")
    seen = _wait_for(proc, lambda: bool(_partial(tmp_path)))
    os.killpg(proc.pid, signal.SIGINT)
    _, err = _finish(proc)
    assert seen, "the run finished before the Ctrl-C"
    assert proc.returncode == 0 and err == "", err
    assert (tmp_path / "out" / "table.json").exists() and not _partial(tmp_path)
    proc = start(tmp_path / "again")
    seen = _wait_for(proc, lambda: bool(_partial(tmp_path)))
    os.killpg(proc.pid, signal.SIGTERM)
    _, err = _finish(proc)
    assert seen and proc.returncode == 143, err
    assert err.strip().splitlines() == ["clm-sim: terminated"], err
    assert not (tmp_path / "again").exists() and not _partial(tmp_path)
    assert survivors(proc.pid) == {}


def _one_run(out: Path) -> int:
    """The seed of the one run that ``out`` describes; fails if its files disagree."""
    seeds = {int(line.split(":")[1]) for line in (out / "config.resolved.yaml").read_text()
             .splitlines() if line.startswith("seed:")}
    seeds.add(load_record(out / "runs" / "training.npz").meta["seed"])
    assert len(seeds) == 1, f"{out} mixes the runs of seeds {seeds}"
    return seeds.pop()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_two_runs_into_one_out_never_mix(tmp_path):
    """Two runs (seeds 1 and 2) into one --out at once: the second is refused in one line
    (exit 2) while the first writes, or it replaces the first's folder as a whole; either way
    the folder describes exactly one run and nothing temporary stays."""
    for seed in (1, 2):
        (tmp_path / f"s{seed}.yaml").write_text(SMALL.replace("seed: 1", f"seed: {seed}"))
    out = tmp_path / "same"
    a = _clm(["run", tmp_path / "s1.yaml", "--out", out, "--quiet"], tmp_path)
    b = _clm(["run", tmp_path / "s2.yaml", "--out", out, "--quiet"], tmp_path)
    _, err_b = _finish(b)
    _, err_a = _finish(a)
    codes = sorted((a.returncode, b.returncode))
    assert codes in ([0, 0], [0, 2]), (err_a, err_b)
    for proc, err in ((a, err_a), (b, err_b)):
        if proc.returncode == 2:
            assert err.strip().splitlines() == [
                f"clm-sim: error: {out}: another clm-sim command is writing this folder; wait "
                f"for it to finish or choose another --out"]
    _one_run(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s1.yaml", "s2.yaml", "same"]


@pytest.mark.slow
def test_a_run_whose_rows_reuse_fits_ends_with_nothing_on_stderr(tmp_path):
    """A run whose continuation row reuses the fits of the row before (as the paper table's do)
    sends torch's tensors to its workers through sockets in multiprocessing's temporary folder;
    the run ends with exit 0 and not a line on stderr (the folder once went before those
    sockets' own clean-up, which then printed a FileNotFoundError traceback at exit)."""
    cfg = tmp_path / "reuse.yaml"
    cfg.write_text(SMALL + (
        "  - {kind: pgnn, training: simultaneous, lambda: 0, hidden: 4, seeds: 2, name: decay,\n"
        "     pgnn: {max_iter: 5, weight_decay: 1.0e-5, continuation_lambda: 0}}\n"
        "  - {kind: pgnn, training: simultaneous, lambda: 0, hidden: 4, seeds: 2, name: cont,\n"
        "     pgnn: {max_iter: 5, weight_decay: 1.0e-5}}\n"))
    proc = _clm(["run", cfg, "--out", tmp_path / "out", "--quiet"], tmp_path)
    _, err = _finish(proc)
    assert proc.returncode == 0, err
    assert err == ""


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_a_command_into_an_out_being_written_is_refused(command, tmp_path, capsys):
    """While another command holds the lock of --out (here: this test), a run or a sweep is
    refused at once in one line and writes nothing."""
    import fcntl

    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL + ("sweep:\n  grid:\n    seed: [1, 2]\n" if command == "sweep" else ""))
    with open(tmp_path / ".out.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        code, stdout, err = _cli([command, cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and stdout == "" and len(err) == 1, err
    assert "another clm-sim command is writing" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".out.lock", "small.yaml"]


PGNN_ROWS = ("  - {kind: pgnn, training: sequential, hidden: 4, seeds: 2, "
             "pgnn: {max_iter: 50}}\n")


def _interrupted_cleanly(proc, err: str, sig, folder: Path, keep: list[str]) -> None:
    code, word = {signal.SIGINT: (130, "interrupted"), signal.SIGTERM: (143, "terminated"),
                  signal.SIGHUP: (129, "hung up"), signal.SIGQUIT: (131, "quit")}[sig]
    assert proc.returncode == code, err
    assert err.strip().splitlines() == [f"clm-sim: {word}"], err
    assert sorted(p.name for p in folder.iterdir()) == keep
    assert survivors(proc.pid) == {}, "a process of the command outlived it"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("moment", ["pool starting", "fits running"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_during_pgnn_fits_ends_workers_without_tracebacks(sig, moment, tmp_path):
    """Ctrl-C (to the whole process group, workers included) or SIGTERM while the PGNN fit pool
    starts or fits: one line, the exit code, no worker traceback, no worker left, nothing
    written."""
    cfg = tmp_path / "pgnn.yaml"
    cfg.write_text(SMALL + PGNN_ROWS)
    proc = _clm(["run", cfg, "--out", tmp_path / "out", "--quiet"], tmp_path)
    started = _wait_for(proc, lambda: len(session_processes(proc.pid)) > 1)
    if moment == "fits running":
        time.sleep(3.0)  # workers have imported torch and fit
    os.killpg(proc.pid, sig)
    _, err = _finish(proc)
    assert started, "the run ended before its fit pool started"
    _interrupted_cleanly(proc, err, sig, tmp_path, ["pgnn.yaml"])


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_command_killed_outright_leaves_no_worker_behind(tmp_path):
    """SIGKILL while the PGNN fit pool fits (no clean-up of the command's own can run): its
    workers see their owner gone and exit, and the process that started them with them."""
    cfg = tmp_path / "pgnn.yaml"
    cfg.write_text(SMALL + PGNN_ROWS)
    proc = _clm(["run", cfg, "--out", tmp_path / "out", "--quiet"], tmp_path)
    # the command and at least one worker (and, on Linux, the fork server that started it)
    started = _wait_for(proc, lambda: len(survivors(proc.pid)) >= 3)
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10.0
    while survivors(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = survivors(proc.pid)
    for pid in left:  # not left running after the test (they hold the command's pipes)
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    _finish(proc)
    assert started, "the run ended before its fit pool started"
    assert left == {}, "a worker outlived the command that was killed"


def _script(tmp_path: Path, text: str, *args: str) -> subprocess.Popen:
    """``text`` run as a Python program of its own session on this checkout's code."""
    path = tmp_path / "script.py"
    path.write_text(text)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, str(path), *args], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=env)


FORKED_UNKNOWN = """\
import sys, time
from experiments.processes import worker_life
if __name__ == "__main__":
    with worker_life.spawning(("time",)):
        # forked by the server, known to no pool: as a worker is while it is being started
        worker = worker_life.context().Process(target=time.sleep, args=(60,))
        worker.start()
    print(worker.pid, flush=True)
    if sys.argv[1] == "server":
        worker_life.stop_server()
    else:  # a pool stopped by an interruption: before its shutdown removes its semaphores
        with worker_life.spawning(("time",)):
            pool = worker_life.new_pool(1)
            pool.submit(time.sleep, 0).result()
        worker_life.stop(pool)
    print("stopped", flush=True)
    time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("stopping", ["server", "pool"])
def test_stopping_the_fork_server_ends_a_worker_no_pool_knows_yet(stopping, tmp_path):
    """A command that ends while its fork server forks a worker (a signal between the fork and
    the pool's record of it, as one CI run met): the worker dies with the server, instead of
    living on to read a task whose semaphores are gone and print a traceback; and a pool
    stopped by the interruption stops the server first (its shutdown removes the semaphores)."""
    proc = _script(tmp_path, FORKED_UNKNOWN, stopping)
    try:
        worker = int(proc.stdout.readline())
        assert proc.stdout.readline().strip() == "stopped"
        deadline = time.monotonic() + 5.0
        while worker in session_processes(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.02)
        alive = [pid for pid in session_processes(proc.pid) if pid == worker]
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert alive == [], "the worker forked by the server outlived it"


SERVER_BEING_STOPPED = """\
import pathlib, sys, time
from experiments.processes import process, worker_life
stop = worker_life._wait_stopped

def slow_stop(pid, timeout_s=0.5):  # the server stopped (SIGSTOP), not yet killed: for 3 s
    if not pathlib.Path("stopping").exists():
        pathlib.Path("stopping").write_text("")
        time.sleep(3.0)
    stop(pid, timeout_s)

worker_life._wait_stopped = slow_stop

def command():
    with worker_life.spawning(("time",)):
        pool = worker_life.new_pool(1)
        pool.submit(time.sleep, 0).result()
    pathlib.Path("ready").write_text("")
    time.sleep(60)

if __name__ == "__main__":
    process.receive_signals()
    sys.exit(process.run(command, program=True, name="test"))
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_command_that_ends_while_it_stops_its_fork_server_leaves_it_killed(tmp_path):
    """An interrupted command stops its fork server (SIGSTOP: it forks nothing more while its
    children are listed) and kills it; if the command's one-second guard ends it in between
    (here: the stop made to last 3 s), the server is killed on the way out, not left stopped for
    good, holding the command's stderr (a stress run waited 300 s on that pipe)."""
    proc = _script(tmp_path, SERVER_BEING_STOPPED)
    started = _wait_for(proc, lambda: (tmp_path / "ready").exists())
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        left = survivors(proc.pid)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert started and (tmp_path / "stopping").exists(), err
    assert (proc.returncode, err.splitlines()) == (130, ["clm-sim: interrupted"]), err
    assert left == {}, "a process of the command outlived it"


BUSY_WITH_STDERR_GONE = """\
import pathlib, signal, sys, time
from experiments.processes import process
def command():
    # As inside a long library call: the main thread does not take the signal thread's poke,
    # which then ends the process itself.
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGUSR1})
    pathlib.Path("computing").write_text("")
    time.sleep(30)
    return 0

if __name__ == "__main__":
    process.receive_signals()
    sys.exit(process.run(command, program=True, name="test"))
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_command_whose_stderr_is_gone_still_ends_on_a_signal(tmp_path):
    """Ctrl-C while the main thread is inside a long library call: the signal thread ends the
    process. With stderr a pipe nobody reads any more (``clm-sim run … 2>&1 | head``), writing
    the line fails; the process still ends with 130. Were the signal thread to die there, the
    command would run on, and an interrupted one would wait forever for the lock that thread
    held."""
    proc = _script(tmp_path, BUSY_WITH_STDERR_GONE)
    started = _wait_for(proc, lambda: (tmp_path / "computing").exists())
    proc.stderr.close()
    os.killpg(proc.pid, signal.SIGINT)
    try:
        code = proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        code = None
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert started
    assert code == 130, "the command hung after the signal" if code is None else code


DISPOSITIONS_WHILE_STARTING = """\
import signal
from experiments.processes import process, worker_life
if __name__ == "__main__":
    process.receive_signals()
    before = [signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)]
    with worker_life._starting():
        during = [signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)]
    print(before == during, signal.SIG_IGN in during, flush=True)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_starting_workers_leaves_a_commands_signal_handlers_alone(tmp_path):
    """Workers start with Ctrl-C and SIGTERM blocked, as the command has them (its signal thread
    takes them); setting them to "ignore" meanwhile, as the command did at every submit, discards
    a signal that is pending: a sweep's SIGTERM, sent as a task file appeared, was lost and the
    sweep ran to its end (exit 0)."""
    out, err = _finish(_script(tmp_path, DISPOSITIONS_WHILE_STARTING))
    assert out.split() == ["True", "False"], err


WORKER_CPU = """\
import resource, time
from experiments.processes import worker_life
def burn():
    start = time.process_time()
    while time.process_time() - start < 0.5:
        pass
    return time.process_time() - start

if __name__ == "__main__":
    with worker_life.spawning(("time",)):
        pool = worker_life.new_pool(1)
        burned = pool.submit(burn).result()
    worker_life.stop(pool)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(burned, children.ru_utime + children.ru_stime, flush=True)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_stopped_pools_cpu_counts_in_its_owners_children(tmp_path):
    """``/usr/bin/time`` of a command counts its workers' CPU (the paper table's CPU is measured
    so): a stopped pool's workers are reaped by the fork server before it is ended, and the
    server by the command. Killed and left to init instead, a worker's CPU vanished from the
    figure (the paper table's 148 s read 38 s)."""
    proc = _script(tmp_path, WORKER_CPU)
    out, err = _finish(proc)
    assert proc.returncode == 0, err
    burned, children = map(float, out.split())
    assert children >= burned >= 0.5, (burned, children)


SWALLOWED = """\
import pathlib, sys, time
from experiments.processes import process
class Slow:
    def __del__(self):  # a finalizer: what Python's garbage collection runs anywhere
        pathlib.Path("in finalizer").write_text("")
        start = time.monotonic()
        while time.monotonic() - start < 20.0:
            pass

def command():
    Slow()
    pathlib.Path("ran on").write_text("")
    return 0

if __name__ == "__main__":
    process.receive_signals()
    sys.exit(process.run(command, program=True, name="test"))
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_that_lands_in_a_finalizer_still_ends_the_command(sig, tmp_path):
    """Python drops an exception raised in a finalizer ("Exception ignored in ..."), the
    interruption's too: a signal taken while the main thread runs one still ends the command
    (one run of a PGNN config met it in a weakref callback and exited 0 with its results)."""
    proc = _script(tmp_path, SWALLOWED)
    started = _wait_for(proc, lambda: (tmp_path / "in finalizer").exists())
    os.killpg(proc.pid, sig)
    _, err = _finish(proc)
    assert started, err
    # nothing written after the signal (the command would write "ran on"), nothing left running
    _interrupted_cleanly(proc, err, sig, tmp_path, ["in finalizer", "script.py"])


AFTER_THE_COMMAND = """\
import atexit, pathlib, sys, time, types
from experiments.processes import process
def busy(marker, open=open, monotonic=time.monotonic):  # (modules are gone at the end)
    open(marker, "w").close()
    start = monotonic()
    while monotonic() - start < 20.0:
        pass

class Late:
    def __del__(self, busy=busy):  # run by the interpreter's shutdown, after exit handlers
        busy("in phase")

def leave_one_behind():  # in a module of its own, which the shutdown tears down
    module = types.ModuleType("late")
    module.late = Late()
    sys.modules["late"] = module

def command():
    if sys.argv[1] == "exit handler":
        atexit.register(busy, "in phase")
    pathlib.Path("result").write_text("")
    return 0

if __name__ == "__main__":
    if sys.argv[1] == "interpreter shutdown":  # the last exit handler leaves an object behind
        atexit.register(leave_one_behind)
    process.receive_signals()
    sys.exit(process.run(command, program=True, name="test"))
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("phase", ["exit handler", "interpreter shutdown"])
def test_a_signal_after_the_results_are_written_ends_with_its_code(phase, tmp_path):
    """docs/cli.md: a signal after the results were written still ends the command with 130
    or 143 and one line. It may come while the exit handlers run (the fit pool, the fork
    server, the libraries' clean-ups are stopped), where the signal thread answers; the
    interpreter's shutdown, where no thread answers any more (the signal would be lost and the
    command exit 0), does not run: a finalizer it would run never starts."""
    proc = _script(tmp_path, AFTER_THE_COMMAND, phase)
    reached = _wait_for(proc, lambda: (tmp_path / "in phase").exists())
    if reached:
        os.killpg(proc.pid, signal.SIGTERM)
    _, err = _finish(proc)
    assert (tmp_path / "result").exists(), err
    expected = (143, "clm-sim: terminated\n") if reached else (0, "")
    assert (proc.returncode, err) == expected, err
    assert reached == (phase == "exit handler")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_sweep_ends_workers_and_keeps_finished_tasks(sig, tmp_path):
    """A sweep interrupted while its workers compute: one line, the exit code, no worker left,
    only whole task files kept (a re-run resumes from them)."""
    cfg = tmp_path / "grid.yaml"
    cfg.write_text(SMALL + "sweep:\n  grid:\n    seed: [1, 2, 3, 4]\n")
    out = tmp_path / "out"
    proc = _clm(["sweep", cfg, "--out", out, "--quiet", "--workers", "2"], tmp_path)
    started = _wait_for(proc, lambda: len(session_processes(proc.pid)) > 2)
    time.sleep(1.0)
    os.killpg(proc.pid, sig)
    _, err = _finish(proc)
    assert started, "the sweep ended before its workers started"
    _interrupted_cleanly(proc, err, sig, tmp_path, ["grid.yaml", "out"])
    for task in (out / "tasks").iterdir():
        assert not task.name.startswith("."), task
        json.loads(task.read_text())
    assert not (out / "table.json").exists()


# --------------------------------------------------------------------------------------------
# data that look wrong but may be right: one warning line each, the command goes on
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def small_training_run(tmp_path_factory):
    from experiments.testbed import Testbed

    cfg = tmp_path_factory.mktemp("small") / "small.yaml"
    cfg.write_text(SMALL)
    return Testbed(load_config(cfg)).training_run()


def _variant(run, **changes) -> dict:
    s = {k: run.signals()[k] for k in ("t", "r", "y", "u")}
    return {**s, **{k: edit(s) for k, edit in changes.items()}}


@pytest.mark.parametrize("case, changes, warning", [
    ("as logged", {}, None),
    ("y and r swapped", {"y": lambda s: s["r"], "r": lambda s: s["y"]}, "swapped"),
    ("force of the wrong sign", {"u": lambda s: -s["u"]}, "does not push y as a force should"),
])
def test_identify_warns_about_suspicious_records(case, changes, warning, small_training_run,
                                                 tmp_path, capsys):
    from clm_sim.records.write import save_csv
    from clm_sim.run import Run

    data = tmp_path / "rec.csv"
    save_csv(Run(**_variant(small_training_run, **changes)), data)
    code, out, err = _cli(["identify", data, "--out", tmp_path / "id"], capsys)
    assert code == 0, err
    warnings = [line for line in err if line.startswith("clm-sim: warning: ")]
    assert err == warnings
    if warning is None:
        assert warnings == []
    else:
        assert len(warnings) == 1 and str(data) in warnings[0] and warning in warnings[0], err


@pytest.mark.parametrize("scale, model_mass, warned", [(1.0, 18.8, False),
                                                       (1 / 35.15, 18.8, True),  # volts
                                                       (1.0, 18800.0, True)])  # grams
def test_a_mass_far_from_the_records_is_a_warning(scale, model_mass, warned,
                                                  small_training_run):
    from clm_sim.run import Run
    from controllers.lip import LIPFeedforward
    from experiments.records.suspicions import record_warnings

    run = Run(**_variant(small_training_run, u=lambda s: s["u"] * scale))
    lip = LIPFeedforward().fit(y=run.y, u=run.u, ts=run.ts)
    lines = record_warnings(run, lip, model_mass=model_mass)
    assert [("forgotten --scale" in line) for line in lines] == ([True] if warned else [])


def test_identify_names_the_file_and_option_of_a_filter_above_nyquist(small_training_run,
                                                                     tmp_path, capsys):
    from clm_sim.records.write import save_npz

    data = tmp_path / "rec.npz"
    save_npz(small_training_run, data)
    code, out, err = _cli(["identify", data, "--lowpass-hz", 6000, "--out", tmp_path / "id"],
                          capsys)
    assert code == 2 and out == "" and len(err) == 1, err
    assert str(data) in err[0] and "--regression-lowpass-hz" in err[0] and "Nyquist" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


def test_a_plant_mass_outside_any_carriage_is_a_warning():
    from clm_sim.plant import Plant
    from experiments.records.suspicions import plant_warnings

    assert plant_warnings(Plant(), "plant") == []
    (line,) = plant_warnings(Plant(mass=18800.0), "plant")
    assert line.startswith("plant.mass: 18800 kg")


def test_a_full_disk_during_a_run_is_one_line_and_leaves_nothing(tmp_path, capsys,
                                                                  monkeypatch):
    """The disk fills up while the run writes (simulated: the first record write fails with
    ENOSPC, as np.savez then raises it without a file name)."""
    import errno

    import experiments.runner

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(experiments.runner, "save_npz", full)
    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL)
    code, out, err = _cli(["run", cfg, "--out", tmp_path / "out", "--quiet"], capsys)
    assert code == 2 and out == "", err
    assert err == [f"clm-sim: error: {tmp_path / 'out'}: cannot write: No space left on device"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.yaml"]


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
@pytest.mark.parametrize("gap_s", [0.0, 0.002, 0.05])
def test_a_second_ctrl_c_ends_the_command_at_once_and_cleanly(gap_s, tmp_path):
    """Two Ctrl-C in a row while the PGNN fit pool works (the second may land in the clean-up
    of the first): still exit 130, one line, nothing written, no process left."""
    cfg = tmp_path / "pgnn.yaml"
    cfg.write_text(SMALL + PGNN_ROWS)
    proc = _clm(["run", cfg, "--out", tmp_path / "out", "--quiet"], tmp_path)
    started = _wait_for(proc, lambda: len(session_processes(proc.pid)) > 1)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(gap_s)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGINT)
    _, err = _finish(proc)
    assert started, "the run ended before its fit pool started"
    # A second signal in the clean-up may leave the pools' semaphores to multiprocessing's
    # resource tracker, which removes them and says so (docs/cli.md); nothing else may print.
    lines = [line for line in err.splitlines() if "resource_tracker" not in line]
    _interrupted_cleanly(proc, "\n".join(lines), signal.SIGINT, tmp_path, ["pgnn.yaml"])
    assert "Traceback" not in err, err
