"""Converged profiles (experiments/identifiability.py, experiments/studies/profiles.py): the
warm-started continuation reports a known flat direction flat and closes on a determined one,
records every point's stop reason, never rises along a flat direction, the Gauss-Newton matrix
names the flat direction, and the study's config is read strictly and run by ``study``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from controllers.pgnn import PGNNFeedforward, TrainingData
from experiments import identifiability as ident

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "experiments" / "configs" / "identifiability.yaml"
OPTIMIZER_STOPS = {"converged", "max_iter", "stalled", "theta_moving"}


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
    assert entry["ends"] == {"down": "bound", "up": "bound"}
    assert entry["open"] == [True, True] and entry["why_open"] == ["bound", "bound"]
    assert entry["range"] == pytest.approx(entry["bound"])
    # The start (an unpinned fit stopped at max_iter) may sit a little above the valley floor
    # that its first pinned neighbours reach; from there on the trade is exact. Tolerance:
    # float64 round-off of the least-squares solve.
    costs = [p.data_cost for w in walks for p in w["points"]]
    assert max(costs) - min(costs) <= 1e-9 * min(costs)
    assert max(costs) <= walks[0]["points"][0].data_cost + 1e-9 * min(costs)
    for w in walks:  # each point starts at its neighbour's cost and only descends from there
        chain = [entry["profile"][len(walks[0]["points"])]["data_cost"]] + [
            p.data_cost for p in w["points"]]
        assert ident.monotone([-c for c in chain], tol=1e-9 * min(costs))
        assert all(p.stop in OPTIMIZER_STOPS for p in w["points"])


def test_a_determined_parameter_closes():
    """One tanh unit, needed for the 3 N step in position: moving the mass off its value leaves
    a force dm * a that the unit can carry only by giving up the step (about 0.004 N² more), so
    the profile rises at the first point on both sides and the range around the fit is closed
    (a rising point that stopped at max_iter is an upper bound: it says so, and still closes
    the range the data allow no wider than it)."""
    data = synthetic()
    fit, entry, _ = _profile(data, "mass", 1, delta=0.002, span=1.0, max_iter=100)
    assert all(end.startswith("rises") for end in entry["ends"].values())
    assert entry["open"] == [False, False]
    lo, hi = entry["range"]
    assert lo < fit.theta_["mass"] < hi
    # The range is where the interpolated profile crosses the level: inside the first steps.
    sc = ident.scales(data.phi, data.target)["mass"]
    assert hi - lo < 2.0 * sc


def test_every_point_records_its_stop_reason_and_iterations():
    data = synthetic(constant_y=True)
    _, entry, walks = _profile(data, "viscous", 2, delta=1e-3, span=0.5, max_iter=5)
    for p in entry["profile"]:
        assert p["stop"] in OPTIMIZER_STOPS and 0 <= p["iterations"] <= 200
    assert all(w["end"] in ident.ENDS for w in walks)
    assert sum(len(w["points"]) for w in walks) + 1 == len(entry["profile"])


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
    assert [w["end"] for w in walks] == ["rises", "rises"]
    assert entry["monotone"] == {"down": True, "up": True}
    lo, hi = entry["range"]
    assert lo == pytest.approx(0.5, abs=0.1) and hi == pytest.approx(1.5, abs=0.1)
    assert entry["open"] == [False, False]
    far = ident.walk(fit_at("max_iter"), start, 1, first_step=1e-6, bound=1e6, level=1e30,
                     points=5)
    assert far["end"] == "bound" and far["points"][-1].value == 1e6 and len(far["points"]) == 5
    rising = ident.walk(fit_at("max_iter"), start, 1, first_step=1.0, bound=10.0, level=0.25,
                        points=5)
    entry = ident.parameter_profile(start, rising, rising, 0.0, 0.25, (-9.0, 10.0))
    assert entry["ends"]["up"] == "rises (not converged)"


def test_gauss_newton_names_the_flat_theta_direction():
    """Constant position: the stiffness column is a multiple of the output bias's, so the
    Schur complement of the network block has a zero eigenvalue along the stiffness alone,
    far below every other theta direction's."""
    data = synthetic(constant_y=True)
    lip = dict(zip(THETA_NAMES, np.linalg.lstsq(data.phi, data.target, rcond=None)[0]))
    model = PGNNFeedforward(hidden=3, max_iter=20, continuation_lam=0.0).fit_data(
        data=data, theta_lip=lip, rng=0)
    gn = ident.sloppy_directions(model, data.phi, data.target, count=2)
    flat = gn["theta"][0]
    # Tolerance: the eigenvalue of an exactly dependent column is round-off (~1e-30 N²); the
    # next theta direction, only nearly absorbable by the linearized network, is many orders
    # above it (~1e-8 N² here).
    assert flat["eigenvalue"] < 1e-12 * gn["theta"][1]["eigenvalue"]
    assert abs(flat["direction"]["stiffness"]) == pytest.approx(1.0, abs=1e-6)
    assert len(gn["smallest"]) == 2
    assert all(0.0 <= s["network_share"] <= 1.0 + 1e-12 for s in gn["smallest"])


def test_record_threshold_is_the_spread_over_records():
    assert ident.record_threshold([1.0, 2.0, 3.0]) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        ident.record_threshold([1.0])


def test_valley_range_centres_on_the_start():
    """An unconverged point elsewhere may dip below the start: the range is still the block
    around the start when the start is within the level."""
    values, costs = [0.0, 1.0, 2.0, 3.0], [1.0, 1.05, 2.0, 0.98]
    entry = ident.valley_range(values, costs, 0.98, 0.1, center=0.0)
    assert entry["open"][0] and not entry["open"][1] and entry["range"][1] < 2.0


# ----------------------------------------------------------------------------- the study config

def test_shipped_config_loads():
    from experiments.studies.profiles import load_profiles

    config, settings = load_profiles(CONFIG)
    assert settings.records >= 5 and settings.hidden == (16, 8)
    assert settings.pgnn.weight_decay == 0 and settings.pgnn.continuation_lam == 0


@pytest.mark.parametrize("section,key", [
    ("identifiability:\n  pointz: 3\n", "identifiability.pointz"),
    ("identifiability:\n  records: 1\n", "records"),
    ("identifiability:\n  step: -1\n", "step"),
])
def test_bad_settings_name_the_file_and_key(tmp_path, section, key):
    from experiments.studies.profiles import load_profiles

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
    """A tiny study through the command: two records, n_l = 2, two points per direction; the
    same result in one process and in two."""
    import json

    from experiments.cli import main

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text("name: tiny\nkind: identifiability\nseed: 1\ntraining: {repeats: 1}\n"
                   "identifiability: {hidden: [2], records: 2, max_iter: 3, points: 2}\n")
    out = tmp_path / "out"
    assert main(["study", str(cfg), "--out", str(out), "--quiet", "--workers", "1"]) == 0
    rec = json.loads((out / "identifiability.json").read_text())["sizes"]["2"]
    assert rec["delta"] > 0 and len(rec["best_cost_per_record"]) == 2
    for e in rec["parameters"].values():
        assert set(e["ends"].values()) <= {"rises", "rises (not converged)", "bound"}
        assert len(e["profile"]) >= 3
    assert (out / "report.md").read_text().startswith("# What the data determine")
    assert (out / "figures" / "identifiability.png").is_file()
    # Reproducible: the same bits in two worker processes (every fit is single-threaded).
    again = tmp_path / "again"
    assert main(["study", str(cfg), "--out", str(again), "--quiet", "--workers", "2"]) == 0
    assert json.loads((again / "identifiability.json").read_text())["sizes"] == json.loads(
        (out / "identifiability.json").read_text())["sizes"]


def test_the_figure_reads_the_typed_profiles_of_the_record():
    """The record's keys are read once (profiles_result); the figure draws the fields: the
    profile sorted by value, above the best data cost, and the fits at their θ."""
    from experiments.plots import identifiability_figure
    from experiments.profiles_result import sizes_from_json

    theta = {"mass": 2.0, "viscous": 40.0, "coulomb": 5.0, "stiffness": 100.0}
    params = {name: {"profile": [{"value": v * 1.1, "data_cost": 1.5, "stop": "converged"},
                                 {"value": v * 0.9, "data_cost": 1.2, "stop": "converged"},
                                 {"value": v, "data_cost": 1.0, "stop": "converged"}],
                     "bound": [v * 0.5, v * 1.5], "range": None}
              for name, v in theta.items()}
    record = {"2": {"best_data_cost": 1.0, "delta": 0.1, "parameters": params,
                    "fits": [{"lambda": 0.0, "data_cost": 1.05, "theta": theta}]}}
    sizes = sizes_from_json(record)
    assert sizes["2"].curves["mass"].values == (2.2, 1.8, 2.0)
    assert sizes["2"].fits[0].lam == 0.0 and sizes["2"].delta == 0.1
    fig = identifiability_figure(sizes)
    line = fig.axes[0].lines[0]
    assert list(line.get_xdata()) == [1.8, 2.0, 2.2]
    assert list(line.get_ydata()) == pytest.approx([0.2, 0.0, 0.5])
