"""Converged profiles (experiments/studies/profiles/identifiability.py,
experiments/studies/profiles/study.py): the warm-started continuation reports a known flat direction
flat and closes on a determined one, records every point's stop reason, never rises along a flat
direction, the Gauss-Newton matrix names the flat direction, and the study's config is read strictly
and run by ``study``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from controllers.pgnn import PGNNFeedforward, TrainingData
from experiments.studies.profiles import identifiability as ident
ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "experiments" / "configs" / "identifiability.yaml"
OPTIMIZER_STOPS = {"converged", "resolved", "max_iter", "stalled", "theta_moving"}


def synthetic(n: int = 1500, seed: int = 0, constant_y: bool = False) -> TrainingData:
    """Motion-like columns and a force theta . T + noise + a step-like position force (3 N
    tanh(30 y)) that a small network must spend its units on; ``constant_y``: the position
    column is constant, so the stiffness trades exactly against the network's output bias."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, n)
    y = np.full(n, 0.05) if constant_y else 0.1 * np.sin(np.pi * t)
    v = 0.1 * np.pi * np.cos(np.pi * t)
    a = -0.1 * np.pi ** 2 * np.sin(np.pi * t) + 2.0 * rng.standard_normal(n)
    phi = np.column_stack([a, v, np.sign(v), y])
    target = (phi @ np.array([18.8, 172.0, 7.2, 20.0]) + 3.0 * np.tanh(30.0 * y)
              + 0.2 * rng.standard_normal(n))
    return TrainingData(phi=phi, target=target)


def _profile(data: TrainingData, name: str, hidden: int, *, delta: float, span: float,
             points: int = 4, max_iter: int = 30):
    """One parameter's profile by continuation from a fit, as the study runs it."""
    lip = dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))
    fit = PGNNFeedforward(hidden=hidden, max_iter=max_iter, continuation_lam=0.0).fit_data(
        data=data, theta_lip=lip, rng=0)
    sc = ident.scales(data.phi, data.target)[name]

    def fit_at(value, beta0):
        m = PGNNFeedforward(hidden=hidden, max_iter=max_iter).fit_pinned(
            data=data, theta_lip=lip, beta0=beta0, pinned={name: value})
        return ident.Point(value, m.fit_.data_cost, m.fit_.stop, m.fit_.iterations,
                           m.network_.get_nonlinear())

    start = ident.Point(fit.theta_[name], fit.fit_.data_cost, fit.fit_.stop,
                        fit.fit_.iterations, fit.network_.get_nonlinear())
    bounds = ident.search_bounds(start.value, lip[name], sc, span)
    walks = [ident.walk(fit_at, start, d, first_step=0.05 * sc, bound=b,
                        level=start.data_cost + delta, points=points)
             for d, b in ((-1, bounds[0]), (1, bounds[1]))]
    return fit, ident.parameter_profile(start, *walks, start.data_cost, delta, bounds), walks


def test_a_known_flat_direction_is_reported_flat_to_the_bound():
    """Constant position: the stiffness trades exactly against the output bias, so every pinned
    fit can reach its neighbour's cost; the continuation follows it to both search bounds, and
    (a warm start never costs more than where it starts) the cost never rises along it."""
    data = synthetic(constant_y=True)
    _, entry, walks = _profile(data, "stiffness", 3, delta=1e-6, span=2.0)
    assert (entry.ends.down, entry.ends.up) == ("bound", "bound")
    assert entry.valley.open == (True, True) and entry.why_open == ("bound", "bound")
    assert entry.valley.limits == pytest.approx(entry.bound)
    # The start (an unpinned fit stopped at max_iter) may sit a little above the valley floor
    # that its first pinned neighbours reach; from there on the trade is exact. Tolerance:
    # float64 round-off of the least-squares solve.
    costs = [p.data_cost for w in walks for p in w.points]
    assert max(costs) - min(costs) <= 1e-9 * min(costs)
    assert max(costs) <= walks[0].points[0].data_cost + 1e-9 * min(costs)
    for w in walks:  # each point starts at its neighbour's cost and only descends from there
        chain = [entry.points[len(walks[0].points)].data_cost] + [p.data_cost for p in w.points]
        assert ident.monotone([-c for c in chain], tol=1e-9 * min(costs))
        assert all(p.stop in OPTIMIZER_STOPS for p in w.points)


def test_a_determined_parameter_closes():
    """One tanh unit, needed for the 3 N step in position: moving the mass off its value leaves
    a force dm * a that the unit can carry only by giving up the step (about 0.004 N² more), so
    the profile rises at the first point on both sides and the range around the fit is closed
    (a rising point that stopped at max_iter is an upper bound: it says so, and still closes
    the range the data allow no wider than it)."""
    data = synthetic()
    fit, entry, _ = _profile(data, "mass", 1, delta=0.002, span=1.0, max_iter=100)
    assert all(end.startswith("rises") for end in (entry.ends.down, entry.ends.up))
    assert entry.valley.open == (False, False)
    lo, hi = entry.valley.limits
    assert lo < fit.theta_["mass"] < hi
    # The range is where the interpolated profile crosses the level: inside the first steps.
    sc = ident.scales(data.phi, data.target)["mass"]
    assert hi - lo < 2.0 * sc


def test_every_point_records_its_stop_reason_and_iterations():
    data = synthetic(constant_y=True)
    _, entry, walks = _profile(data, "viscous", 2, delta=1e-3, span=0.5, max_iter=5)
    for p in entry.points:
        assert p.stop in OPTIMIZER_STOPS and 0 <= p.iterations <= 200
    assert all(w.end in ident.ENDS for w in walks)
    assert sum(len(w.points) for w in walks) + 1 == len(entry.points)


def test_walk_on_a_known_profile():
    """An exact profile (v - 1)**2: the walk closes where it crosses the level (bisected, then
    linear interpolation between points: 0.5 and 1.5 to a tenth of the bracket), is monotone away from the minimum, marks a rising point
    that did not converge, and is decided within its budget however far the bound is."""
    def fit_at(stop):
        return lambda v, beta: ident.Point(v, (v - 1.0) ** 2, stop, 3, beta)

    start = ident.Point(1.0, 0.0, "converged", 3, np.zeros(1))
    walks = [ident.walk(fit_at("converged"), start, d, first_step=0.1, bound=1.0 + d * 100.0,
                        level=0.25, points=6, refine=4) for d in (-1, 1)]
    entry = ident.parameter_profile(start, *walks, 0.0, 0.25, (-99.0, 101.0))
    assert [w.end for w in walks] == ["rises", "rises"]
    assert (entry.monotone.down, entry.monotone.up) == (True, True)
    lo, hi = entry.valley.limits
    assert lo == pytest.approx(0.5, abs=0.1) and hi == pytest.approx(1.5, abs=0.1)
    assert entry.valley.open == (False, False)
    far = ident.walk(fit_at("max_iter"), start, 1, first_step=1e-6, bound=1e6, level=1e30,
                     points=5)
    assert far.end == "bound" and far.points[-1].value == 1e6 and len(far.points) == 5
    rising = ident.walk(fit_at("max_iter"), start, 1, first_step=1.0, bound=10.0, level=0.25,
                        points=5)
    entry = ident.parameter_profile(start, rising, rising, 0.0, 0.25, (-9.0, 10.0))
    assert entry.ends.up == "rises (not converged)"


def test_gauss_newton_names_the_flat_theta_direction():
    """Constant position: the stiffness column is a multiple of the output bias's, so the
    Schur complement of the network block has a zero eigenvalue along the stiffness alone,
    far below every other theta direction's."""
    data = synthetic(constant_y=True)
    lip = dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))
    model = PGNNFeedforward(hidden=3, max_iter=20, continuation_lam=0.0).fit_data(
        data=data, theta_lip=lip, rng=0)
    gn = ident.sloppy_directions(model, data.phi, data.target, count=2)
    flat = gn.theta[0]
    # Tolerance: the eigenvalue of an exactly dependent column is round-off (~1e-30 N²); the
    # next theta direction, only nearly absorbable by the linearized network, is many orders
    # above it (~1e-8 N² here).
    assert flat.eigenvalue < 1e-12 * gn.theta[1].eigenvalue
    assert abs(flat.direction["stiffness"]) == pytest.approx(1.0, abs=1e-6)
    assert len(gn.smallest) == 2
    assert all(0.0 <= s.network_share <= 1.0 + 1e-12 for s in gn.smallest)


def test_record_threshold_is_the_spread_over_records():
    assert ident.record_threshold([1.0, 2.0, 3.0]) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        ident.record_threshold([1.0])


def test_valley_range_centres_on_the_start():
    """An unconverged point elsewhere may dip below the start: the range is still the block
    around the start when the start is within the level."""
    values, costs = [0.0, 1.0, 2.0, 3.0], [1.0, 1.05, 2.0, 0.98]
    entry = ident.valley_range(values, costs, 0.98, 0.1, center=0.0)
    assert entry.open[0] and not entry.open[1] and entry.limits[1] < 2.0


# ----------------------------------------------------------------------------- the study config

def test_shipped_config_loads():
    from experiments.studies.profiles.study import load_profiles

    config, settings = load_profiles(CONFIG)
    assert settings.records >= 5 and settings.hidden == (16, 8)
    # the paper's cost, each record's fit the lowest of its starts
    assert settings.pgnn.weight_decay == 0 and settings.pgnn.starts == ("draw", "lip", "exchange")


@pytest.mark.parametrize("section,key", [
    ("identifiability:\n  pointz: 3\n", "identifiability.pointz"),
    ("identifiability:\n  records: 1\n", "records"),
    ("identifiability:\n  step: -1\n", "step"),
])
def test_bad_settings_name_the_file_and_key(tmp_path, section, key):
    from experiments.studies.profiles.study import load_profiles

    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: identifiability\n" + section)
    with pytest.raises(UserError, match=rf"bad.yaml: .*{key}"):
        load_profiles(bad)


def test_run_sends_a_profile_config_to_study(tmp_path, capsys):
    """The profiles left the paper table: ``run`` on a config with ``identifiability:`` says
    which command runs it (one line, exit 2)."""
    from experiments.cli import main

    bad = tmp_path / "old.yaml"
    bad.write_text("identifiability: {span: 1.0}\n")
    assert main(["run", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "clm-sim study" in err and len(err.strip().splitlines()) == 1
    paper = (ROOT / "experiments" / "configs" / "paper_table.yaml").read_text()
    assert "\nidentifiability:" not in paper


@pytest.mark.slow
def test_study_runs_end_to_end(tmp_path):
    """A tiny study through the command: two records, n_l = 3, short record fits (20
    iterations, 20 more to polish: the profiles' start need not be a minimum for what is
    checked here), two points per direction, a coarse resolution (so that points resolve and
    are checked); the same result in one process and in two; the file reads back into the
    typed record and writes the same."""
    import json

    from experiments.cli import main
    from experiments.studies.profiles.result import sizes_from_json, sizes_to_json

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text("name: tiny\nkind: identifiability\nseed: 1\ntraining: {repeats: 1}\n"
                   "identifiability: {hidden: [3], records: 2, max_iter: 3, points: 2, "
                   "resolution: 1000.0, check: 2, check_iter: 4, polish: 20,\n"
                   "  pgnn: {max_iter: 20, weight_decay: 0, continuation_lambda: 0}}\n")
    out = tmp_path / "out"
    assert main(["study", str(cfg), "--out", str(out), "--quiet", "--workers", "1"]) == 0
    sizes = json.loads((out / "identifiability.json").read_text())["sizes"]
    rec = sizes["3"]
    assert rec["delta"] > 0 and len(rec["best_cost_per_record"]) == 2
    assert rec["atol"] == pytest.approx(1000.0 * rec["delta"], rel=1e-12)
    for e in rec["parameters"].values():
        assert set(e["ends"].values()) <= {"rises", "rises (not converged)", "bound"}
        assert len(e["profile"]) >= 3
        for p in e["profile"]:  # both tests recorded, from the recorded numbers
            assert p["predicted_decrease"] == pytest.approx(p["data_cost"] * p["first_order"])
            assert p["resolution_test"] == (p["predicted_decrease"] <= rec["atol"]
                                            and p["tail_decrease"] <= rec["atol"])
            assert p["relative_test"] == (p["first_order"] <= rec["ftol"])
            # A point's stop is the optimizer's: "resolved" only where the test held.
            assert p["stop"] != "resolved" or p["resolution_test"]
    resolved = [p for e in rec["parameters"].values() for p in e["profile"]
                if p["resolution_test"] and not p["relative_test"]]
    assert resolved and 1 <= len(rec["checks"]) <= 2
    for c in rec["checks"]:  # continued from a resolved point: the cost can only fall
        assert c["moved"] >= 0.0 and c["predicted_decrease"] <= rec["atol"]
        assert c["iterations"] <= 4
    report = (out / "report.md").read_text()
    assert report.startswith("# What the data determine")
    assert "resolution test, checked" in report
    assert (out / "figures" / "identifiability.png").is_file()
    assert sizes_to_json(sizes_from_json(sizes)) == sizes
    # Reproducible: the same bits in two worker processes (every fit is single-threaded).
    again = tmp_path / "again"
    assert main(["study", str(cfg), "--out", str(again), "--quiet", "--workers", "2"]) == 0
    assert json.loads((again / "identifiability.json").read_text())["sizes"] == sizes


def _size_record(theta: dict, costs: tuple, stops: tuple, delta: float = 0.1):
    """A hand-made record: per parameter three points at 1.1, 0.9 and 1 times its value."""
    from experiments.studies.profiles.result import (FirstStop, LipIntervals, MarkedFit, Point,
                                             RecordFit, Sides, SizeRecord, ValleyRange,
                                             WalkSettings)

    zero = dict.fromkeys(THETA_NAMES, 0.0)
    fit = RecordFit(1, 0, 1.0, "max_iter", 3, FirstStop(1.0, "max_iter", 3), 0.0, theta)
    params = {name: ident.parameter_profile(
        Point(v, costs[2], stops[2], 1, first_order=0.0, ftol=1e-4, atol=0.05 * delta),
        ident.Walk((Point(v * 0.9, costs[1], stops[1], 1, first_order=1.0, ftol=1e-4,
                          atol=0.05 * delta),), "bound"),
        ident.Walk((Point(v * 1.1, costs[0], stops[0], 1, first_order=1.0, ftol=1e-4,
                          atol=0.05 * delta),), "bound"), 1.0, delta, (v * 0.5, v * 1.5))
        for name, v in theta.items()}
    return SizeRecord(1.0, delta, (1.0, 1.1), (1, 2), fit, dict.fromkeys(THETA_NAMES, 1.0),
                      WalkSettings(3, 1, 0.25, 4.0, 0, 0, 0.05, 0.05 * delta, 1e-4, 5),
                      (MarkedFit(0.0, 1.05, theta),), (fit,),
                      LipIntervals(zero, zero, zero, 0.0, 1, 10), (1.0, 1.0), zero, zero,
                      params)


def test_the_figure_reads_the_typed_record():
    """The figure draws the record's fields: the profile sorted by value, above the best data
    cost, points that passed a test filled and the others hollow, and the fits at their θ."""
    from experiments.studies.profiles.figures import identifiability_figure

    theta = {"mass": 2.0, "viscous": 40.0, "coulomb": 5.0, "stiffness": 100.0}
    rec = _size_record(theta, (1.5, 1.2, 1.0), ("max_iter", "max_iter", "converged"))
    assert rec.parameters["mass"].points[0].value == pytest.approx(1.8)
    fig = identifiability_figure({2: rec})
    line = fig.axes[0].lines[0]
    assert list(line.get_xdata()) == pytest.approx([1.8, 2.0, 2.2])
    assert list(line.get_ydata()) == pytest.approx([0.2, 0.0, 0.5])
    filled, hollow = fig.axes[0].lines[1], fig.axes[0].lines[2]
    assert list(filled.get_xdata()) == pytest.approx([2.0])  # the start: first_order 0
    assert list(hollow.get_xdata()) == pytest.approx([1.8, 2.2])
    assert hollow.get_markerfacecolor() == "white"


# ----------------------------------------------------------------------------- convergence tests

def test_the_resolution_stop_on_a_linear_problem():
    """On a linear least-squares problem the Gauss-Newton model is exact: at the start it
    predicts the whole decrease to the minimum. Given an ``atol`` above that and no window, the
    optimizer stops at once as ``resolved`` (with the window it steps first); below it, it steps until the rest is within ``atol``;
    without it, it converges by the relative test."""
    from controllers import optim

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((50, 3)), rng.standard_normal(50)
    p_min = np.linalg.lstsq(a, b, rcond=None)[0]
    v_min = float(np.sum((a @ p_min - b) ** 2))

    def fun(p, jacobian):
        r = a @ p - b
        return (r, a) if jacobian else r

    p0 = np.ones(3)
    v0 = float(np.sum((a @ p0 - b) ** 2))
    gap = v0 - v_min
    got = optim.levenberg_marquardt(fun, p0, ftol=1e-12, atol=1.01 * gap, atol_window=0)
    assert got.stop == "resolved" and got.iterations == 0
    # With its window (the default 10 iterations) the prediction alone never resolves a point:
    # it steps first (and here converges by the relative test on the way).
    windowed = optim.levenberg_marquardt(fun, p0, ftol=1e-12, atol=1.01 * gap, max_iter=50)
    assert windowed.iterations >= 1
    assert windowed.stop == "converged" or windowed.iterations >= 10
    # The predicted absolute decrease is the true one (to round-off).
    assert got.cost * got.first_order == pytest.approx(gap, rel=1e-9)
    # Below it: damped steps until the (exact) predicted remaining decrease is within atol.
    got = optim.levenberg_marquardt(fun, p0, ftol=1e-12, atol=0.1 * gap, atol_window=0,
                                    max_iter=50)
    assert got.stop == "resolved" and got.iterations >= 1
    assert got.cost - v_min == pytest.approx(got.cost * got.first_order, rel=1e-6)
    assert got.cost - v_min <= 0.1 * gap
    # With its window (the default 10 iterations), a point that has just fallen by more than
    # atol is not resolved, whatever the model predicts.
    got = optim.levenberg_marquardt(fun, p0, ftol=1e-12, atol=0.1 * gap, max_iter=50)
    assert got.stop != "resolved" or got.iterations > 10
    got = optim.levenberg_marquardt(fun, p0, ftol=1e-12, max_iter=50)
    assert got.stop == "converged" and got.cost == pytest.approx(v_min, rel=1e-9)


def test_a_point_records_both_tests_and_is_never_relabelled():
    """The tests are computed from the recorded first-order measure and last fall, whatever
    the stop: a ``max_iter`` point whose predicted decrease and last fall are within the
    resolution passes that test but keeps its stop; one that passes neither is not settled,
    and a rise at it is marked."""
    p = ident.Point(1.0, 0.1, "max_iter", 100, first_order=0.004, ftol=1e-4, atol=5e-4)
    assert p.predicted_decrease == pytest.approx(4e-4)
    assert p.resolution_test and not p.relative_test and p.settled
    d = p.to_json()
    assert d["stop"] == "max_iter" and d["resolution_test"] and not d["relative_test"]
    q = ident.Point(1.0, 0.1, "max_iter", 100, first_order=0.006, ftol=1e-4, atol=5e-4)
    assert not q.settled
    falling = ident.Point(1.0, 0.1, "max_iter", 100, first_order=0.004, ftol=1e-4, atol=5e-4,
                          tail=6e-4)  # predicted within, but still falling faster than atol
    assert not falling.resolution_test
    unknown = ident.Point(1.0, 0.1, "max_iter", 100)  # no measure: no test passes
    assert not unknown.settled and unknown.to_json()["predicted_decrease"] is None
    start = ident.Point(0.0, 0.0, "converged", 3, first_order=0.0, ftol=1e-4, atol=5e-4)
    for point, end in ((p, "rises"), (q, "rises (not converged)")):
        risen = ident.Walk((ident.Point(2.0, 1.0, point.stop, 100,
                                        first_order=point.first_order * 0.1 / 1.0,
                                        ftol=1e-4, atol=5e-4),), "rises")
        entry = ident.parameter_profile(start, risen, risen, 0.0, 0.5, (-2.0, 2.0))
        assert entry.ends.up == end


def test_pinned_fit_stops_resolved_within_its_tolerance():
    """A pinned PGNN fit given an absolute tolerance stops ``resolved`` once the predicted
    decrease and the fall over its last 10 iterations are within it, never before its tenth
    iteration (and without it, runs on: the same start, more iterations)."""
    data = synthetic()
    lip = dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))
    model = PGNNFeedforward(hidden=3, max_iter=200)
    beta0 = model.new_network(data, np.random.default_rng(0)).get_nonlinear()

    def pinned(max_iter, atol=None):
        return PGNNFeedforward(hidden=3, max_iter=max_iter).fit_pinned(
            data=data, theta_lip=lip, beta0=beta0, pinned={"mass": 18.8}, atol=atol)

    free, ten = pinned(200).fit_, pinned(10)
    start_cost = ten.history_[0].cost
    # A resolution that the descent reaches at its tenth iteration (and the relative test not).
    assert ten.fit_.first_order > ten.fit_.ftol
    fall = start_cost - ten.fit_.data_cost
    atol = 1.001 * max(ten.fit_.data_cost * ten.fit_.first_order, fall)
    got = pinned(200, atol).fit_
    assert got.stop == "resolved" and got.iterations == 10
    assert got.data_cost * got.first_order <= atol
    assert free.iterations > 10 and free.stop != "resolved"


# ----------------------------------------------------------------------------- the record's keys

# identifiability.json's keys (theta names, the LIP-interval names that
# experiments.stats.hac.NeweyWest names, and "bound", also a walk's end reason, aside): none is a
# contract between modules.
_RECORD_KEYS = {
    "range", "open", "inside", "profile", "start", "ends", "monotone", "why_open",
    "value", "data_cost", "stop", "iterations", "tail_decrease", "first_order",
    "predicted_decrease", "relative_test", "resolution_test", "best_data_cost", "delta",
    "delta_from", "best_cost_per_record", "seeds", "scale", "points", "step", "span",
    "refine", "polish", "resolution", "atol", "ftol", "check_iter", "checks", "fits",
    "record_fits", "lip_intervals", "lip_cost_per_record", "lip_over_records", "mean", "std",
    "parameters", "draw", "first", "sloppy", "largest", "smallest", "eigenvalue", "relative",
    "network_share", "direction", "lambda", "continued_cost", "moved", "sizes", "seed",
    "continued_iterations", "confirmed_from",
    "wall_time_s", "down", "up"}


def test_the_record_keys_are_read_and_written_only_in_the_result_module():
    """The study, its report, the walk and the figure read typed fields: no string constant
    (docstrings aside) in them is one of the file's keys; the scan finds them in
    the result module (so it can find a use)."""
    import ast

    def uses(path):
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        return {node.value for node in ast.walk(tree)
                if isinstance(node, ast.Constant) and isinstance(node.value, str)
                and id(node) not in docstrings and node.value in _RECORD_KEYS}

    study = ROOT / "experiments" / "studies" / "profiles"
    for module in ("identifiability.py", "study.py", "report.py"):
        assert uses(study / module) == set(), module
    src = (study / "figures.py").read_text()
    figure = src[src.index("def plot_profile("):src.index("def identifiability_figure(")]
    assert not any(f'"{k}"' in figure for k in _RECORD_KEYS)
    # (lambda's key comes from the alias table, controllers.pgnn_settings.FILE_KEYS)
    assert uses(study / "result.py") == _RECORD_KEYS - {"lambda"}
    assert f'"{ident.ENDS[1]}"' not in figure


def test_a_rise_is_confirmed_before_it_counts():
    """A point that a local test left above the level is continued (``confirm``): where the
    continuation brings it back within the level the walk goes on (to the bound here); where
    it stays above, the direction rises at it, and the point keeps both costs."""
    start = ident.Point(0.0, 0.0, "converged", 3, np.zeros(1))

    def fit_at(v, beta):  # a plateau at 1.0 that a longer descent leaves
        return ident.Point(v, 1.0, "resolved", 2, beta)

    def confirm_to(cost):
        return lambda p: ident.Point(p.value, cost, "max_iter", p.iterations + 50, p.beta,
                                     continued=50, confirmed_from=p.data_cost)

    flat = ident.walk(fit_at, start, 1, first_step=1.0, bound=10.0, level=0.5, points=4,
                      confirm=confirm_to(0.1))
    assert flat.end == "bound" and all(p.confirmed_from == 1.0 for p in flat.points)
    risen = ident.walk(fit_at, start, 1, first_step=1.0, bound=10.0, level=0.5, points=4,
                       refine=1, confirm=confirm_to(0.9))
    assert risen.end == "rises" and len(risen.points) == 2
    assert all(p.continued == 50 and p.data_cost == 0.9 for p in risen.points)
    assert risen.points[0].to_json()["confirmed_from"] == 1.0
    unconfirmed = ident.walk(fit_at, start, 1, first_step=1.0, bound=10.0, level=0.5, points=4)
    assert unconfirmed.end == "rises" and unconfirmed.points[0].confirmed_from is None
