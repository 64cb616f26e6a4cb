"""Rule C of the EMPS benchmark (leave one cycle out, one-standard-error rule) and the training
record's plateau friction, on records of the independent reference simulator
(tests/reference_sim.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import reference_sim as ref
from clm_sim.effects import Cogging, ForceOffset, FrictionAsymmetry, Presliding, Stribeck
from clm_sim.errors import UserError
from clm_sim.plant import Plant
from clm_sim.record import Run
from experiments.studies.emps_cycles import (CycleScores, cycle_edges, fitted_parameters,
                                             left_out, one_se_choice)

TS = 1e-3
MOVES = [(0.05, 0.05), (0.1, 0.1), (0.05, 0.08), (0.0, 0.04)]  # one cycle: two speeds up, two down


def _record(cycles: int, viscous=(172.0,), seed=3) -> Run:
    """``cycles`` repetitions of MOVES; the viscous friction of each cycle from ``viscous``
    (cycled), so a drift within the record can be made."""
    r = ref.trapezoid_reference(TS, moves=MOVES * cycles, accel=1.0, dwell=0.1)
    rec = ref.run_loop(ref.Stage(mass=18.8, viscous=viscous[0], coulomb=7.21),
                       ref.Cascade(kp=160.0, kv=1700.0, ts=TS), r, TS, resolution=1e-7,
                       dither_std=5.0, seed=seed)
    return Run(t=rec.t, r=rec.r, y=rec.y, u=rec.u, meta={"source": "reference_sim"})


@pytest.fixture(scope="module")
def record() -> Run:
    return _record(3)


def test_the_cycles_are_cut_at_the_low_reversals_of_the_reference(record):
    edges = cycle_edges(record.r, 3)
    assert edges[0] == 0 and edges[-1] == len(record) and len(edges) == 4
    # Each cut is a minimum of the reference at the low end of the stroke, 0 m here.
    for i in edges[1:-1]:
        assert record.r[i] == pytest.approx(0.0, abs=1e-9)
        assert record.r[i + 5] > record.r[i] and record.r[i - 200:i].max() > record.r[i]
    # The cycles repeat one program: equal lengths within two samples, the first one with the
    # record's initial 0.1 s at rest.
    lengths = np.diff(edges) - np.array([100, 0, 0])
    assert lengths.max() - lengths.min() <= 2


def test_a_wrong_number_of_cycles_is_one_line(record):
    with pytest.raises(UserError, match="benchmark.cycles: 4 cycles need 3 reversals.*has 2"):
        cycle_edges(record.r, 4)


def test_leaving_a_cycle_out_keeps_it_out_of_the_estimation_part(record):
    edges = cycle_edges(record.r, 3)
    rest, held = left_out(record, edges, 1)
    assert np.array_equal(held.y, record.y[edges[1]:edges[2]])
    assert np.array_equal(rest.y, np.concatenate([record.y[:edges[1]], record.y[edges[2]:]]))
    assert len(rest) + len(held) == len(record)
    # One time base, the record's sample time, without a gap at the seam.
    np.testing.assert_allclose(np.diff(rest.t), TS, rtol=1e-9)
    # The seam is a reversal at one position: the reference jumps by less than a sample's
    # travel at the reversal's speed (here 1 m/s^2 * 1 ms * 1 ms).
    assert abs(rest.r[edges[1]] - rest.r[edges[1] - 1]) < 1e-5


def _scores(means, ses, params):
    """CycleScores of four cycles with the given means and standard errors: the values m ± d
    twice each have a standard deviation d·√(4/3), so a standard error d/√3."""
    out = {}
    for name, m, s, p in zip("abcd", means, ses, params):
        d = s * np.sqrt(3.0)
        out[name] = CycleScores((m - d, m - d, m + d, m + d), p)
    return out


def test_the_one_se_rule_names_the_simplest_within_one_standard_error():
    scores = _scores([4.0, 4.8, 6.0, 4.9], [1.0, 0.5, 0.2, 0.1], [13, 5, 4, 5])
    assert scores["a"].mean == pytest.approx(4.0) and scores["a"].se == pytest.approx(1.0)
    # b (5 parameters, 4.8) and d (5, 4.9) are within 4.0 + 1.0; c (4 parameters) is not.
    assert one_se_choice(scores) == "b"


def test_the_one_se_rule_keeps_the_best_where_it_is_clearly_better():
    scores = _scores([4.0, 4.8, 6.0], [0.3, 0.5, 0.2], [13, 5, 4])
    assert one_se_choice(scores) == "a"


def test_the_parameters_counted_are_those_taken_from_data():
    lip = Plant(mass=95.0, viscous=200.0, coulomb=20.0, stiffness=3.0,
                effects=(ForceOffset(force_n=-3.0),))
    assert fitted_parameters(lip) == 5
    assert fitted_parameters(dataclasses.replace(lip, stiffness=0.0)) == 4
    extended = dataclasses.replace(lip, effects=(
        ForceOffset(force_n=-3.0), ForceOffset(force_n=2.6),
        Stribeck(peak=-6.4, velocity=0.013, exponent=2.0),
        Cogging(amplitude=1.0, period=0.0025, phase=-0.2),
        FrictionAsymmetry(viscous_pos=-38.0, viscous_neg=38.0),
        Presliding(sliding=1.8, stiffness=4050.0)))
    # M, Fv, Fc, k, one offset, Stribeck 2, cogging 3, asymmetry 1, pre-sliding 2.
    assert fitted_parameters(extended) == 13


def test_a_cycles_setting_of_one_is_one_line(tmp_path):
    from experiments.studies.emps_benchmark import load_benchmark

    path = tmp_path / "b.yaml"
    path.write_text("name: b\nbenchmark: {training: a.mat, test: b.mat, cycles: 1}\n")
    with pytest.raises(UserError, match="benchmark.cycles"):
        load_benchmark(path)


def test_the_page_prints_rule_c_and_its_choice(record):
    """Rule C's choice is the simple row within one standard error of the richer one (which has
    the lowest mean), printed with its table beside rules A and B."""
    from experiments.diagnosis.model import SimulationModel
    from experiments.simulation import simulate_record
    from experiments.studies.emps_benchmark import BenchmarkSettings, Row, to_markdown

    truth = Plant(mass=18.8, viscous=172.0, coulomb=7.21, effects=(), encoder_resolution=1e-7)
    held = record.slice(2 * len(record) // 3)

    def row(name, mass, cycles, plant=truth):
        sim = lambda m, run: simulate_record(  # noqa: E731
            SimulationModel(dataclasses.replace(truth, mass=18.8 * m), None, name, TS), run)
        return Row(name, "record", plant, 0.0, sim(mass, record), sim(mass, record), 0.0, 0.0,
                   held_out=sim(mass, held), held_out_back=sim(mass, held), cycles=cycles)

    rich = dataclasses.replace(truth, stiffness=2.0, effects=(
        ForceOffset(force_n=1.0), Cogging(amplitude=1.0, period=0.0025, phase=0.0)))
    rows = [row("published", 1.3, CycleScores((9e-3, 9e-3, 9e-3), 4)),
            row("rich", 1.02, CycleScores((3e-3, 5e-3, 7e-3), fitted_parameters(rich)), rich),
            row("simple", 1.05, CycleScores((5e-3, 5.5e-3, 6e-3), fitted_parameters(truth),
                                            ("M 18.1", "M 18.2", "M 18.3")))]
    page = to_markdown("b", rows, BenchmarkSettings(training="a", test="b", cycles=3), "cmd")
    assert "(lowest mean: rich, 5.00 ± 1.15 mm)" in page
    assert "Left one cycle out (rule C" in page and "the choice is **simple**" in page
    assert "| simple | 3 | 5.00 | 5.50 | 6.00 | 5.50 ± 0.29 | yes |" in page
    assert "| published | 4 | 9.00 | 9.00 | 9.00 | 9.00 ± 0.00 | (not a candidate) |" in page
    assert "- simple, without cycle 3: M 18.3" in page
    # benchmark.json carries each row's cycle scores and its parameter count.
    import json

    saved = json.loads(json.dumps(rows[2].to_json()))
    assert saved["left_one_cycle_out_rmse_m"] == [5e-3, 5.5e-3, 6e-3]
    assert saved["fitted_parameters"] == 3


def test_the_plateau_friction_follows_a_drift_within_the_record():
    """Model-free: two cycles of one program, the stage's viscous friction 172 N·s/m in the
    first and 190 in the second (two runs joined at rest): the plateau lines give each cycle's
    value, symmetric, and the Coulomb friction in the intercepts."""
    from experiments.studies.emps_cycles import joined
    from experiments.studies.emps_plateaus import cycle_friction, plateaus

    # Three speeds each way, so that a line through them can miss one.
    moves = [(0.04, 0.04), (0.08, 0.08), (0.14, 0.12), (0.10, 0.06), (0.06, 0.1), (0.0, 0.03)]
    r = ref.trapezoid_reference(TS, moves=moves, accel=1.0, dwell=0.1)
    runs = []
    for viscous, seed in ((172.0, 5), (190.0, 6)):
        x = ref.run_loop(ref.Stage(mass=18.8, viscous=viscous, coulomb=7.21),
                         ref.Cascade(kp=160.0, kv=1700.0, ts=TS), r, TS, resolution=1e-7,
                         dither_std=0.5, seed=seed)
        runs.append(Run(t=x.t, r=x.r, y=x.y, u=x.u))
    rec = joined(runs)
    rows = cycle_friction(plateaus(rec, cycle_edges(rec.r, 2), min_samples=50))
    assert [r.cycle for r in rows] == [0, 1]
    # Three plateaus a direction, 0.3-1 s each, 0.5 N of dither: the slopes within 1 % (an
    # 18 N·s/m drift is 10 %), the intercepts within 2 % of the Coulomb friction.
    for row, viscous in zip(rows, (172.0, 190.0)):
        assert row.viscous == pytest.approx(viscous, rel=0.01)
        assert abs(row.viscous_odd) < 0.01 * viscous
        assert row.intercept_up == pytest.approx(7.21, rel=0.02)
        assert row.intercept_down == pytest.approx(-7.21, rel=0.02)
        # The reference stage's friction is affine in speed: every plateau on its line within
        # the dither's mean over a plateau (0.5 N / sqrt(500 samples) ~ 0.02 N, and 0.1 N).
        assert row.off_line_n < 0.1
    # A friction that is not affine in speed (a Stribeck rise of 3 N fading by 0.05 m/s: 1.6 N
    # at 0.04 m/s, 0.2 N at 0.08) leaves a plateau off its line (the line takes up part of it).
    x = ref.run_loop(ref.Stage(mass=18.8, viscous=172.0, coulomb=7.21, stribeck_peak=3.0,
                               stribeck_velocity=0.05),
                     ref.Cascade(kp=160.0, kv=1700.0, ts=TS), r, TS, resolution=1e-7,
                     dither_std=0.5, seed=7)
    run = Run(t=x.t, r=x.r, y=x.y, u=x.u)
    (row,) = cycle_friction(plateaus(run, cycle_edges(run.r, 1), min_samples=50))
    assert row.off_line_n > 0.1


def _benchmark_without_work(record, tmp_path, monkeypatch, stub: str, setting: str = ""):
    """A benchmark config on ``record`` in ``tmp_path`` (the current folder), with
    ``emps_benchmark.<stub>`` replaced by a function that fails the test if the work starts."""
    from clm_sim.record import save_npz
    from experiments.studies import emps_benchmark

    def no_work(*args, **kwargs):
        raise AssertionError(f"the benchmark's work ({stub}) started before its checks")

    monkeypatch.setattr(emps_benchmark, stub, no_work)
    monkeypatch.chdir(tmp_path)
    save_npz(record, tmp_path / "rec.npz")
    (tmp_path / "model.yaml").write_text(f"ts: {TS}\nplant: {{mass: 18.8, viscous: 172.0, "
                                         f"coulomb: 7.21}}\n")
    cfg = tmp_path / "b.yaml"
    cfg.write_text("name: b\nkind: emps_benchmark\nbenchmark:\n  training: rec.npz\n"
                   f"  test: rec.npz\n  published_model: model.yaml\n  {setting}\n")
    return cfg


@pytest.mark.parametrize("setting, key", [("cycles: 100", "benchmark.cycles"),
                                          ("init_samples: 30000", "benchmark.init_samples")])
def test_a_benchmark_setting_the_record_cannot_meet_is_refused_before_the_work(
        record, tmp_path, capsys, monkeypatch, setting, key):
    """Checked against the records before any model is made (was: after minutes of fits), in
    one line naming the config file and the key that is wrong."""
    from experiments.cli import main

    cfg = _benchmark_without_work(record, tmp_path, monkeypatch, "make_models", setting)
    code = main(["study", str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert str(cfg) in err[0] and key in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_benchmark_out_that_is_no_benchmark_is_refused_before_the_work(
        record, tmp_path, capsys, monkeypatch):
    """An existing folder that is not a benchmark's result, as --out: refused before the fits
    (the review found it refused only when the result was written, after minutes of work)."""
    from experiments.cli import main

    cfg = _benchmark_without_work(record, tmp_path, monkeypatch, "run_benchmark")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    code = main(["study", str(cfg), "--out", str(mine), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and str(mine) in err[0], err
    assert (mine / "notes.txt").read_text() == "mine"


def test_a_split_leaves_each_part_a_window_to_score():
    """An estimation fraction that leaves a part its initialization but fewer than the
    scored samples a simulation needs is refused naming the fraction (the review found it
    refused only after the fits, naming an option the study does not have)."""
    from clm_sim.errors import UserError
    from clm_sim.open_loop import MIN_SCORED_SAMPLES
    from clm_sim.record import Run
    from experiments.studies.emps_benchmark import split

    n, init = 1000, 20
    t = np.arange(n) * TS
    run = Run(t=t, r=t, y=t, u=t)
    est, held = split(run, 0.5, init)
    assert len(est) + len(held) == n
    tight = (n - init - MIN_SCORED_SAMPLES + 1) / n  # the held-out part one sample short
    with pytest.raises(UserError, match="benchmark.estimation_fraction"):
        split(run, tight, init)
    with pytest.raises(UserError, match="benchmark.init_samples"):
        split(run, 0.5, n // 2)
