"""What the data determine about theta_phy at lambda = 0: converged profiles, their threshold
from the training records, the LIP's own intervals and the fits' sloppy directions.

Per network size (``identifiability.hidden``) and on the config's plant:

1. ``records`` training records (dither seeds ``seed, seed + 1, ...``), each with its LIP and
   ``draws`` PGNN fits on the profiled cost (``pgnn:``; default the paper's: mean squared error,
   no network weight decay, no continuation start); the best data cost of each record gives the
   threshold ``delta`` (its standard deviation over the records), and the Gauss-Newton matrix of
   each fit its sloppy directions (:func:`experiments.identifiability.sloppy_directions`);
2. on the first record, from its best fit, the warm-started continuation of the data cost's
   profile over each physical parameter, in both directions
   (:func:`experiments.identifiability.walk`: ``points`` points per direction at most, each of
   ``max_iter`` Levenberg-Marquardt iterations at most, steps ``step * scale_k`` doubling, out to
   ``span * scale_k`` beyond the hull of theta* and theta_LIP);
3. the LIP's Newey-West intervals on that record and its spread over the records, beside the
   profile ranges.

``clm-sim study CONFIG`` dispatches here for ``kind: identifiability``; ``identifiability.json``,
``report.md``, ``config.resolved.yaml`` and ``figures/identifiability.png`` are written into the
output folder. The fits run in ``--workers`` processes; the result does not depend on how many.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml

from clm_sim.errors import UserError
from clm_sim.outdir import atomic_folder
from clm_sim.plant import THETA_NAMES
from clm_sim.schema import build, load_yaml, to_plain
from controllers.pgnn_settings import PGNNSettings
from experiments import identifiability as ident
from experiments.config import ExperimentConfig, resolved
from experiments.studies.kinds import run_checked, take_kind
from experiments.testbed import STREAM_NETWORK, Progress, Testbed, stream


@dataclass(frozen=True)
class ProfileSettings:
    """The ``identifiability:`` section of a config.

    hidden: network sizes n_l profiled; records: training records (dither seeds), >= 2 (the
    threshold is their spread; 5 or more for a usable one); draws: network draws per record;
    pgnn: the fit settings profiled (lambda is 0; default: the paper's cost); polish: further
    Levenberg-Marquardt iterations for a record's fit that did not converge (0: none); max_iter:
    Levenberg-Marquardt iterations per profile point at most; resolution: a profile point is
    resolved (and stops) when the Gauss-Newton model predicts an absolute decrease of its data
    cost of at most this fraction of delta (besides the optimizer's relative test, ``pgnn.ftol``);
    check: how many resolved points are continued for ``check_iter`` more iterations to test
    that resolution (those with the largest predicted decrease; 0: none); points: profile points
    per direction at most (the budget); step: first step in units of scale_k (the change of theta_k that alone
    moves the force by its rms); span: how far beyond the hull of theta* and theta_LIP the
    search goes, in units of scale_k; refine: bisections of the step where a profile rises
    (locating the range's end); sloppy: smallest Gauss-Newton directions reported per fit.
    """

    hidden: tuple[int, ...] = (16, 8)
    records: int = 5
    draws: int = 1
    pgnn: PGNNSettings = field(default_factory=lambda: PGNNSettings(
        weight_decay=0.0, continuation_lam=0.0))
    polish: int = 400
    max_iter: int = 100
    resolution: float = 0.05
    check: int = 4
    check_iter: int = 500
    points: int = 8
    step: float = 0.25
    span: float = 4.0
    refine: int = 2
    sloppy: int = 3

    def __post_init__(self):
        for key, low in (("records", 2), ("draws", 1), ("polish", 0), ("max_iter", 1),
                         ("check", 0), ("check_iter", 1), ("points", 1), ("refine", 0),
                         ("sloppy", 1)):
            value = getattr(self, key)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
                raise UserError(f"{key}: expected an integer >= {low}, got {value!r}")
        if not self.hidden or not all(isinstance(h, int) and h >= 1 for h in self.hidden):
            raise UserError(f"hidden: expected a list of integers >= 1, got {self.hidden!r}")
        for key in ("step", "span", "resolution"):
            if not getattr(self, key) > 0:
                raise UserError(f"{key}: expected a number > 0, got {getattr(self, key)!r}")


def load_profiles(path) -> tuple[ExperimentConfig, ProfileSettings]:
    """Read a profile study config (an experiment config plus ``identifiability:``); errors
    name the file and the key."""
    path = Path(path)
    data = take_kind(load_yaml(path), path, "identifiability")
    raw = data.pop("identifiability", None)
    try:
        config = build(ExperimentConfig, data, "config")
        settings = build(ProfileSettings, raw, "identifiability")
    except UserError as exc:
        raise UserError(f"{path}: {str(exc).removeprefix('config.').removeprefix('config: ')}") \
            from None
    return config, settings


def _fit_settings(settings: ProfileSettings, hidden: int, max_iter: int | None = None) -> dict:
    out = {**asdict(settings.pgnn), "hidden": hidden, "lam": 0.0,
           "training": "simultaneous"}
    if max_iter is not None:
        out["max_iter"] = max_iter
    return out


# ----------------------------------------------------------------------------- phase 1: records

def run_record(task: tuple) -> dict:
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
    out = {"record": index, "seed": seed, "lip": dict(lip.theta_), "sizes": {}}
    for hidden in settings.hidden:
        fs = _fit_settings(settings, hidden)
        data = training_data(config.features, y=run.y, u=run.u, ts=run.ts,
                             decimation=fs.get("decimation"))
        if "lip_intervals" not in out:
            out["lip_intervals"] = ident.lip_intervals(data.phi, data.target)
            theta_lip = np.array([lip.theta_[k] for k in THETA_NAMES])
            out["lip_cost"] = float(np.mean((data.target - data.phi @ theta_lip) ** 2))
        fits = []
        for draw in range(settings.draws):
            model = PGNNFeedforward(**fs, features=config.features).fit_data(
                data=data, theta_lip=lip.theta_,
                rng=np.random.default_rng(stream(seed, STREAM_NETWORK, draw)))
            first = {k: getattr(model.fit_, k) for k in ("data_cost", "stop", "iterations")}
            if settings.polish and model.fit_.stop != "converged":
                # Continue the same descent (nothing pinned) before the fit is a profile's start
                # or a record's best cost: a fit stopped at max_iter is still falling.
                model = PGNNFeedforward(**{**fs, "max_iter": settings.polish},
                                        features=config.features).fit_pinned(
                    data=data, theta_lip=lip.theta_, beta0=model.network_.get_nonlinear(),
                    pinned={})
            fits.append({"draw": draw, "lambda": 0.0, "data_cost": model.fit_.data_cost,
                         "stop": model.fit_.stop, "iterations": model.fit_.iterations,
                         "first": first, "tail_decrease": ident.tail_decrease(model.history_),
                         "theta": dict(model.theta_), "fit": model.fit_,
                         "sloppy": ident.sloppy_directions(model, data.phi, data.target,
                                                           settings.sloppy),
                         "beta": model.network_.get_nonlinear()})
        out["sizes"][str(hidden)] = fits
        if index == 0:
            out.setdefault("data", {})[str(hidden)] = data
    return out


# ----------------------------------------------------------------------------- phase 2: profiles

def run_direction(task: tuple) -> dict:
    """One direction of one parameter's profile: (config, settings, hidden, data, theta_lip,
    start Point, name, direction, bound, level, atol) -> the walk's points and end; each point
    stops at the optimizer's relative test, at the resolution test (predicted decrease <=
    ``atol``, N**2) or at ``settings.max_iter``."""
    import torch

    from controllers.pgnn import PGNNFeedforward

    torch.set_num_threads(1)
    config, settings, hidden, data, theta_lip, start, name, direction, bound, level, atol = task
    fs = _fit_settings(settings, hidden, settings.max_iter)
    sc = ident.scales(data.phi, data.target)[name]

    def fit_at(value: float, beta0: np.ndarray) -> ident.Point:
        model = PGNNFeedforward(**fs, features=config.features).fit_pinned(
            data=data, theta_lip=theta_lip, beta0=beta0, pinned={name: value}, atol=atol)
        return ident.point_of(value, model.fit_, atol=atol, beta=model.network_.get_nonlinear(),
                              tail=ident.tail_decrease(model.history_))

    got = ident.walk(fit_at, start, direction, first_step=settings.step * sc, bound=bound,
                     level=level, points=settings.points, refine=settings.refine)
    return {"name": name, "direction": direction, "end": got["end"], "points": got["points"]}


def run_check(task: tuple) -> dict:
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
    return {"name": name, "value": point.value, "data_cost": point.data_cost,
            "predicted_decrease": point.predicted_decrease,
            "continued_cost": model.fit_.data_cost, "stop": model.fit_.stop,
            "iterations": model.fit_.iterations}


def compute(config: ExperimentConfig, settings: ProfileSettings, *, workers: int = 1,
            progress=None) -> dict:
    """Every record, then every profile direction (in ``workers`` processes when > 1); the
    result does not depend on ``workers``."""
    from experiments.workers import map_in_order

    progress = progress or (lambda message: None)
    tasks = [(config, settings, i) for i in range(settings.records)]
    records = map_in_order(run_record, tasks, workers, lambda done, i, r: progress(
        f"record {done}/{len(tasks)} (seed {r['seed']}): " + "; ".join(
            f"n_l={h}: " + ", ".join(f"{f['data_cost']:.5f} N² ({f['stop']})" for f in fits)
            for h, fits in r["sizes"].items())))
    first = records[0]
    out = {}
    for hidden in settings.hidden:
        key = str(hidden)
        data = first["data"][key]
        sc = ident.scales(data.phi, data.target)
        best_per_record = [min(f["data_cost"] for f in r["sizes"][key]) for r in records]
        delta = ident.record_threshold(best_per_record)
        best = min(first["sizes"][key], key=lambda f: f["data_cost"])
        start_cost = best["data_cost"]
        atol = settings.resolution * delta
        directions = []
        for name in THETA_NAMES:
            bounds = ident.search_bounds(best["theta"][name], first["lip"][name], sc[name],
                                         settings.span)
            start = ident.point_of(best["theta"][name], best["fit"], atol=atol,
                                   beta=best["beta"])
            for direction, bound in ((-1, bounds[0]), (1, bounds[1])):
                directions.append((config, settings, hidden, data, first["lip"], start, name,
                                   direction, bound, start_cost + delta, atol))
        progress(f"n_l={key}: δ = {delta:.3g} N² over {len(records)} records; profiling from "
                 f"the best fit ({start_cost:.5f} N², {best['stop']}) in "
                 f"{len(directions)} directions")
        walks = map_in_order(run_direction, directions, workers, lambda done, i, w: progress(
            f"  n_l={key} {w['name']} {'+' if w['direction'] > 0 else '-'}: {w['end']} after "
            f"{len(w['points'])} points, "
            f"{sum(p.settled for p in w['points'])} resolved or converged"))
        # The resolution test trusts a local model: continue the resolved points it trusts
        # least (largest predicted decrease) and see how far their cost still falls.
        resolved = sorted(((w["name"], p) for w in walks for p in w["points"]
                           if p.resolution_test and not p.relative_test),
                          key=lambda np_: -np_[1].predicted_decrease)[:settings.check]
        checks = map_in_order(run_check, [(config, settings, hidden, data, first["lip"], n, p)
                                          for n, p in resolved], workers,
                              lambda done, i, c: progress(
                                  f"  n_l={key} check {done}/{len(resolved)}: {c['name']} "
                                  f"fell {c['data_cost'] - c['continued_cost']:.2g} N² in "
                                  f"{c['iterations']} more iterations"))
        out[key] = summarize(settings, records, key, walks, delta, best, sc, checks)
    return out


# ----------------------------------------------------------------------------- summary

def summarize(settings: ProfileSettings, records: list[dict], key: str, walks: list[dict],
              delta: float, best: dict, sc: dict, checks: list[dict] = ()) -> dict:
    """The identifiability record of one network size (see the module docstring)."""
    first = records[0]
    fits0 = first["sizes"][key]
    v_best = min([p.data_cost for w in walks for p in w["points"]]
                 + [f["data_cost"] for f in fits0])
    params = {}
    for name in THETA_NAMES:
        down, up = (next(w for w in walks if w["name"] == name and w["direction"] == d)
                    for d in (-1, 1))
        start = ident.point_of(best["theta"][name], best["fit"],
                               atol=settings.resolution * delta, tail=best["tail_decrease"])
        bounds = ident.search_bounds(best["theta"][name], first["lip"][name], sc[name],
                                     settings.span)
        params[name] = ident.parameter_profile(start, down, up, v_best, delta, bounds)
    lips = np.array([[r["lip"][n] for n in THETA_NAMES] for r in records])
    return {
        "best_data_cost": v_best, "delta": delta, "delta_from": "spread over records",
        "best_cost_per_record": [min(f["data_cost"] for f in r["sizes"][key]) for r in records],
        "seeds": [r["seed"] for r in records],
        "start": {k: best[k] for k in ("draw", "data_cost", "stop", "iterations", "first",
                                        "tail_decrease", "theta")},
        "scale": sc, "max_iter": settings.max_iter, "points": settings.points,
        "step": settings.step, "span": settings.span, "refine": settings.refine,
        "polish": settings.polish, "resolution": settings.resolution,
        "atol": settings.resolution * delta, "ftol": best["fit"].ftol,
        "checks": [{**c, "moved": c["data_cost"] - c["continued_cost"]} for c in checks],
        "check_iter": settings.check_iter,
        "fits": [{k: f[k] for k in ("lambda", "data_cost", "theta")} for f in fits0],
        "record_fits": [{"seed": r["seed"], **{k: f[k] for k in (
            "draw", "data_cost", "stop", "iterations", "first", "tail_decrease", "theta",
            "sloppy")}}
            for r in records for f in r["sizes"][key]],
        "lip_intervals": first["lip_intervals"],
        "lip_cost_per_record": [r["lip_cost"] for r in records],
        "lip_over_records": {"mean": dict(zip(THETA_NAMES, map(float, lips.mean(axis=0)))),
                             "std": dict(zip(THETA_NAMES, map(float, lips.std(axis=0,
                                                                               ddof=1))))},
        "parameters": params}


def _g(x: float) -> str:
    return f"{x:.4g}"


def to_markdown(ident_out: dict) -> str:
    """The report: per network size the threshold, the profile ranges beside the LIP's
    intervals, the points' stop reasons and the sloppy directions of every record's fit."""
    from experiments.table import THETA_UNITS

    lines = ["# What the data determine at λ = 0: converged profiles", ""]
    for key, rec in ident_out.items():
        li, lr = rec["lip_intervals"], rec["lip_over_records"]
        st = rec["start"]
        lines += [f"## n_l = {key}", "",
                  f"Best data cost {rec['best_data_cost']:.5f} N²; δ = {rec['delta']:.3g} N² "
                  f"(standard deviation of the best data cost over {len(rec['seeds'])} "
                  f"training records, seeds {', '.join(map(str, rec['seeds']))}: "
                  + ", ".join(f"{c:.5f}" for c in rec["best_cost_per_record"]) + " N²; the "
                  "LIP's data cost, a convex fit, spreads by "
                  f"{np.std(rec['lip_cost_per_record'], ddof=1):.3g} N² over the same records: "
                  + ", ".join(f"{c:.5f}" for c in rec["lip_cost_per_record"]) + " N²). "
                  f"Each record's fit: {st['first']['iterations']} iterations at most from its "
                  f"draw, then up to {rec['polish']} more where it had not converged. Profiles "
                  f"from the best fit on seed {rec['seeds'][0]} ({st['first']['data_cost']:.5f} "
                  f"N² after {st['first']['iterations']} iterations, {st['first']['stop']}; "
                  f"{st['data_cost']:.5f} N² after {st['iterations']} more, {st['stop']}); each "
                  f"point ≤ {rec['max_iter']} iterations warm-started from its neighbour, ≤ "
                  f"{rec['points']} points per direction, {rec['refine']} bisections where a "
                  "profile rises.", "",
                  "| parameter | θ* (best fit) | range within δ | ends (down / up) | points "
                  "converged / resolved / neither | monotone (down / up) | LIP ± 95 % "
                  "Newey-West | LIP sd over records |", "|---|---|---|---|---|---|---|---|"]
        for name, e in rec["parameters"].items():
            unit = THETA_UNITS[name]
            if e["range"] is None:
                rng = "none within δ"
            else:
                lo, hi = e["range"]
                rng = ((f"(flat to the {e['why_open'][0]}) " if e["open"][0] else "")
                       + f"[{_g(lo)}, {_g(hi)}]"
                       + (f" (flat to the {e['why_open'][1]})" if e["open"][1] else ""))
            n_rel = sum(p["relative_test"] for p in e["profile"])
            n_res = sum(p["resolution_test"] and not p["relative_test"] for p in e["profile"])
            lines.append(
                f"| {name} [{unit}] | {_g(e['start'])} | {rng} | {e['ends']['down']} / "
                f"{e['ends']['up']} | {n_rel} / {n_res} / {len(e['profile']) - n_rel - n_res} | "
                f"{'yes' if e['monotone']['down'] else 'no'} / "
                f"{'yes' if e['monotone']['up'] else 'no'} | {_g(li['theta'][name])} ± "
                f"{_g(1.96 * li['std_newey_west'][name])} | {_g(lr['std'][name])} |")
        pts = [p for e in rec["parameters"].values() for p in e["profile"]]
        stops = [p["stop"] for p in pts]
        rel = [p for p in pts if p["relative_test"]]
        res = [p for p in pts if p["resolution_test"] and not p["relative_test"]]
        rest = [p for p in pts if not (p["resolution_test"] or p["relative_test"])]
        pred = [p["predicted_decrease"] for p in pts if p["predicted_decrease"] is not None]
        tail = max(p["tail_decrease"] for p in rest) if rest else None
        lines += ["", f"Profile points (the start counted once per parameter): {len(pts)}; "
                  f"{len(rel)} pass the optimizer's relative test (Gauss-Newton predicted "
                  f"relative decrease ≤ ftol = {rec['ftol']:g}), {len(res)} more pass the "
                  f"resolution test only (predicted absolute decrease ≤ {rec['resolution']:g} δ "
                  f"= {rec['atol']:.2g} N²), {len(rest)} pass neither (upper bounds on the "
                  "profile there). Stops: " + ", ".join(
                      f"{stops.count(x)} {x}" for x in sorted(set(stops))) + ". Predicted "
                  f"decrease over the points: {min(pred) / rec['delta']:.2g} δ to "
                  f"{max(pred) / rec['delta']:.2g} δ (median "
                  f"{float(np.median(pred)) / rec['delta']:.2g} δ)"
                  + (f"; the largest fall of an unsettled point's data cost over its last "
                     f"{ident.TAIL} iterations {tail:.2g} N² ({tail / rec['delta']:.2g} δ)"
                     if tail is not None else "") + ". Ends: rises = the profile rose above "
                  "δ; bound = flat to the search bound (" + f"{rec['span']:g} scales beyond θ* "
                  "and θ_LIP).", ""]
        if rec["checks"]:
            moved = [c["moved"] for c in rec["checks"]]
            lines += [f"The resolution test, checked: the {len(moved)} resolved points with the "
                      f"largest predicted decrease, each continued for up to "
                      f"{rec['check_iter']} more iterations, fell by "
                      + ", ".join(f"{m / rec['delta']:.2g} δ" for m in moved)
                      + " (predicted: " + ", ".join(
                          f"{c['predicted_decrease'] / rec['delta']:.2g} δ"
                          for c in rec["checks"]) + f"); the stated resolution is "
                      f"{rec['resolution']:g} δ: "
                      + ("held" if max(moved) <= rec["atol"] else "NOT held") + ".", ""]
        lines += [
                  f"LIP residual lag-1 autocorrelation {li['lag1_autocorr']:.2f} "
                  f"({li['lags']} Newey-West lags, {li['n_samples']} samples).", "",
                  "Sloppy directions of each record's fit (Gauss-Newton matrix J'J of the "
                  "data cost over every parameter, each scaled so that one unit moves the force "
                  "by 1 N rms; an eigenvalue is the cost rise in N² of a unit step): the "
                  "smallest eigenvalue, its ratio to the largest and its share on the network; "
                  "then the θ direction least determined once the network has absorbed what it "
                  "can (smallest eigenvalue of the Schur complement of the network block) and "
                  "that eigenvalue:", "",
                  "| seed | data cost [N²] | stop | λ_min [N²] | λ_min/λ_max | network share "
                  "| least determined θ direction (m, fv, fc, fk) | its eigenvalue [N²] |",
                  "|---|---|---|---|---|---|---|---|"]
        for f in rec["record_fits"]:
            s = f["sloppy"]["smallest"][0]
            th = f["sloppy"]["theta"][0]
            lines.append(f"| {f['seed']} | {f['data_cost']:.5f} | {f['stop']} | "
                         f"{s['eigenvalue']:.2g} | {s['relative']:.2g} | "
                         f"{s['network_share']:.3f} | "
                         + ", ".join(f"{th['direction'][n]:+.2f}" for n in THETA_NAMES)
                         + f" | {th['eigenvalue']:.2g} |")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- running

def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def run_profiles(config: ExperimentConfig, settings: ProfileSettings, out, *,
                 workers: int | None = None, quiet: bool = False) -> dict:
    """Run the study and write it into ``out`` (replaced atomically). Returns the record per
    network size."""
    from experiments import plots
    from experiments.profiles_result import sizes_from_json

    progress = Progress(quiet)
    out = Path(out)
    workers = workers or os.cpu_count() or 1
    with atomic_folder(out, marker="identifiability.json",
                       what="a clm-sim identifiability study") as tmp:
        (tmp / "config.resolved.yaml").write_text(yaml.safe_dump(
            {**resolved(config), "identifiability": to_plain(settings)}, sort_keys=False))
        start = time.perf_counter()
        result = _plain(compute(config, settings, workers=workers, progress=progress))
        (tmp / "identifiability.json").write_text(json.dumps(
            {"wall_time_s": time.perf_counter() - start, "sizes": result}, indent=1,
            allow_nan=False))
        (tmp / "report.md").write_text(to_markdown(result))
        plots.save(plots.identifiability_figure(sizes_from_json(result)),
                   tmp / "figures" / "identifiability.png")
    progress(f"report in {out}/report.md")
    return result


def main(config_path, out=None, *, workers: int | None = None, quiet: bool = False) -> int:
    """``clm-sim study CONFIG`` for ``kind: identifiability``."""
    run_checked(config_path, out, load_profiles, run_profiles, workers=workers,
                quiet=quiet)
    return 0