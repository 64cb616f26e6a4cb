"""The EMPS benchmark's folds (one cycle left out), its choice among candidates, and the
training record's plateau friction, on records of the independent reference simulator
(tests/reference_sim.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import reference_sim as ref
from clm_sim.effects.position import ForceOffset
from clm_sim.errors import UserError
from clm_sim.plant import Plant
from experiments.studies.emps.cycles import cycle_edges, left_out
from clm_sim.run import Run

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


def _fit(statuses, rmses, masses=None):
    from experiments.records import output_error as oe

    masses = masses or [20.0] * len(rmses)
    stops = tuple(oe.Stop(f"s{i}", {"mass": 20.0}, {"mass": m}, 1.0, r, st, "", 10, 0.0, 0.0)
                  for i, (st, r, m) in enumerate(zip(statuses, rmses, masses)))
    return oe.SimulationFit(Plant(effects=()), ("mass",), {}, stops)


def test_an_unphysical_end_scores_nan():
    """A start that stopped where the candidate is unphysical (a Stribeck dip deeper than the
    Coulomb level: the fit's flat cost there) gets a NaN test score, not an error that ends the
    study after its fits; a physical end is scored."""
    from clm_sim.effects.friction import Stribeck
    from experiments.studies.emps.benchmark import end_score

    plant = Plant(coulomb=20.0, effects=(Stribeck(peak=-5.0, velocity=0.01, exponent=2.0),))
    assert np.isnan(end_score(plant, {"stribeck": -25.0}, lambda p: 1.0))
    assert end_score(plant, {"stribeck": -10.0}, lambda p: 2.0) == 2.0


def test_equal_costs_at_other_parameters_are_not_the_same_end():
    """Two converged starts within 1 % of the lowest training RMSE are one end only where their
    parameters agree within 2 % (of the size, 20 kg here): 20.3 kg is, 21 kg is a second
    point of a flat valley (the fit is then not a measurement and the starts do not agree)."""
    same = _fit([1, 2], [1.0, 1.002], [20.0, 20.3])
    assert same.measured and len(same.reached()) == 2
    valley = _fit([1, 2], [1.0, 1.002], [20.0, 21.0])
    assert not valley.measured and not valley.agree and len(valley.reached()) == 1


def _row(name, cycles, fit=None, candidate=True):
    from experiments.studies.emps.benchmark import Row

    plant = Plant(mass=18.8, viscous=172.0, coulomb=7.21, effects=(ForceOffset(1.0),))
    return Row(name, "record", plant, 1e-3, 2e-3, candidate, fit, cycles, (2e-3,))


def test_the_rule_picks_the_lowest_mean_among_measured_fits():
    """The lowest mean over the left-out cycles wins, but only among candidates whose fit is a
    measurement: 'lowest' ends at a step-size stop (status 3) that no second start reached,
    so 'next' is chosen; the reference row (not a candidate) is never chosen."""
    from experiments.studies.emps.benchmark import choose

    measured = _fit([2, 1, 3], [1.0, 1.005, 1.3])
    assert measured.measured and measured.agree
    lone = _fit([3, 2], [0.9, 1.2])
    assert not lone.measured
    rows = [_row("reference", (1e-3, 1e-3), candidate=False),
            _row("lowest", (2e-3, 2e-3), lone), _row("next", (3e-3, 2e-3), measured),
            _row("worse", (4e-3, 4e-3), measured)]
    picked = [r.name for r in choose(rows) if r.chosen]
    assert picked == ["next"]
    # Without any measured candidate the rule chooses none.
    assert not any(r.chosen for r in choose([rows[0], rows[1]]))


def test_the_report_names_the_choice_and_the_band(tmp_path):
    """The table marks the chosen row, the verdict compares it with the published model (the
    first row) and gives the band over every end point; benchmark.json's row says chosen."""
    import json

    from experiments.studies.emps.benchmark import BenchmarkRun, choose
    from experiments.studies.emps.report import table, verdict
    from experiments.studies.emps.settings import BenchmarkSettings

    measured = _fit([2, 1], [1.0, 1.001])
    rows = choose([_row("published", (3e-3, 3e-3), candidate=False),
                   _row("a", (2e-3, 2e-3), measured), _row("b", (2.5e-3, 2e-3), measured)])
    settings = BenchmarkSettings(training="a", test="b", cycles=2)
    lines = table(rows, settings)
    assert lines[3].startswith("| a |") and lines[3].endswith("| **yes** |")
    assert lines[2].startswith("| published |") and "(reference)" in lines[2]
    run = BenchmarkRun(rows=rows, pick=rows[1], leak={}, drift=None, sensitivity=[],
                       initial_state={}, cpu_s=0.0, folds=[])
    text = "\n".join(verdict(run, settings))
    assert "**a**, 2.00 ± 0.00 mm over the cycles" in text and "(+0.0 %)" in text
    assert "(whole training record, 2 end points): 2.00 to 2.00 mm" in text
    saved = json.loads(json.dumps(rows[1].to_json()))
    assert saved["chosen"] is True and saved["model_file"] == "models/a.json"


def test_a_cycles_setting_of_one_is_one_line(tmp_path):
    from experiments.studies.emps.settings import load_benchmark

    path = tmp_path / "b.yaml"
    path.write_text("name: b\nbenchmark: {training: a.mat, test: b.mat, cycles: 1}\n")
    with pytest.raises(UserError, match="benchmark.cycles"):
        load_benchmark(path)


def test_the_plateau_friction_follows_a_drift_within_the_record():
    """Model-free: two cycles of one program, the stage's viscous friction 172 N·s/m in the
    first and 190 in the second (two runs joined at rest): the plateau lines give each cycle's
    value, symmetric, and the Coulomb friction in the intercepts."""
    from experiments.studies.emps.cycles import joined
    from experiments.studies.emps.plateaus import cycle_friction, plateaus

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
    from experiments.studies.emps import benchmark as emps_benchmark
    from clm_sim.records.write import save_npz

    def no_work(*args, **kwargs):
        raise AssertionError(f"the benchmark's work ({stub}) started before its checks")

    monkeypatch.setattr(emps_benchmark, stub, no_work)
    monkeypatch.chdir(tmp_path)
    save_npz(record, tmp_path / "rec.npz")
    (tmp_path / "model.yaml").write_text(f"ts: {TS}\nplant: {{mass: 18.8, viscous: 172.0, "
                                         f"coulomb: 7.21}}\n")
    cfg = tmp_path / "b.yaml"
    cfg.write_text("name: b\nkind: emps_benchmark\nbenchmark:\n  training: rec.npz\n"
                   f"  test: rec.npz\n  published_model: model.yaml\n"
                   f"  candidates: [{{name: a}}]\n  {setting}\n")
    return cfg


@pytest.mark.parametrize("setting, key", [("cycles: 100", "benchmark.cycles"),
                                          ("cycles: 3\n  init_samples: 30000",
                                           "benchmark.init_samples")])
def test_a_benchmark_setting_the_record_cannot_meet_is_refused_before_the_work(
        record, tmp_path, capsys, monkeypatch, setting, key):
    """Checked against the records before any model is made (was: after minutes of fits), in
    one line naming the config file and the key that is wrong."""
    from experiments.cli import main

    cfg = _benchmark_without_work(record, tmp_path, monkeypatch, "make_candidate", setting)
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


PAGE_JSON = (Path(__file__).resolve().parents[1] / "docs" / "results" / "emps_models"
             / "benchmark.json")


@pytest.mark.skipif(not PAGE_JSON.exists(), reason="the study's benchmark.json is not shipped "
                    "beside the page")
def test_the_page_table_and_choice_are_the_shipped_study_output():
    """docs/results/emps_benchmark.md against the study output shipped beside it
    (emps_models/benchmark.json): every table row's test RMSE, left-out mean and fit column
    (measured or not, starts that reached the lowest end) is the JSON's; the page marks the
    JSON's chosen row and no other; re-applying the config's rule (lowest left-out mean among
    measured candidates) to the JSON gives that row; the answer quotes its test RMSE and the
    published model's."""
    import json

    docs = PAGE_JSON.parents[1]
    data = json.loads(PAGE_JSON.read_text())
    rows = {r["name"]: r for r in data["rows"]}
    lines = (docs / "emps_benchmark.md").read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("| model |"))
    marked = []
    for line in lines[first + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.split("|")[1:-1]]
        r = rows[cells[0]]
        assert float(cells[2]) == pytest.approx(r["test_rmse_m"] * 1e3, abs=0.005), cells[0]
        if r["left_one_cycle_out_rmse_m"]:
            mean = float(cells[8].split("±")[0])
            assert mean == pytest.approx(r["left_one_cycle_out_mean_m"] * 1e3, abs=0.005)
        if r["fit"] is not None:
            fit = r["fit"]
            state = "measured" if fit["measured"] else "not a measurement"
            assert cells[9] == f"{state}, {fit['reached']}/{len(fit['stops'])} starts"
        if cells[10] == "**yes**":
            marked.append(cells[0])
    eligible = [r for r in data["rows"] if r["candidate"] and r["measured"]]
    rule = min(eligible, key=lambda r: r["left_one_cycle_out_mean_m"])["name"]
    assert marked == [data["chosen"]] == [rule]
    answer = "\n".join(lines[:25])
    assert f"**{rows[rule]['test_rmse_m'] * 1e3:.2f} mm**" in answer
    assert f"**{rows['published model']['test_rmse_m'] * 1e3:.2f} mm**" in answer
