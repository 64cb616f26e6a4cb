"""What the data determine about theta_phy at lambda = 0: converged profiles, their threshold
from the training records, the LIP's own intervals and the fits' sloppy directions.

Per network size (``identifiability.hidden``) and on the config's plant:

1. ``records`` training records (dither seeds ``seed, seed + 1, ...``), each with its LIP and
   ``draws`` PGNN fits on the profiled cost (``pgnn:``; default the paper's: mean squared error,
   no network weight decay, no continuation start); the best data cost of each record gives the
   threshold ``delta`` (its standard deviation over the records), and the Gauss-Newton matrix of
   each fit its sloppy directions
   (:func:`experiments.studies.profiles.identifiability.sloppy_directions`);
2. on the first record, from its best fit, the warm-started continuation of the data cost's
   profile over each physical parameter, in both directions
   (:func:`experiments.studies.profiles.identifiability.walk`: ``points`` points per direction at
   most, each of ``max_iter`` Levenberg-Marquardt iterations at most, steps ``step * scale_k``
   doubling, out to ``span * scale_k`` beyond the hull of theta* and theta_LIP); a point stops when
   converged (the optimizer's relative test) or resolved (predicted decrease and last fall within
   ``resolution * delta``), and a point above delta is continued ``check_iter`` iterations
   before the rise counts;
3. the check of the resolution: the ``check`` resolved points with the largest predicted
   decrease, continued ``check_iter`` iterations (how far their cost still falls);
4. the LIP's Newey-West intervals on that record and its spread over the records, beside the
   profile ranges.

The record of each network size is a :class:`experiments.studies.profiles.result.SizeRecord`.

``clm-sim study CONFIG`` dispatches here for ``kind: identifiability``; ``identifiability.json``,
``report.md``, ``config.resolved.yaml`` and ``figures/identifiability.png`` are written into the
output folder. The fits run in ``--workers`` processes; the result does not depend on how many.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from clm_sim.schema import build, load_yaml, to_plain
from controllers.pgnn.fit_record import FitRecord
from controllers.pgnn_settings import PGNNSettings
from experiments.config import ExperimentConfig, resolved
from experiments.processes.workers import cores
from experiments.studies.kinds import preflighted, refuse_unread, take_kind
from experiments.studies.profiles import identifiability as ident
from experiments.studies.profiles.report import to_markdown
from experiments.studies.profiles.result import (Check, FirstStop, LipIntervals, MarkedFit, Point,
                                                 ProfilesResult, RecordFit, SizeRecord, Walk,
                                                 WalkSettings)
from experiments.studies.protocol import Study
from experiments.testbed import STREAM_NETWORK, Testbed, stream


_LOW, _GT_ZERO = "integer at least", "number above zero"  # a setting's constraint


def _at_least(low: int) -> dict:
    return {_LOW: low}


_POSITIVE = {_GT_ZERO: True}


@dataclass(frozen=True)
class ProfileSettings:
    """The ``identifiability:`` section of a config.

    hidden: network sizes n_l profiled; records: training records (dither seeds), >= 2 (the
    threshold is their spread; 5 or more for a usable one); draws: network draws per record;
    pgnn: the fit settings profiled (lambda is 0; default: the paper's cost); polish: further
    Levenberg-Marquardt iterations for a record's fit that did not converge (0: none); max_iter:
    Levenberg-Marquardt iterations per profile point at most; resolution: a profile point is
    resolved (and stops) when the Gauss-Newton model predicts an absolute decrease of its data
    cost of at most this fraction of delta and its cost fell by no more over its last 10
    iterations (besides the optimizer's relative test, ``pgnn.ftol``);
    check: how many resolved points are continued for ``check_iter`` more iterations to test
    that resolution (those with the largest predicted decrease; 0: none; besides, every point
    that rises above delta is continued as long before the rise counts); points: profile points
    per direction at most (the budget); step: first step in units of scale_k (the change of
    theta_k that alone moves the force by its rms); span: how far beyond the hull of theta* and
    theta_LIP the search goes, in units of scale_k; refine: bisections of the step where a profile rises
    (locating the range's end); sloppy: smallest Gauss-Newton directions reported per fit.
    """

    hidden: tuple[int, ...] = (16, 8)
    records: int = field(default=5, metadata=_at_least(2))
    draws: int = field(default=1, metadata=_at_least(1))
    pgnn: PGNNSettings = field(default_factory=lambda: PGNNSettings(
        weight_decay=0.0, continuation_lam=0.0))
    polish: int = field(default=400, metadata=_at_least(0))
    max_iter: int = field(default=100, metadata=_at_least(1))
    resolution: float = field(default=0.05, metadata=_POSITIVE)
    check: int = field(default=4, metadata=_at_least(0))
    check_iter: int = field(default=500, metadata=_at_least(1))
    points: int = field(default=8, metadata=_at_least(1))
    step: float = field(default=0.25, metadata=_POSITIVE)
    span: float = field(default=4.0, metadata=_POSITIVE)
    refine: int = field(default=2, metadata=_at_least(0))
    sloppy: int = field(default=3, metadata=_at_least(1))

    def __post_init__(self):
        # Each setting's constraint is declared once, beside it (the field's metadata).
        for f in fields(self):
            value, low = getattr(self, f.name), f.metadata.get(_LOW)
            if f.metadata.get(_GT_ZERO) and not value > 0:
                raise UserError(f"{f.name}: expected a number > 0, got {value!r}")
            if low is not None and not (isinstance(value, int) and not isinstance(value, bool)
                                        and value >= low):
                raise UserError(f"{f.name}: expected an integer >= {low}, got {value!r}")
        if not self.hidden or not all(isinstance(h, int) and h >= 1 for h in self.hidden):
            raise UserError(f"hidden: expected a list of integers >= 1, got {self.hidden!r}")


def load_profiles(path) -> tuple[ExperimentConfig, ProfileSettings]:
    """Read a profile study config (an experiment config plus ``identifiability:``); errors
    name the file and the key."""
    path = Path(path)
    data = take_kind(load_yaml(path), path, "identifiability")
    raw = data.pop("identifiability", None)
    try:
        refuse_unread(data, "identifiability", "identifiability", ("data",))  # before the build: it assumes a run
        config = build(ExperimentConfig, data, "config")
        refuse_unread(data, "identifiability", "identifiability")
        settings = build(ProfileSettings, raw, "identifiability")
    except UserError as exc:
        raise UserError(f"{path}: {str(exc).removeprefix('config.').removeprefix('config: ')}") \
            from None
    return config, settings


def _fit_settings(settings: ProfileSettings, hidden: int, max_iter: int | None = None) -> dict:
    """The keyword arguments of a profile's PGNN (lambda = 0, simultaneous)."""
    out = dict(asdict(settings.pgnn), hidden=hidden, lam=0.0, training="simultaneous")
    if max_iter is not None:
        out.update(max_iter=max_iter)
    return out


# ----------------------------------------------------------------------------- phase 1: records

@dataclass(frozen=True)
class RecordFitRun:
    """A record's fit as phase 2 needs it: the typed row, the fit record (its first-order
    measure and tolerance) and its hidden layers (the profiles' start)."""

    row: RecordFit
    fit: FitRecord
    beta: np.ndarray


@dataclass(frozen=True)
class RecordRun:
    """One training record's outcome: its index and seed, its LIP (named, SI) with its data
    cost (N**2) and Newey-West intervals, per network size its fits (and, on the first record
    only, the fitting data the profiles walk on)."""

    index: int
    seed: int
    lip: dict[str, float]
    lip_cost: float
    lip_intervals: LipIntervals
    fits: dict[int, tuple[RecordFitRun, ...]]
    data: dict[int, object]

    def best(self, hidden: int) -> RecordFitRun:
        return min(self.fits[hidden], key=lambda f: f.row.data_cost)


def run_record(task: tuple) -> RecordRun:
    """One training record: its LIP (with Newey-West intervals) and, per network size, its
    ``draws`` fits with their stop reasons and sloppy directions. ``task``: (config, settings,
    record index)."""
    import torch

    from controllers.pgnn import PGNNFeedforward, training_data

    torch.set_num_threads(1)
    config, settings, index = task
    seed = config.seed + index
    tb = Testbed(config)
    run = tb.training_run(seed=seed)
    lip = tb.fit_lip(run)
    theta_lip = np.array([lip.theta_[k] for k in THETA_NAMES])
    fits, kept, intervals, lip_cost = {}, {}, None, None
    for hidden in settings.hidden:
        fs = _fit_settings(settings, hidden)
        data = training_data(config.features, y=run.y, u=run.u, ts=run.ts,
                             decimation=fs.get("decimation"))
        if intervals is None:
            intervals = ident.lip_intervals(data.phi, data.target)
            lip_cost = float(np.mean((data.target - data.phi @ theta_lip) ** 2))
        rows = []
        for draw in range(settings.draws):
            model = PGNNFeedforward(**fs, features=config.features).fit_data(
                data=data, theta_lip=lip.theta_,
                rng=np.random.default_rng(stream(seed, STREAM_NETWORK, draw)))
            first = FirstStop(model.fit_.data_cost, model.fit_.stop, model.fit_.iterations)
            if settings.polish and model.fit_.stop != "converged":
                # Continue the same descent (nothing pinned) before the fit is a profile's start
                # or a record's best cost: a fit stopped at max_iter is still falling.
                model = PGNNFeedforward(**dict(fs, max_iter=settings.polish),
                                        features=config.features).fit_pinned(
                    data=data, theta_lip=lip.theta_, beta0=model.network_.get_nonlinear(),
                    pinned={})
            row = RecordFit(seed, draw, model.fit_.data_cost, model.fit_.stop,
                            model.fit_.iterations, first, ident.tail_decrease(model.history_),
                            dict(model.theta_),
                            ident.sloppy_directions(model, data.phi, data.target,
                                                    settings.sloppy))
            rows.append(RecordFitRun(row, model.fit_, model.network_.get_nonlinear()))
        fits[hidden] = tuple(rows)
        if index == 0:
            kept[hidden] = data
    return RecordRun(index, seed, dict(lip.theta_), lip_cost, intervals, fits, kept)


# ----------------------------------------------------------------------------- phase 2: profiles

@dataclass(frozen=True)
class DirectionTask:
    """One direction of one parameter's profile: the network size, its fitting data, theta_LIP,
    the start point, the parameter, the direction (+1 or -1), the search bound (SI), the level
    where the profile counts as risen (N**2) and the resolution (N**2)."""

    hidden: int
    data: object
    theta_lip: dict[str, float]
    start: Point
    name: str
    direction: int
    bound: float
    level: float
    atol: float


def run_direction(task: tuple) -> tuple[str, int, Walk]:
    """(config, settings, DirectionTask) -> (parameter, direction, the walk); each point stops
    at the optimizer's relative test, at the resolution test (predicted decrease <= ``atol``,
    N**2) or at ``settings.max_iter``."""
    import torch

    from controllers.pgnn import PGNNFeedforward

    torch.set_num_threads(1)
    config, settings, t = task
    fs = _fit_settings(settings, t.hidden, settings.max_iter)
    sc = ident.scales(t.data.phi, t.data.target)[t.name]

    def fit_at(value: float, beta0: np.ndarray) -> Point:
        model = PGNNFeedforward(**fs, features=config.features).fit_pinned(
            data=t.data, theta_lip=t.theta_lip, beta0=beta0, pinned={t.name: value},
            atol=t.atol)
        return ident.point_of(value, model.fit_, atol=t.atol,
                              beta=model.network_.get_nonlinear(),
                              tail=ident.tail_decrease(model.history_))

    def confirm(point: Point) -> Point:  # a rise counts at the end of a longer descent
        model = PGNNFeedforward(**dict(fs, max_iter=settings.check_iter),
                                features=config.features).fit_pinned(
            data=t.data, theta_lip=t.theta_lip, beta0=point.beta, pinned={t.name: point.value})
        return ident.point_of(point.value, model.fit_, atol=t.atol,
                              beta=model.network_.get_nonlinear(),
                              tail=ident.tail_decrease(model.history_), before=point)

    got = ident.walk(fit_at, t.start, t.direction, first_step=settings.step * sc,
                     bound=t.bound, level=t.level, points=settings.points,
                     refine=settings.refine, confirm=confirm)
    return t.name, t.direction, got


def run_check(task: tuple) -> Check:
    """The test of a resolved point: (config, settings, hidden, data, theta_lip, name, Point)
    -> the same pinned fit continued from the point's hidden layers for
    ``settings.check_iter`` iterations (no resolution stop): how far its data cost still
    fell."""
    import torch

    from controllers.pgnn import PGNNFeedforward

    torch.set_num_threads(1)
    config, settings, hidden, data, theta_lip, name, point = task
    fs = _fit_settings(settings, hidden, settings.check_iter)
    model = PGNNFeedforward(**fs, features=config.features).fit_pinned(
        data=data, theta_lip=theta_lip, beta0=point.beta, pinned={name: point.value})
    return Check(name, point.value, point.data_cost, point.predicted_decrease,
                 model.fit_.data_cost, model.fit_.stop, model.fit_.iterations)


def compute(config: ExperimentConfig, settings: ProfileSettings, *, workers: int = 1,
            progress=None) -> dict[int, SizeRecord]:
    """Every record, then every profile direction, then the checks (in ``workers`` processes
    when > 1); the result does not depend on ``workers``."""
    from experiments.processes.workers import local_pool, map_in_order

    # One pool for all phases: its workers import torch once, not once a phase.
    with local_pool(workers) if workers > 1 else contextlib.nullcontext() as pool:
        return _compute(config, settings, workers, pool, progress or (lambda message: None))


def _compute(config: ExperimentConfig, settings: ProfileSettings, workers: int, pool,
             progress) -> dict[int, SizeRecord]:
    """:func:`compute` on ``pool`` (``None``: in this process)."""
    from experiments.processes.workers import map_in_order

    tasks = [(config, settings, i) for i in range(settings.records)]
    records = map_in_order(run_record, tasks, workers, pool=pool,
                           done=lambda done, i, r: progress(
        f"record {done}/{len(tasks)} (seed {r.seed}): " + "; ".join(
            f"n_l={h}: " + ", ".join(f"{f.row.data_cost:.5f} N² ({f.row.stop})" for f in fits)
            for h, fits in r.fits.items())))
    first = records[0]
    out = {}
    for hidden in settings.hidden:
        data = first.data[hidden]
        sc = ident.scales(data.phi, data.target)
        delta = ident.record_threshold([r.best(hidden).row.data_cost for r in records])
        best = first.best(hidden)
        atol = settings.resolution * delta
        directions = []
        for name in THETA_NAMES:
            bounds = ident.search_bounds(best.row.theta[name], first.lip[name], sc[name],
                                         settings.span)
            start = ident.point_of(best.row.theta[name], best.fit, atol=atol, beta=best.beta,
                                   tail=best.row.tail_decrease)
            for direction, bound in ((-1, bounds[0]), (1, bounds[1])):
                directions.append((config, settings, DirectionTask(
                    hidden, data, first.lip, start, name, direction, bound,
                    best.row.data_cost + delta, atol)))
        progress(f"n_l={hidden}: δ = {delta:.3g} N² over {len(records)} records; profiling "
                 f"from the best fit ({best.row.data_cost:.5f} N², {best.row.stop}) in "
                 f"{len(directions)} directions")
        walks = map_in_order(run_direction, directions, workers, pool=pool,
                             done=lambda done, i, w: progress(
            f"  n_l={hidden} {w[0]} {'+' if w[1] > 0 else '-'}: {w[2].end} after "
            f"{len(w[2].points)} points, {sum(p.settled for p in w[2].points)} converged or "
            "resolved"))
        # The resolution test trusts a local model: continue the resolved points it trusts
        # least (largest predicted decrease) and see how far their cost still falls.
        resolved = sorted(((name, p) for name, _, w in walks for p in w.points
                           if p.resolution_test and not p.relative_test
                           and p.confirmed_from is None),
                          key=lambda item: -item[1].predicted_decrease)[:settings.check]
        checks = map_in_order(run_check, [(config, settings, hidden, data, first.lip, n, p)
                                          for n, p in resolved], workers, pool=pool,
                              done=lambda done, i, c: progress(
                                  f"  n_l={hidden} check {done}/{len(resolved)}: {c.name} "
                                  f"fell {c.moved:.2g} N² in {c.iterations} more iterations"))
        out[hidden] = summarize(settings, records, hidden, walks, delta, sc, tuple(checks))
    return out


# ----------------------------------------------------------------------------- summary

def summarize(settings: ProfileSettings, records: list[RecordRun], hidden: int,
              walks: list[tuple[str, int, Walk]], delta: float, sc: dict,
              checks: tuple[Check, ...] = ()) -> SizeRecord:
    """The identifiability record of one network size (see the module docstring)."""
    first = records[0]
    best = first.best(hidden)
    atol = settings.resolution * delta
    v_best = min([p.data_cost for _, _, w in walks for p in w.points]
                 + [f.row.data_cost for f in first.fits[hidden]])
    by_side = {(name, d): w for name, d, w in walks}
    params = {}
    for name in THETA_NAMES:
        start = ident.point_of(best.row.theta[name], best.fit, atol=atol,
                               tail=best.row.tail_decrease)
        bounds = ident.search_bounds(best.row.theta[name], first.lip[name], sc[name],
                                     settings.span)
        params[name] = ident.parameter_profile(start, by_side[name, -1], by_side[name, 1],
                                               v_best, delta, bounds)
    lips = np.array([[r.lip[n] for n in THETA_NAMES] for r in records])
    return SizeRecord(
        best_data_cost=v_best, delta=delta,
        best_cost_per_record=tuple(r.best(hidden).row.data_cost for r in records),
        seeds=tuple(r.seed for r in records), start=best.row, scale=dict(sc),
        settings=WalkSettings(settings.max_iter, settings.points, settings.step,
                              settings.span, settings.refine, settings.polish,
                              settings.resolution, atol, best.fit.ftol, settings.check_iter),
        fits=tuple(MarkedFit(0.0, f.row.data_cost, f.row.theta) for f in first.fits[hidden]),
        record_fits=tuple(f.row for r in records for f in r.fits[hidden]),
        lip_intervals=first.lip_intervals,
        lip_cost_per_record=tuple(r.lip_cost for r in records),
        lip_mean=dict(zip(THETA_NAMES, map(float, lips.mean(axis=0)))),
        lip_std=dict(zip(THETA_NAMES, map(float, lips.std(axis=0, ddof=1)))),
        parameters=params, checks=checks)


def _timed(config: ExperimentConfig, settings: ProfileSettings, *, workers: int,
           progress) -> tuple[ProfilesResult, None]:
    start = time.perf_counter()
    sizes = compute(config, settings, workers=workers, progress=progress)
    return ProfilesResult(sizes, time.perf_counter() - start), None


def _figures(result: ProfilesResult, folder: Path, scene=None) -> None:
    from experiments import plots
    from experiments.studies.profiles.figures import identifiability_figure

    plots.save(identifiability_figure(result.sizes), folder / "identifiability.png")


STUDY = Study(
    kind="identifiability", section="identifiability", what="a clm-sim identifiability study",
    settings=ProfileSettings, load=preflighted(load_profiles), compute=_timed,
    result=ProfilesResult, result_file="identifiability.json",
    report=lambda result, settings: to_markdown(result.sizes), figures=_figures,
    resolved=lambda config, settings: {**resolved(config),
                                       "identifiability": to_plain(settings)},
    workers=cores, json_options=(("allow_nan", False),))
