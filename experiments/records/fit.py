"""PGNN identification from measured records: the ``data:`` section of an experiment config.

    training record -> filtered features and force (the config's feature map, at the record's
    own sample rate) -> samples inside the training window -> LIP (least squares) and PGNN per
    seed -> force prediction error inside the window and beyond it, on every record

The fitting data are :func:`controllers.pgnn.training_data` at decimation 1, restricted to the
window (position and/or velocity of the filtered signals), then decimated with the PGNN's own
decimation (one sample per 8 ms by default, whatever the record's rate). The LIP of a record is
the least-squares ``theta`` on the same windowed, filtered samples, so both models see the same
data; it carries a constant force offset column besides the four physical ones (as the
diagnosis finds on EMPS and the published EMPS model has: without it the stiffness absorbs the
offset through the mean position). The PGNN's network carries its offset in its output bias.
``force_rms`` (N) is the rms of filtered force minus prediction over the samples inside
the window and over those outside it, on the training record and on the validation record.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from clm_sim.errors import UserError
from clm_sim.plant import THETA_NAMES, THETA_UNITS
from experiments.config import ExperimentConfig
from experiments.report.table_md import SHORT, fmt_p, theta_paths
from experiments.results import SeedFit
from experiments.stats.comparisons import AGAINST_LIP, Comparison, ComparisonFamily, varies
from experiments.stats.paired import Paired
from experiments.table import (SIDES, RecordRow, Settings, Stat, regularizers,
                               row_settings)


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
    """Per side of the window (:data:`experiments.table.SIDES`: inside, outside): rms force
    prediction error (N; None where the record has no such sample)."""
    err = rec.target - pred
    return dict(zip(SIDES, (_rms(err[rec.inside]), _rms(err[~rec.inside]))))


@dataclasses.dataclass(frozen=True)
class RecordLIP:
    """The LIP of a record: ``theta`` (named, SI units), a constant force ``offset_n`` (N; the
    published EMPS model and the diagnosis have one) and their standard errors ``std`` (the
    same names and ``"offset"``)."""

    theta: dict
    offset_n: float
    std: dict

    @property
    def theta_(self) -> dict:  # the fitted-model view record_warnings reads
        return self.theta

    @property
    def std_(self) -> dict:
        return self.std

    def predict(self, phi: np.ndarray) -> np.ndarray:
        """Force (N) for filtered feature columns ``phi`` (N, 4)."""
        return phi @ np.array([self.theta[k] for k in THETA_NAMES]) + self.offset_n


def fit_lip(train: Prepared) -> RecordLIP:
    """Least-squares theta and force offset on the windowed, filtered training samples, with
    their standard errors; ``UserError`` where the window does not excite every parameter (a
    column zero or collinear)."""
    phi = train.phi[train.inside]
    cols = np.column_stack([phi, np.ones(len(phi))])
    target = train.target[train.inside]
    scale = np.linalg.norm(cols, axis=0)
    if np.any(scale == 0) or np.linalg.matrix_rank(cols / scale) < cols.shape[1]:
        raise UserError(f"{train.name} record: the training window does not excite all "
                        f"parameters (a regressor is zero or collinear inside it); it needs "
                        f"motion in both directions (widen data.window)")
    x = np.linalg.lstsq(cols, target, rcond=None)[0]
    resid = target - cols @ x
    cov = np.linalg.pinv(cols.T @ cols) * (resid @ resid / max(len(target) - len(x), 1))
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = (*THETA_NAMES, "offset")
    return RecordLIP(dict(zip(THETA_NAMES, map(float, x[:4]))), float(x[4]),
                     dict(zip(names, map(float, std))))


def record_checks(config: ExperimentConfig, run, train: Prepared, source: str) -> tuple[
        RecordLIP, list[str]]:
    """The guards of :mod:`experiments.records.guards` on the training record: refuse (one
    line) a record or window that identifies nothing or a fit with non-finite numbers; the
    LIP of the window and the warnings where it is suspect."""
    from experiments.records.guards import cutoff_warnings, fit_warnings, refuse_small_window
    from experiments.records.suspicions import record_warnings

    refuse_small_window(int(train.inside.sum()), len(train.inside), source)
    try:
        lip = fit_lip(train)
    except UserError:  # collinear columns: name the cut-off where that is the cause
        cutoff = cutoff_warnings(config.features.regression_lowpass_hz, run.ts, len(run),
                                 "features.regression_lowpass_hz")
        if cutoff:
            raise UserError(f"{source}: nothing to identify: {cutoff[0]}") from None
        raise
    values = [*lip.theta.values(), lip.offset_n, *lip.std.values()]
    if not np.all(np.isfinite(values)):
        raise UserError(f"{source}: the fit gives non-finite parameters; the record's values "
                        f"are too large or degenerate for a least-squares fit")

    def refit(y, cutoff):
        try:
            band = dataclasses.replace(config, features=dataclasses.replace(
                config.features, regression_lowpass_hz=cutoff))
            other = prepare(band, dataclasses.replace(run, y=y), train.name)
            return fit_lip(other).theta["mass"] if other.inside.sum() else float("nan")
        except UserError:
            return float("nan")

    return lip, record_warnings(run, lip) + fit_warnings(
        run, config.features, lip.theta, lip.std, option="features.regression_lowpass_hz",
        refit=refit)


def _stat(values) -> Stat | None:
    values = [v for v in values if v is not None]
    if not values:
        return None
    return Stat(float(np.mean(values)),
                float(np.std(values, ddof=1)) if len(values) > 1 else 0.0,
                float(np.median(values)))


def fit_rows(config: ExperimentConfig, records: list[Prepared], progress,
             lip: RecordLIP | None = None) -> list[tuple[RecordRow, list]]:
    """Every row of ``config`` identified on ``records[0]`` and scored on all ``records``, with
    its models (``lip``: the LIP of the window, if already fitted)."""
    from controllers.pgnn import TrainingData
    from controllers.pgnn_settings import decimation_for
    from experiments.processes import workers
    from experiments.testbed import STREAM_NETWORK, stream

    train = records[0]
    lip = lip or fit_lip(train)
    theta_lip = lip.theta
    progress(f"LIP on the window ({int(train.inside.sum())} of {len(train.inside)} samples): "
             + ", ".join(f"{k} {v:.4g}" for k, v in theta_lip.items())
             + f", offset {lip.offset_n:.4g} N")
    rows = []
    for spec in config.feedforwards:
        if spec.kind == "lip":
            preds = [[lip.predict(r.phi) for r in records]]
            thetas, fits, models = [theta_lip], None, [None]
        else:
            step = decimation_for(train.ts, spec.pgnn.decimation)
            data = TrainingData(np.ascontiguousarray(train.phi[train.inside][::step]),
                                train.target[train.inside][::step].copy())
            progress(f"  training {spec.label()}: {spec.seeds} seeds on {len(data.target)} "
                     f"samples (decimation {step})")
            models = workers.map_fits([(spec.pgnn_settings(), config.features, data, theta_lip,
                                        stream(config.seed, STREAM_NETWORK, s))
                                       for s in range(spec.seeds)])
            preds = [[r.phi @ np.array([m.theta_[k] for k in THETA_NAMES]) + m.network(r.phi)
                      for r in records] for m in models]
            thetas = [dict(m.theta_) for m in models]
            fits = [SeedFit(s, m.fit_) for s, m in enumerate(models)]
        per_seed = [{r.name: force_rms(p, r) for p, r in zip(pred, records)} for pred in preds]
        kept = None if fits is None else [f.record for f in fits]
        row = RecordRow(
            spec.kind, spec.training, spec.lam, spec.hidden, len(per_seed), spec.label(),
            {k: float(np.mean([t[k] for t in thetas])) for k in THETA_NAMES}, thetas,
            force_rms={r.name: {side: _stat([s[r.name][side] for s in per_seed])
                                for side in SIDES} for r in records},
            force_rms_per_seed=per_seed,
            offset_n=lip.offset_n if spec.kind == "lip" else None,
            fits=None if fits is None else tuple(f.summary() for f in fits),
            converged=None if kept is None else sum(k.converged for k in kept),
            regularizers=None if kept is None else Settings(regularizers(spec, kept)),
            settings=None if kept is None else Settings(row_settings(spec, kept)))
        rows.append((row, models))
        progress(f"{spec.label()}: " + "; ".join(
            f"{r.name} " + ", ".join(f"{side} {_fmt(row.force_rms[r.name][side])} N"
                                     for side in SIDES) for r in records))
    return rows


def _fmt(stat: Stat | None) -> str:
    if stat is None:
        return "–"
    if not stat.std:
        return f"{stat.mean:.3f}"
    return f"{stat.mean:.3f} ± {stat.std:.3f} (median {stat.median:.3f})"


def comparisons(rows: list[RecordRow]) -> ComparisonFamily:
    """Paired differences of ``force_rms`` over seeds, per record and side, between PGNN rows of
    the same seed count that differ in one setting (:func:`experiments.stats.comparisons.varies`;
    ``b`` the earlier row), and of every PGNN row against the LIP (one LIP, so one-sample):
    ``a - b`` with its 95 % t-interval, the t and Wilcoxon signed-rank p-values, the paired log
    ratio ``a / b`` (the errors beyond the window are heavy-tailed: one seed reaches 1e5 N), the
    count of seeds where ``a < b``, and Holm's adjustment of the Wilcoxon p-values over the
    family; ``starred`` when that stays below 0.05."""
    out = []
    pgnn = [r for r in rows if r.kind == "pgnn"]
    lip = next((r for r in rows if r.kind == "lip"), None)
    pairs = []
    for j, a in enumerate(pgnn):
        for b in pgnn[:j]:
            one = varies(a.settings, b.settings) if a.n_seeds == b.n_seeds else None
            if one is not None:
                pairs.append((a, b, *one))
    if lip is not None:
        pairs += [(a, lip, AGAINST_LIP, None) for a in pgnn]
    for a, b, setting, values in pairs:
        for rec in a.force_rms:
            for side in SIDES:
                da = [s[rec][side] for s in a.force_rms_per_seed]
                db = [s[rec][side] for s in b.force_rms_per_seed]
                if None in da or None in db:
                    continue
                out.append(Comparison.of(Paired.of(da, db), a=a.label, b=b.label,
                                         metric="force_rms", record=rec, side=side,
                                         varies=setting, values=values))
    return ComparisonFamily.adjusted(out, "p_wilcoxon")


def to_markdown(rows: list[RecordRow], pairs: ComparisonFamily) -> str:
    """The force prediction table (N, mean ± std over seeds), the fits and the paired
    differences."""
    recs = list(rows[0].force_rms)
    head = (["feedforward", "seeds"]
            + [f"force rms {r} {side} [N]" for r in recs for side in SIDES]
            + [f"{SHORT[k]} [{THETA_UNITS[k]}]" for k in THETA_NAMES]
            + ["offset [N]", "fits converged"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row.label, str(row.n_seeds)]
        cells += [_fmt(row.force_rms[r][side]) for r in recs for side in SIDES]
        cells += [f"{row.theta_phy[k]:.4g}" for k in THETA_NAMES]
        cells.append(f"{row.offset_n:.4g}" if row.offset_n is not None else "–")
        cells.append(f"{row.converged}/{len(row.fits)}" if row.fits is not None else "–")
        lines.append("| " + " | ".join(cells) + " |")
    stops = [(r.label, f) for r in rows for f in r.fits or () if not f.converged]
    lines += ["", "Not converged: " + ("; ".join(
        f"{label} seed {f.seed} ({f.stop} after {f.iterations} iterations)"
        for label, f in stops) if stops else "none") + "."]
    lines += theta_paths([r for r in rows if r.fits is not None])
    lines += ["", "**Paired differences** (a − b over the same seeds, between rows that differ "
              "in one setting, named after `varies`, and against the LIP; mean, 95 % "
              "t-interval and median; seeds where a is lower; p-values of the t-test and the "
              "Wilcoxon signed-rank test; the geometric-mean ratio a/b with its interval; "
              "* where the Wilcoxon p stays below 0.05 after Holm's adjustment over every "
              "difference listed here):", ""]
    for c in pairs:
        ci = f"[{c.ci95[0]:+.3f}, {c.ci95[1]:+.3f}] N" if c.ci95 else "(no interval)"
        ratio = c.ratio
        ratio = (f"; ratio {ratio.ratio:.3f} [{ratio.low:.3f}, {ratio.high:.3f}]"
                 if ratio else "")
        lines.append(
            f"- force rms, {c.record} {c.side}, varies {c.varies}: {c.a} − {c.b} "
            f"= {c.diff:+.3f} N {ci}, median {c.median_diff:+.3f} N (n = {c.n}; a "
            f"lower in {c.a_lower}; p t {fmt_p(c.p_t)}, Wilcoxon "
            f"{fmt_p(c.p_wilcoxon)}, Holm {fmt_p(c.p_holm)}{ratio})"
            + (" *" if c.starred else ""))
    return "\n".join(lines) + "\n"


@dataclasses.dataclass
class RecordsResult:
    """The rows identified from a config's records, their comparisons, fitted models (per row,
    per seed), the record guards' warnings, the training window and the samples per record and
    side. ``to_json`` is the run's ``table.json`` (besides its environment)."""

    rows: list[RecordRow]
    comparisons: ComparisonFamily
    models: list
    warnings: list[str]
    window: dict
    samples: dict

    def to_json(self) -> dict:
        return {"rows": [r.to_json() for r in self.rows],
                "comparisons": self.comparisons.to_json(), "warnings": self.warnings,
                "window": self.window, "samples": self.samples}


def compute(config: ExperimentConfig, progress, warn=None) -> RecordsResult:
    """Identify every row of ``config`` from its ``data:`` records. The record guards refuse in one
    line a record or window that identifies nothing; ``warn(source, lines)`` receives the
    warnings where the result is suspect (default: stderr, one line each)."""
    from experiments.records.suspicions import warn as stderr_warn

    warn = warn or stderr_warn
    from experiments.records.guards import refuse_other_rate, refuse_unidentifiable

    recs = [("training", config.data.load("training"))]
    source = f"data.training ({config.data.training})"
    refuse_unidentifiable(recs[0][1], source)
    if config.data.validation is not None:
        recs.append(("validation", config.data.load("validation")))
        refuse_other_rate(recs[1][1], recs[0][1],
                          f"data.validation ({config.data.validation})")
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
    lip, warnings = record_checks(config, recs[0][1], prepared[0], source)
    warn(source, warnings)
    done = fit_rows(config, prepared, progress, lip)
    rows = [row for row, _ in done]
    return RecordsResult(
        rows, comparisons(rows), [m for _, m in done], warnings,
        dataclasses.asdict(config.data.window),
        {p.name: {**dict(zip(SIDES, (int(p.inside.sum()), int((~p.inside).sum())))),
                  "rate_hz": 1 / p.ts} for p in prepared})
