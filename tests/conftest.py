"""Shared fixtures: sample time, default PID, and the expensive closed-loop runs (once per session)."""

from __future__ import annotations

import gc
import os
import signal
from pathlib import Path

# Before numpy, scipy or torch load: the kernels the CLI pins (docs/reproducibility.md), so a test
# that runs the CLI in-process computes what `clm-sim` computes.
from clm_sim.numerics import pin_portable_kernels

pin_portable_kernels()

# The suite tests what Ctrl-C does to commands. Run in the background of a non-interactive shell
# (`pytest ... &` in a script), this process starts with SIGINT ignored, and every process it
# starts would inherit that (a command then rightly leaves it ignored). A handler, unlike
# SIG_IGN, is reset to the default at exec: the tests' processes get an ordinary Ctrl-C.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

import numpy as np  # noqa: E402
import pytest

from clm_sim.loop import Dither, simulate
from clm_sim.plant import Plant
from controllers.pid import PIDDesign, design_pid
from experiments.config import ExperimentConfig

TS = 1e-4  # s: the 10 kHz sample time of the product


class ZeroController:
    """``C(z) = 0``: the loop is open and the plant sees only ``u_ff + dither``."""

    b = np.array([0.0])
    a = np.array([1.0])


@pytest.fixture(scope="session")
def ts() -> float:
    return TS


@pytest.fixture(scope="session")
def zero_controller() -> ZeroController:
    return ZeroController()


@pytest.fixture(scope="session")
def default_pid():
    """The default design (30 Hz crossover) for the default plant's linear part."""
    p = Plant()
    return design_pid(mass=p.mass, viscous=p.viscous, stiffness=p.stiffness, design=PIDDesign(),
                      ts=TS)


@pytest.fixture(scope="session")
def r1() -> np.ndarray:
    """One pass of the default training reference r1 (m), 17.6 s."""
    return ExperimentConfig().references["r1"].sample(TS).r


@pytest.fixture(scope="session")
def r1_dither(r1) -> np.ndarray:
    """The default 50 N dither for one pass of r1, from a fixed seed."""
    return Dither().draw(len(r1), np.random.default_rng(12345))


@pytest.fixture(scope="session")
def default_training_run(default_pid, r1, r1_dither):
    """The default plant in closed loop on one pass of r1 with dither."""
    return simulate(Plant(), default_pid, r1, TS, dither=r1_dither)


# The slow tier, measured (`pytest -n auto --durations=0` on a 2-core machine:
# seconds of one case, setup included, wall time in a full run: a ranking, not a figure): tests
# of which one case takes more than about a second of CPU — end-to-end CLI runs, subprocesses
# that import torch, PGNN fits to convergence, the foreign-record diagnoses. Kept here, in one
# list with the measurement that put each test in it, rather than as marks scattered over the
# files; tests marked `@pytest.mark.slow` in their file count too. The seconds also order the
# run (longest first, below): a long test left out of this list starts late and ends the run
# alone. CI runs both tiers.
SLOW = {
    "test_paper_table_page.py": {
        "test_a_fresh_run_of_the_first_seeds_reproduces_the_stored_run_seed_by_seed": 47},
    "test_lambda0.py": {"test_emps_pgnn_runs_on_the_measured_records": 35,
                        "test_a_record_split_over_tasks_gives_what_one_task_gives": 4,
                        "test_paper_cost_lambda0_replays_near_the_lip_without_reversal_spikes": 6},
    "test_sweep.py": {"test_sweep_killed_by_sigkill_resumes_without_recomputing": 25,
                      "test_sweep_stopped_by_sigterm_keeps_whole_results_and_resumes": 15,
                      "test_dask_local_cluster_gives_the_local_results": 10,
                      "test_failed_tasks_are_recorded_and_the_others_finish": 5},  # setup
    # two tiny studies; was 47 s before its phases shared one worker pool
    "test_profiles.py": {"test_study_runs_end_to_end": 17},
    "test_export.py": {"test_strict_warnings_matrix": 14,  # 20 compiles of the AVX2 header
                       "test_cli_exports_a_run_pgnn_that_matches_on_an_unseen_reference": 9},
    # the tiny study (`build_once`: one build for both workers), 14 s of setup; its other tests
    # come later in the slow tier and find it built
    "test_failure_map.py": {"test_tiny_grid_runs_and_every_cell_is_paired": 14},
    "test_pgnn.py": {"test_fit_converges_and_records_how": 13,
                     "test_lambda_zero_costs_no_more_than_the_regularized_fit_of_its_draw": 5,
                     "test_optimized_init_never_costs_more_than_lip": 2,
                     "test_regularized_pgnn_learns_parasitic_force_and_keeps_theta": 3,
                     "test_jacobian_matches_finite_differences": 1,
                     "test_result_does_not_depend_on_the_callers_thread_count": 2,
                     "test_orthogonal_projection_keeps_theta_lip": 1},
    "test_testbed.py": {"test_readme_api_example_runs_from_any_folder": 11,
                        # -n 0: two testbeds, one on the fit pool
                        "test_rows_that_reuse_starts_give_the_same_bits_on_the_fit_pool": 7},
    "test_cli.py": {"test_a_run_whose_rows_reuse_fits_ends_with_nothing_on_stderr": 15,
                    "test_a_command_killed_outright_leaves_no_worker_behind": 10,
                    "test_signal_during_pgnn_fits_ends_workers_without_tracebacks": 8,
                    "test_study_trains_every_seed_it_reports": 6,  # 5 LM iterations a fit
                    "test_two_runs_into_one_out_never_mix": 6,
                    "test_a_command_started_with_ctrl_c_ignored_runs_through_it": 6,
                    "test_a_command_computes_on_one_thread_whatever_the_thread_variables": 3,
                    "test_a_second_ctrl_c_ends_the_command_at_once_and_cleanly": 5,
                    "test_lip_json_of_identify_is_a_diagnose_model": 4,
                    "test_identify_reads_renamed_columns_in_mm_like_the_si_record": 1},
    "test_diagnosis.py": {"test_emulated_machine_config_reports_feedforward_gain": 8,
                          "test_emps_out_of_sample_gain": 6,
                          "test_cli_writes_json_and_report": 5,
                          "test_model_effect_the_data_lacks_is_not_supported": 3,
                          "test_default_plant_cable_carrier_is_cable_slab_not_cogging": 1,
                          "test_hidden_effect_is_named_first_with_its_parameters": 1},
    "test_reproducibility.py": {
        "test_a_users_kernel_choice_wins_and_native_opts_out": 7,
        "test_pinning_before_the_libraries_load_gives_their_avx2_kernels": 6},
    "test_loop.py": {"test_runner_is_deterministic": 5},
    "test_foreign_records.py": {"*": 1},  # 1-3 s of CPU per record
    "test_bad_input.py": {"test_real_process_prints_one_line_and_exits_2": 1},
    "test_plots.py": {"test_importing_plots_chooses_no_backend": 1},
    "test_lip.py": {"test_identify_cli_recovers_independent_record": 3},  # setup
}


def _seconds(item) -> float:
    """The measured seconds of ``item``'s test in :data:`SLOW` (0 where it is not listed)."""
    names = SLOW.get(item.path.name, {})
    return names.get(item.originalname, names.get("*", 0))


@pytest.hookimpl(tryfirst=True)  # the slow marks before `-m` selects on them
def pytest_collection_modifyitems(config, items):
    for item in items:
        names = SLOW.get(item.path.name, ())
        if "*" in names or item.originalname in names:
            item.add_marker(pytest.mark.slow)
    # Longest first (the slow tier, its measured tests by their time, then the rest in file
    # order): pytest-xdist hands tests out in this order, so on two workers the long ones start
    # early and share out evenly instead of one of them ending the run alone. The fixtures that a
    # test pulled forward shares with tests left in place are session-scoped, so that leaving
    # its module does not make a worker build them twice.
    items.sort(key=lambda item: (item.get_closest_marker("slow") is None, -_seconds(item)))


@pytest.hookimpl(tryfirst=True, optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """With ``-n`` (pytest-xdist's ``load``), hand the tests out one at a time in collection order.

    ``load`` starts each worker on a block of the collection (a quarter of its share): with the
    longest tests first, one worker would get all of them. xdist's group scheduler, where every
    test without an ``xdist_group`` mark is a unit of its own, gives each worker its next test
    when it has at most two left: the longest start first and the two workers end together.
    Another ``--dist`` is left as asked."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadGroupScheduling

    return LoadGroupScheduling(config, log)


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """With ``-n``, compile the numba kernels once, before the workers start.

    On a fresh clone there is no numba cache yet (``__pycache__``): both workers, and every
    worker process that the first tests spawn (the paper table's pool, the failure map's,
    the sweeps'), would each compile the same kernels at once, several seconds of CPU apiece.
    Compiled here, they all load the cache. The open loop compiles in a second process while
    this one compiles the closed loop (8 s each on a fresh clone; 9 s side by side against 16 s
    one after the other), then the foreign records' integrator (2.6 s) and the pre-sliding
    states (1.0 s). Nothing else: the product compiles the same way on its first run
    (``clm_sim/kernel.py``)."""
    if os.environ.get("PYTEST_XDIST_WORKER") or not session.config.getoption("numprocesses",
                                                                               None):
        return
    import subprocess
    import sys
    import time

    import reference_sim

    import clm_sim

    start = time.monotonic()
    cache = Path(clm_sim.__file__).parent / "__pycache__"
    beside = None
    if not any(cache.glob("kernel.open_loop-*.nbi")):  # not compiled yet: in a second process
        beside = subprocess.Popen([sys.executable, "-c", "import conftest; "
                                   "conftest.compile_open_loop()"], cwd=Path(__file__).parent)
    simulate(Plant(), ZeroController(), np.zeros(20), TS)  # the closed loop
    # The foreign records' integrator: on a ramp (at rest on zeros the stage sticks and nothing
    # is integrated, and it would compile in every worker).
    reference_sim.run_loop(reference_sim.Stage(), reference_sim.Cascade(60.0, 4700.0, 1e-3),
                           np.linspace(0.0, 1e-2, 20), 1e-3, resolution=1e-7)
    from clm_sim.kernel import dahl_states

    dahl_states(np.zeros(4), 1e-6)  # pre-sliding (clm_sim.effects, the open loop's start)
    if beside is None or beside.wait() != 0:  # cached already, or the second process failed
        compile_open_loop()
    _WARM_UP.append(time.monotonic() - start)


def compile_open_loop() -> None:
    """Compile (or load) the open-loop kernel (:mod:`clm_sim.open_loop`)."""
    from clm_sim.open_loop import initial_state, simulate_input

    plant = Plant()
    y = np.linspace(0.0, 1e-4, 40)
    simulate_input(plant, np.zeros(40), TS, initial_state(y, TS, plant))


_WARM_UP: list = []  # the seconds the kernels took before the workers started (this process)


def pytest_terminal_summary(terminalreporter):
    """Say what the time pytest prints leaves out: it starts after the kernels compiled."""
    if _WARM_UP:
        terminalreporter.write_line(f"numba kernels compiled or loaded before the workers "
                                    f"started: {_WARM_UP[0]:.1f} s (not in the time below)")


def pytest_collection_finish(session):
    """The test modules and the libraries they imported live for the whole run: frozen, the full
    collections of the run do not walk them (a pytest worker's heap is then mostly torch,
    python-control and scipy's), nor does the interpreter's shutdown at the end."""
    gc.freeze()


def pytest_unconfigure(config):
    """What the tests left lives until the process ends: frozen too (see above)."""
    gc.freeze()


@pytest.fixture(scope="session", autouse=True)
def fits_in_the_tests_process():
    """With pytest-xdist (``-n``) every core already runs a test: a test's PGNN fits run in its
    own process rather than on the fit pool (:func:`experiments.processes.workers.map_fits`), whose
    fork server imports torch again and whose fits travel pickled. The pool gives the same bits
    (``test_pgnn.py::test_worker_pool_gives_the_same_bits`` and, for rows that reuse starts,
    ``test_testbed.py::test_rows_that_reuse_starts_give_the_same_bits_on_the_fit_pool``, which
    ask for it: :func:`fit_pool`), and the tests of real ``clm-sim`` processes still run theirs on it. Measured on the 2-core machine: 35 s of
    the suite's 630 s of CPU."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    import experiments.processes.workers

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(experiments.processes.workers, "cores", lambda: 1)
        yield


@pytest.fixture
def fit_pool(monkeypatch) -> list:
    """For a test about the PGNN fit pool (the others fit in their own process under ``-n``,
    above): :func:`experiments.processes.workers.map_fits` uses the pool whatever the cores, and the
    returned list gets an entry each time it does. The pool and its fork server end with the
    test: the fit pool's server imports less than a sweep's, so later pools start their own."""
    from experiments.processes import worker_life, workers
    used, pool = [], workers._pool
    monkeypatch.setattr(workers, "cores", lambda: 2)
    monkeypatch.setattr(workers, "_pool", lambda: used.append(1) or pool())
    yield used
    workers.stop_fits()
    worker_life.stop_server()


def _hypothesis_profiles() -> None:
    """The hostile-input properties' profiles (HYPOTHESIS_PROFILE=long for a deeper search);
    where hypothesis is not installed those tests skip themselves."""
    try:
        from hypothesis import HealthCheck, settings
    except ImportError:
        return
    slow = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
    settings.register_profile("fast", max_examples=30, deadline=None, derandomize=True,
                              suppress_health_check=slow)
    settings.register_profile("long", max_examples=500, deadline=None, suppress_health_check=slow)
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fast"))


_hypothesis_profiles()
