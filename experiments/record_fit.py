"""PGNN identification from measured records: the ``data:`` section of an experiment config.

    training record -> filtered features and force (the config's feature map, at the record's
    own sample rate) -> samples inside the training window -> LIP (least squares) and PGNN per
    seed -> force prediction error inside the window and beyond it, on every record

The fitting data are :func:`controllers.pgnn.training_data` at decimation 1, restricted to the
window (position and/or velocity of the filtered signals), then decimated with the PGNN's own
decimation (one sample per 8 ms by default, whatever the record's rate). The LIP of a record is
the least-squares ``theta`` on the same windowed, filtered samples, so both models see the same
data. ``force_rms`` (N) is the rms of filtered force minus prediction over the samples inside
the window and over those outside it, on the training record and on the validation record.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES
from experiments import table
from experiments.config import ExperimentConfig


@dataclasses.dataclass(frozen=True)
class Prepared:
    """One record's filtered columns ``phi`` (N, 4: a, v, sign v, y), force ``target`` (N,)
    and the training-window mask ``inside``."""

    name: str
    phi: np.ndarray
    target: np.ndarray
    inside: np.ndarray
    ts: float


def prepare(config: ExperimentConfig, run, name: str) -> Prepared:
    from controllers.pgnn import training_data

    data = training_data(config.features, y=run.y, u=run.u, ts=run.ts, decimation=1)
    inside = config.data.window.inside(data.phi[:, 3], data.phi[:, 1])
    return Prepared(name, data.phi, data.target, inside, run.ts)


def _rms(x) -> float | None:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None


def force_rms(pred: np.ndarray, rec: Prepared) -> dict:
    """``{"inside", "outside"}``: rms force prediction error (N) inside and outside the window
    (None where the record has no such sample)."""
    err = rec.target - pred
    return {"inside": _rms(err[rec.inside]), "outside": _rms(err[~rec.inside])}


def fit_lip(train: Prepared) -> dict[str, float]:
    """Least-squares theta on the windowed, filtered training samples."""
    return fit_lip_std(train)[0]


def fit_lip_std(train: Prepared) -> tuple[dict[str, float], dict[str, float]]:
    """:func:`fit_lip` and the standard errors of its parameters (same units); ``UserError``
    where the window does not excite every parameter (a column zero or collinear)."""
    phi, target = train.phi[train.inside], train.target[train.inside]
    scale = np.linalg.norm(phi, axis=0)
    if np.any(scale == 0) or np.linalg.matrix_rank(phi / scale) < phi.shape[1]:
        raise UserError(f"{train.name} record: the training window does not excite all "
                        f"parameters (a regressor is zero or collinear inside it); it needs "
                        f"motion in both directions (widen data.window)")
    theta = np.linalg.lstsq(phi, target, rcond=None)[0]
    resid = target - phi @ theta
    cov = np.linalg.pinv(phi.T @ phi) * (resid @ resid / max(len(target) - len(theta), 1))
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    return dict(zip(THETA_NAMES, map(float, theta))), dict(zip(THETA_NAMES, map(float, std)))


def record_checks(config: ExperimentConfig, run, train: Prepared, source: str) -> tuple[
        dict[str, float], list[str]]:
    """The guards of :mod:`experiments.record_guards` on the training record: refuse (one
    line) a record or window that identifies nothing or a fit with non-finite numbers; the
    LIP of the window and the warnings where it is suspect."""
    from types import SimpleNamespace

    from experiments.record_guards import fit_warnings, refuse_small_window
    from experiments.suspicions import record_warnings

    refuse_small_window(int(train.inside.sum()), len(train.inside), source)
    theta, std = fit_lip_std(train)
    if not all(np.isfinite(list(theta.values())) + np.isfinite(list(std.values()))):
        raise UserError(f"{source}: the fit gives non-finite parameters; the record's values "
                        f"are too large or degenerate for a least-squares fit")

    def refit(y, cutoff):
        try:
            band = dataclasses.replace(config, features=dataclasses.replace(
                config.features, regression_lowpass_hz=cutoff))
            other = prepare(band, dataclasses.replace(run, y=y), train.name)
            return fit_lip_std(other)[0]["mass"] if other.inside.sum() else float("nan")
        except UserError:
            return float("nan")

    lip = SimpleNamespace(theta_=theta, std_=std)
    return theta, record_warnings(run, lip) + fit_warnings(
        run, config.features, theta, std, option="features.regression_lowpass_hz", refit=refit)


def _stat(values) -> dict | None:
    values = [v for v in values if v is not None]
    if not values:
        return None
    return {"mean": float(np.mean(values)),
            "std": float(np.std(values, ddof=1)) if len(values) > 1 else 0.0,
            "median": float(np.median(values))}


def evaluate(config: ExperimentConfig, records: list[Prepared], progress,
             theta_lip: dict[str, float] | None = None) -> list[dict]:
    """Every row of ``config`` identified on ``records[0]`` and scored on all ``records``
    (``theta_lip``: the LIP of the window, if already fitted)."""
    from controllers.pgnn import TrainingData
    from controllers.pgnn_settings import decimation_for
    from experiments import workers
    from experiments.testbed import STREAM_NETWORK, stream

    train = records[0]
    theta_lip = theta_lip or fit_lip(train)
    progress(f"LIP on the window ({int(train.inside.sum())} of {len(train.inside)} samples): "
             + ", ".join(f"{k} {v:.4g}" for k, v in theta_lip.items()))
    rows = []
    for spec in config.feedforwards:
        if spec.kind == "lip":
            preds = [[r.phi @ np.array([theta_lip[k] for k in THETA_NAMES]) for r in records]]
            thetas, fits, models = [theta_lip], None, [None]
        else:
            settings = spec.pgnn_settings()
            step = decimation_for(train.ts, settings["decimation"])
            data = TrainingData(np.ascontiguousarray(train.phi[train.inside][::step]),
                                train.target[train.inside][::step].copy())
            progress(f"  training {spec.label()}: {spec.seeds} seeds on {len(data.target)} "
                     f"samples (decimation {step})")
            models = workers.map_fits([(settings, config.features, data, theta_lip,
                                        stream(config.seed, STREAM_NETWORK, s))
                                       for s in range(spec.seeds)])
            preds = [[r.phi @ np.array([m.theta_[k] for k in THETA_NAMES]) + m.network(r.phi)
                      for r in records] for m in models]
            thetas = [dict(m.theta_) for m in models]
            fits = [{"seed": s, **{k: m.fit_[k] for k in (
                "stop", "cost_stop", "iterations", "data_cost", "reg_cost", "first_order",
                "theta_moved", "theta_path", "continuation_lambda", "start")}}
                for s, m in enumerate(models)]
        per_seed = [{r.name: force_rms(p, r) for p, r in zip(pred, records)} for pred in preds]
        row = {"kind": spec.kind, "training": spec.training, "lambda": spec.lam,
               "hidden": spec.hidden, "n_seeds": len(per_seed), "label": spec.label(),
               "force_rms": {r.name: {side: _stat([s[r.name][side] for s in per_seed])
                                      for side in ("inside", "outside")} for r in records},
               "force_rms_per_seed": per_seed,
               "theta_phy": {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES},
               "theta_phy_per_seed": thetas}
        if fits is not None:
            row["fits"] = fits
            row["converged"] = sum(f["stop"] == "converged" for f in fits)
            row["regularizers"] = table.regularizers(spec, fits)
        rows.append((row, models))
        progress(f"{spec.label()}: " + "; ".join(
            f"{r.name} inside {_fmt(row['force_rms'][r.name]['inside'])} N, outside "
            f"{_fmt(row['force_rms'][r.name]['outside'])} N" for r in records))
    return rows


def _fmt(stat) -> str:
    if stat is None:
        return "–"
    if not stat["std"]:
        return f"{stat['mean']:.3f}"
    return f"{stat['mean']:.3f} ± {stat['std']:.3f} (median {stat['median']:.3f})"


def comparisons(rows: list[dict]) -> list[dict]:
    """Paired differences of ``force_rms`` over seeds: every other PGNN row against the
    lambda = 0 row of the same n_l, seeds and network weight decay (``a - b``, 95 %
    t-interval), per record and side."""
    out = []
    lam0 = [r for r in rows if r["kind"] == "pgnn" and r["training"] == "simultaneous"
            and not r["lambda"]]
    for b in lam0:
        for a in rows:
            if a is b or a["kind"] != "pgnn" or a["hidden"] != b["hidden"] \
                    or a["n_seeds"] != b["n_seeds"] or a in lam0 \
                    or a["regularizers"]["weight_decay"] != b["regularizers"]["weight_decay"]:
                continue
            for rec in a["force_rms"]:
                for side in ("inside", "outside"):
                    da = [s[rec][side] for s in a["force_rms_per_seed"]]
                    db = [s[rec][side] for s in b["force_rms_per_seed"]]
                    if None in da or None in db:
                        continue
                    mean, lo, hi = table.t_interval(np.subtract(da, db))
                    ci = [lo, hi] if len(da) > 1 else None
                    out.append({"a": a["label"], "b": b["label"], "metric": "force_rms",
                                "record": rec, "side": side, "n": len(da), "diff": mean,
                                "ci95": ci, "excludes_zero": bool(ci and (lo > 0 or hi < 0))})
    return out


def to_markdown(rows: list[dict], pairs: list[dict]) -> str:
    """The force prediction table (N, mean ± std over seeds), the fits and the paired
    differences."""
    recs = list(rows[0]["force_rms"])
    head = (["feedforward", "seeds"]
            + [f"force rms {r} {side} [N]" for r in recs for side in ("inside", "outside")]
            + [f"{table._SHORT[k]} [{table.THETA_UNITS[k]}]" for k in THETA_NAMES]
            + ["fits converged"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["label"], str(row["n_seeds"])]
        cells += [_fmt(row["force_rms"][r][side]) for r in recs for side in ("inside",
                                                                           "outside")]
        cells += [f"{row['theta_phy'][k]:.4g}" for k in THETA_NAMES]
        cells.append(f"{row['converged']}/{len(row['fits'])}" if "fits" in row else "–")
        lines.append("| " + " | ".join(cells) + " |")
    stops = [(r["label"], f) for r in rows for f in r.get("fits", []) if f["stop"] != "converged"]
    lines += ["", "Not converged: " + ("; ".join(
        f"{label} seed {f['seed']} ({f['stop']} after {f['iterations']} iterations)"
        for label, f in stops) if stops else "none") + "."]
    lines += table.theta_paths([r for r in rows if "fits" in r])
    lines += ["", "**Paired differences** (a − b over the same seeds; mean and 95 % "
              "t-interval; * where it excludes 0):", ""]
    for c in pairs:
        ci = f"[{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}] N" if c["ci95"] else "(no interval)"
        lines.append(f"- force rms, {c['record']} {c['side']}: {c['a']} − {c['b']} = "
                     f"{c['diff']:+.3f} N {ci} (n = {c['n']})" + (" *" if c["excludes_zero"]
                                                                   else ""))
    return "\n".join(lines) + "\n"


def compute(config: ExperimentConfig, progress, warn=None) -> dict:
    """Identify every row of ``config`` from its ``data:`` records: ``{"rows", "comparisons",
    "models": [per row, per seed], "warnings", "samples"}``. The record guards refuse in one
    line a record or window that identifies nothing; ``warn(source, lines)`` receives the
    warnings where the result is suspect (default: stderr, one line each)."""
    from experiments.suspicions import warn as stderr_warn

    warn = warn or stderr_warn
    from experiments.record_guards import refuse_unidentifiable

    recs = [("training", config.data.load("training"))]
    source = f"data.training ({config.data.training})"
    refuse_unidentifiable(recs[0][1], source)
    if config.data.validation is not None:
        recs.append(("validation", config.data.load("validation")))
    for name, run in recs:
        progress(f"{name} record: {len(run)} samples at {1 / run.ts:g} Hz")
    prepared = []
    for name, run in recs:
        try:
            prepared.append(prepare(config, run, name))
        except UserError as exc:  # a filter cut-off above Nyquist, a record too short for it
            raise UserError(f"data.{name}: {exc}") from None
    for p in prepared:
        progress(f"{p.name}: {int(p.inside.sum())} samples inside the window, "
                 f"{int((~p.inside).sum())} outside")
    theta, warnings = record_checks(config, recs[0][1], prepared[0], source)
    warn(source, warnings)
    done = evaluate(config, prepared, progress, theta)
    rows = [row for row, _ in done]
    return {"rows": rows, "comparisons": comparisons(rows), "models": [m for _, m in done],
            "warnings": warnings,
            "window": dataclasses.asdict(config.data.window),
            "samples": {p.name: {"inside": int(p.inside.sum()),
                                 "outside": int((~p.inside).sum()),
                                 "rate_hz": 1 / p.ts} for p in prepared}}
