"""Reproducibility: threads pinned whatever the BLAS and shared by threads of one process, CPU
kernels pinned before the libraries load, the environment recorded, and the cross-machine
tolerance with which a published table is compared to a fresh run
(``experiments.stats.agreement``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import threadpoolctl
import torch

from clm_sim import numerics
from clm_sim.plant import THETA_NAMES
from controllers.pgnn import PGNNFeedforward, TrainingData
from experiments.stats import agreement
from experiments.report import table_md
from experiments.table import read_row

ROOT = Path(__file__).resolve().parents[1]


# --- threads ------------------------------------------------------------------------------------

def _blas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpoolctl.threadpool_info()}


def test_single_threaded_pins_every_pool_and_restores_it():
    before_blas, before_torch = threadpoolctl.threadpool_info(), torch.get_num_threads()
    with numerics.single_threaded():
        assert _blas_threads() == {1}
        assert torch.get_num_threads() == 1
        with numerics.single_threaded():  # nested: still one, and the outer exit restores
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 1 and _blas_threads() == {1}
    assert torch.get_num_threads() == before_torch
    assert [i["num_threads"] for i in threadpoolctl.threadpool_info()] == \
        [i["num_threads"] for i in before_blas]


def test_threads_of_one_process_do_not_reset_each_others_limits():
    """torch's and BLAS's thread counts are process-wide: a block that leaves while another
    thread's block is still inside must not restore the counts under it."""
    inside = threading.Barrier(2)
    first_left = threading.Event()
    seen = []

    def short():
        with numerics.single_threaded():
            inside.wait()
        first_left.set()

    def long():
        with numerics.single_threaded():
            inside.wait()
            first_left.wait(timeout=30)
            seen.append((torch.get_num_threads(), _blas_threads()))

    threads = [threading.Thread(target=short), threading.Thread(target=long)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert seen == [(1, {1})]


def _data(n=2000, seed=4) -> TrainingData:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, n)
    y = 0.1 * np.sin(np.pi * t)
    v = 0.1 * np.pi * np.cos(np.pi * t)
    a = -0.1 * np.pi**2 * np.sin(np.pi * t) + rng.standard_normal(n)
    phi = np.column_stack([a, v, np.sign(v), y])
    target = phi @ [18.8, 172.0, 7.21, 20.0] + 2.0 * np.sin(2 * np.pi * y / 0.05) \
        + 0.1 * rng.standard_normal(n)
    return TrainingData(phi=phi, target=target)


def _in_threads(jobs):
    """Run the callables each in its own thread, all at once; their results in order."""
    out = [None] * len(jobs)
    threads = [threading.Thread(target=lambda i=i: out.__setitem__(i, jobs[i]()))
               for i in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    return out


def test_fits_in_threads_of_one_process_do_not_disturb_each_other():
    """Two fits at once in threads of one process give the bits each gives alone in a thread.
    (Against the main thread the comparison would not hold: OpenBLAS's products differ in the
    last bit between the main thread and another one, measured, and a fit amplifies that.)"""
    data = _data()
    theta = dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))

    def fit(seed):
        return lambda: PGNNFeedforward(hidden=8, max_iter=15).fit_data(
            data=data, theta_lip=theta, rng=np.random.default_rng(seed)).network_.state_dict()

    alone = [_in_threads([fit(s)])[0] for s in (0, 1)]
    together = _in_threads([fit(0), fit(1)])
    for a, b in zip(alone, together):
        assert all(torch.equal(a[k], b[k]) for k in a)


HELD = """
import json, sys, threading, warnings, threadpoolctl
from clm_sim.numerics import single_threaded
import numpy
if sys.argv[1] == "held":
    threadpoolctl.threadpool_limits(2)  # a user's limit in the main thread, never undone
out = []
def work():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with single_threaded():
            out.append(max(i["num_threads"] for i in threadpoolctl.threadpool_info()
                           if i["user_api"] == "blas"))
    out.append([str(w.message) for w in caught if w.category is RuntimeWarning])
t = threading.Thread(target=work); t.start(); t.join()
print(json.dumps(out))
"""


@pytest.mark.parametrize("case", ["held", "free"])
def test_a_blas_count_another_thread_holds_is_said(case):
    """threadpoolctl lets only the thread that first set OpenBLAS's count change it: after a
    limit set in the main thread, a fit in another thread runs on that many BLAS threads, and
    single_threaded says so instead of promising bits it cannot give; without it, one thread
    and no warning."""
    out = subprocess.run([sys.executable, "-c", HELD, case], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    threads, warnings = json.loads(out.stdout)
    if case == "held":
        assert threads == 2 and len(warnings) == 1 and "openblas 2" in warnings[0], out.stdout
    else:
        assert threads == 1 and warnings == [], out.stdout


# --- kernels ------------------------------------------------------------------------------------

def _fresh_python(code: str, **env) -> str:
    full = {k: v for k, v in os.environ.items() if k not in numerics.PORTABLE_KERNELS}
    full.pop(numerics.NATIVE_SWITCH, None)
    full.update(env)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


AVX2 = {"avx2", "fma"} <= numerics._cpu_flags() and os.uname().machine == "x86_64"

PROBE = ("from clm_sim import numerics; state = numerics.pin_portable_kernels(); "
         "import numpy, scipy.linalg, torch, json; "
         "print(json.dumps([state, numerics.kernels()]))")


@pytest.mark.skipif(not AVX2, reason="the portable kernels are AVX2 ones: this CPU has no AVX2")
def test_pinning_before_the_libraries_load_gives_their_avx2_kernels():
    state, kernels = json.loads(_fresh_python(PROBE))
    assert state == "portable"
    assert {b["architecture"] for b in kernels["blas"]} == {"Haswell"}
    assert kernels["torch_cpu_capability"] == "AVX2"
    assert kernels["mkl_cbwr"] == "AVX2"
    assert "X86_V4" not in kernels["numpy_simd"]


@pytest.mark.skipif(not AVX2, reason="the portable kernels are AVX2 ones: this CPU has no AVX2")
def test_a_users_kernel_choice_wins_and_native_opts_out():
    state, kernels = json.loads(_fresh_python(PROBE, OPENBLAS_CORETYPE="Sandybridge"))
    assert state == "portable"
    assert {b["architecture"] for b in kernels["blas"]} == {"Sandybridge"}
    state, _ = json.loads(_fresh_python(PROBE, CLM_SIM_NATIVE_KERNELS="1"))
    assert state == "native"


def test_pinning_after_numpy_loaded_says_it_is_too_late():
    code = "import numpy; from clm_sim import numerics; print(numerics.pin_portable_kernels())"
    assert _fresh_python(code) in ("unpinned", "native")  # native: no AVX2 here


def test_environment_names_versions_cpu_and_kernels():
    env = numerics.environment()
    assert env["versions"]["numpy"] == np.__version__
    assert env["versions"]["torch"].split("+")[0] == torch.__version__.split("+")[0]
    assert env["cpu"] and env["kernels"]["blas"]


# --- the cross-machine tolerance ---------------------------------------------------------------

@pytest.mark.parametrize("text,value,ulp", [("0.014", 0.014, 1e-3), ("18.68", 18.68, 1e-2),
                                            ("174.7", 174.7, 0.1), ("32", 32.0, 1.0),
                                            ("1.5e-05", 1.5e-5, 1e-6), ("-4.99", -4.99, 1e-2)])
def test_a_printed_cell_knows_its_last_digit(text, value, ulp):
    cell = agreement.Cell.parse(text)
    assert cell.value == pytest.approx(value) and cell.ulp == pytest.approx(ulp)


def _row(label, mae_r2, thetas, converged=10, kind="pgnn"):
    n = len(mae_r2)
    stat = lambda v: {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1)) if n > 1 else 0.0}
    theta = {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES} if thetas else None
    per_seed = {"r1": list(np.full(n, 2.5e-7)), "r2": list(mae_r2)}
    row = {"label": label, "n_seeds": n, "kind": kind, "training": None, "lambda": None,
           "hidden": None, "mae": {ref: stat(v) for ref, v in per_seed.items()},
           "mae_per_seed": per_seed, "theta_phy": theta, "theta_phy_per_seed": thetas}
    if kind == "pgnn":
        fit = {"theta_drift": 0.1, "data_cost": 1.0, "reg_cost": 0.0, "objective": 1.0,
               "seed": 0, "iterations": 100, "agree": 1, "spread": 0.0,
               "multiple_optima": False}
        row |= {"training": "simultaneous", "lambda": 0.0, "hidden": 16,
                "regularizers": {"weight_decay": 0.0, "orthogonal_weight": 0.0,
                                 "pinn_weight": 0.0, "lambda_diag": None}}
        row["fits"] = [fit | {"stop": "converged"}] * converged + [
            fit | {"stop": "max_iter", "seed": 9, "iterations": 300, "first_order": 1e-3}
        ] * (n - converged)
        row["converged"] = converged
        row |= {k: {"mean": 0.0, "std": 0.0} for k in ("data_cost", "reg_cost", "theta_drift")}
        row["network_peak_beyond_n"] = {}
    return row


def to_markdown(rows: list[dict]) -> str:
    """table.md of rows as stored in a table.json."""
    return table_md.to_markdown([read_row(r) for r in rows])


def _doc(shift_mae=0.0, shift_theta=0.0, converged=10, lip_shift=0.0, std_scale=1.0,
         outlier=0.0):
    """A table of the LIP and one PGNN row of ten seeds; ``shift_mae`` moves the row's r2 MAE
    by that many standard errors, ``std_scale`` scales its spread about the mean,
    ``shift_theta`` moves every seed's stiffness by that many seed-to-seed spreads and
    ``outlier`` moves seed 0's alone (a seed further down the valley)."""
    rng = np.random.default_rng(0)
    mae = 6.9e-7 + 1.6e-7 * rng.standard_normal(10)
    thetas = [{"mass": 18.7, "viscous": 175 + 10 * rng.standard_normal(), "coulomb": 9.5,
               "stiffness": 32 + 18 * rng.standard_normal()} for _ in range(10)]
    se = float(np.std(mae, ddof=1)) / np.sqrt(10)
    mae = mae.mean() + std_scale * (mae - mae.mean())
    spread = float(np.std([t["stiffness"] for t in thetas], ddof=1))
    thetas = [t | {"stiffness": t["stiffness"] + shift_theta * spread} for t in thetas]
    thetas[0]["stiffness"] += outlier * spread
    lip = {"mass": 18.77, "viscous": 159.6 + lip_shift, "coulomb": 7.833, "stiffness": 23.45}
    rows = [_row("LIP", [6.85e-7], [lip], kind="lip"),
            _row("PGNN simultaneous, lambda=0, n_l=16", mae + shift_mae * se, thetas, converged)]
    return {"rows": rows}


@pytest.mark.parametrize("change,agrees", [
    ({}, True),
    ({"shift_mae": 0.8}, True), ({"shift_mae": -0.8}, True),
    ({"shift_mae": 1.6}, False), ({"shift_mae": -1.6}, False),
    ({"shift_theta": 0.9}, True), ({"shift_theta": 1.3}, False),
    ({"converged": 9}, True), ({"converged": 8}, False),
    # most fits capped: the end points are not the data's; 95 % of two independent means
    ({"converged": 3, "page_converged": 3, "shift_mae": 2.5}, True),
    ({"converged": 3, "page_converged": 3, "shift_mae": 3.0}, False),
    # either run saying that most fits did not converge is enough, whichever is the page
    ({"converged": 5, "page_converged": 4, "shift_mae": 2.5}, True),
    ({"converged": 4, "page_converged": 5, "shift_mae": 2.5}, True),
    ({"converged": 5, "page_converged": 5, "shift_mae": 2.5}, False),
    ({"lip_shift": 0.04}, True), ({"lip_shift": 0.3}, False),
    # the spread over seeds: within its standard error (0.24 s for ten seeds) where the fits
    # converged, within 1.96·√2 of it (0.65 s) where most did not
    ({"std_scale": 0.85}, True), ({"std_scale": 0.5}, False),
    ({"converged": 3, "page_converged": 3, "std_scale": 0.5}, True),
    ({"converged": 3, "page_converged": 3, "std_scale": 0.3}, False),
])
def test_the_tolerance_accepts_what_the_seeds_allow_and_no_more(change, agrees):
    change = dict(change)
    base = {"converged": change.pop("page_converged")} if "page_converged" in change else {}
    published = agreement.parse_markdown(to_markdown(_doc(**base)["rows"]))
    mismatches = agreement.compare(published, _doc(**change))
    assert (mismatches == []) == agrees, [str(m) for m in mismatches]


@pytest.mark.parametrize("page,fresh", [({}, {"outlier": 20.0}), ({"outlier": 20.0}, {})])
def test_the_theta_tolerance_is_the_larger_spread_either_way(page, fresh):
    """One seed far down the valley moves the mean by two spreads of the others and makes its
    run's spread six times theirs: the same verdict whichever run is the page (the page
    prints its spread, ``mean ± std``), and a shift of every seed beyond the larger spread
    is still found."""
    published = agreement.parse_markdown(to_markdown(_doc(**page)["rows"]))
    assert " ± " in published[1]["fk [N/m]"]
    assert agreement.compare(published, _doc(**fresh)) == []
    moved = agreement.compare(published, _doc(**(fresh | {"shift_theta": 12.0})))
    assert [(m.row, m.column) for m in moved] == [("PGNN simultaneous, lambda=0, n_l=16",
                                                   "fk [N/m]")]


def test_theta_is_printed_with_its_spread_only_where_the_seeds_differ():
    doc = _doc()
    row = doc["rows"][1]
    row["theta_phy_per_seed"] = [t | {"mass": 18.7 + 1e-15 * i}
                                 for i, t in enumerate(row["theta_phy_per_seed"])]
    line = agreement.parse_markdown(to_markdown(doc["rows"]))[1]
    assert line["m [kg]"] == "18.7" and " ± " in line["fv [N·s/m]"]
    assert agreement.parse_markdown(to_markdown(doc["rows"]))[0]["fv [N·s/m]"] == "159.6"


def test_a_missing_or_extra_row_is_a_mismatch():
    published = agreement.parse_markdown(to_markdown(_doc()["rows"]))
    fresh = _doc()
    fresh["rows"][1]["label"] = "PGNN simultaneous, lambda=0, n_l=8"
    found = {(m.row, m.column) for m in agreement.compare(published, fresh)}
    assert ("PGNN simultaneous, lambda=0, n_l=16", "row") in found
    assert ("PGNN simultaneous, lambda=0, n_l=8", "row") in found


@pytest.mark.parametrize("page, table, expected", [
    ("missing.md", None, "missing.md: cannot read it"),
    ("page.md", "not json", "fresh.json: cannot read it"),
    ("page.md", "[1, 2]", "not a clm-sim table.json"),
    ("empty.md", '{"rows": []}', "no results table"),
])
def test_compare_refuses_bad_files(page, table, expected, tmp_path, capsys):
    from experiments.cli import main

    (tmp_path / "page.md").write_text(to_markdown(_doc()["rows"]), encoding="utf-8")
    (tmp_path / "empty.md").write_text("# nothing here\n", encoding="utf-8")
    if table is not None:
        (tmp_path / "fresh.json").write_text(table, encoding="utf-8")
    code = main(["compare", str(tmp_path / page), str(tmp_path / "fresh.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and expected in err[0], err


def test_compare_names_the_cells_outside_the_tolerance(tmp_path, capsys):
    from experiments.cli import main

    (tmp_path / "page.md").write_text(to_markdown(_doc()["rows"]), encoding="utf-8")
    (tmp_path / "same.json").write_text(json.dumps(_doc()), encoding="utf-8")
    (tmp_path / "moved.json").write_text(json.dumps(_doc(shift_mae=3.0)), encoding="utf-8")
    assert main(["compare", str(tmp_path / "page.md"), str(tmp_path / "same.json")]) == 0
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "page.md"), str(tmp_path / "moved.json")]) == 1
    out = capsys.readouterr().out
    assert "PGNN simultaneous, lambda=0, n_l=16 | MAE r2 [µm]" in out and "outside" in out
