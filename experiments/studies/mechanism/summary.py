"""The mechanism study's statistics: per case, finding (iii) over records x draws (two-level
bootstrap, the t-test on the per-record means, Holm over the cases), the mechanism's medians,
the unit-by-unit summary and the pre-registered prediction beside the outcome."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.stats

from controllers.pgnn_settings import FILE_KEYS
from experiments.stats.paired import holm
from experiments.studies.mechanism.result import (CaseSummary, CellResult, Fit, ForceDifference,
                                                   LipSummary, MaeDifference, MechanismResult,
                                                   Outcome, Ratio, RowSummary, UnitsRow,
                                                   WorstFit)
from experiments.studies.mechanism.settings import MechanismSettings


def cluster_bootstrap(values: list[list[float]], resamples: int, confidence: float,
                      rng: np.random.Generator) -> dict:
    """Mean of ``values[record][draw]`` and its percentile interval from a two-level bootstrap:
    records with replacement, then draws with replacement within each chosen record."""
    vals = [np.asarray(v, dtype=float) for v in values]
    n = len(vals)
    means = np.empty(resamples)
    for b in range(resamples):
        pick = rng.integers(0, n, n)
        means[b] = np.mean([vals[i][rng.integers(0, len(vals[i]), len(vals[i]))].mean()
                            for i in pick])
    tail = 50 * (1 - confidence)
    lo, hi = np.percentile(means, [tail, 100 - tail])
    return {"mean": float(np.mean([v.mean() for v in vals])), "ci": [float(lo), float(hi)]}


def _record_t(values: list[list[float]]) -> float | None:
    per_record = [float(np.mean(v)) for v in values]
    if len(per_record) < 2 or np.std(per_record) == 0:
        return None
    return float(scipy.stats.ttest_1samp(per_record, 0.0).pvalue)


def record_t_interval(values: list[list[float]], confidence: float) -> list[float] | None:
    """The t-interval of the mean over the per-record means of ``values[record][draw]``: the
    interval of the p column's test. With few records a percentile bootstrap over them is
    narrower than it should be (it never sees a record mean beyond the ones it has), so this
    one is printed beside it."""
    per_record = np.array([float(np.mean(v)) for v in values])
    if len(per_record) < 2:
        return None
    half = (scipy.stats.t.ppf(0.5 + confidence / 2, len(per_record) - 1)
            * per_record.std(ddof=1) / np.sqrt(len(per_record)))
    return [float(per_record.mean() - half), float(per_record.mean() + half)]


def paired_median(values: list[list[float]]) -> dict:
    """Median of paired differences ``values[record][draw]`` and how many are above zero: the
    force error beyond the range is heavy-tailed (one network that explodes beyond the range
    carries a mean of fifty pairs), so its mean is printed beside these, not alone."""
    flat = [x for v in values for x in v]
    return {"median": float(np.median(flat)), "higher": int(sum(x > 0 for x in flat)),
            "n": len(flat)}


def summarize(settings: MechanismSettings, results: list[CellResult]) -> MechanismResult:
    """Per case: finding (iii) over records x draws (difference and log ratio of MAE on the
    outside reference, lam - 0, and of the static force error beyond the range), the per-record
    means, and the mechanism's medians; Holm over the cases."""
    rng = np.random.default_rng(0)  # the bootstrap's own stream: same results, same intervals
    out, pvals = {}, []
    ref = settings.outside
    for case in settings.cases:
        cell_list = [r for r in results if r.case == case]
        pairs = []  # per record: [(fit lam0, fit reg), ...]
        for r in cell_list:
            by = {(f.draw, f.lam): f for f in r.fits}
            pairs.append([(by[(d, 0.0)], by[(d, settings.lam)]) for d in range(settings.draws)])
        diff = [[b.mae[ref] - a.mae[ref] for a, b in p] for p in pairs]
        logr = [[np.log(b.mae[ref] / a.mae[ref]) for a, b in p] for p in pairs]
        err = [[b.error_beyond_rms_n - a.error_beyond_rms_n for a, b in p] for p in pairs]
        boot_lr = cluster_bootstrap(logr, settings.bootstrap, settings.confidence, rng)
        fits = [f for r in cell_list for f in r.fits]

        def med(lam, get):
            return float(np.median([get(f) for f in fits if f.lam == lam]))

        rows = {}
        for name, lam in (("lambda=0", 0.0), (f"lambda={settings.lam:g}", settings.lam)):
            rows[name] = RowSummary(
                mae_inside_um=med(lam, lambda f: f.mae[settings.inside]) * 1e6,
                mae_outside_um=med(lam, lambda f: f.mae[ref]) * 1e6,
                error_beyond_rms_n=med(lam, lambda f: f.error_beyond_rms_n),
                error_along_rms_n=med(lam, lambda f: f.error_along_rms_n),
                dwell_force_n=med(lam, lambda f: f.dwell_force_n),
                drift_stiffness=med(lam, lambda f: f.drift_stiffness),
                network_linear_stiffness=med(lam, lambda f: f.network_linear["stiffness"]),
                model_linear_stiffness_minus_lip=med(
                    lam, lambda f: f.drift_stiffness + f.network_linear["stiffness"]),
                remainder_cubic=med(lam, lambda f: f.remainder_cubic),
                model_cubic=med(lam, lambda f: f.model_cubic),
                # how far each parameter travelled (median |theta - theta_LIP| over the fits):
                # a control that holds one parameter shows here where the drift went instead
                theta_moved={k: float(np.median(
                    [abs(f.theta[k] - r.lip.theta[k])
                     for r in cell_list for f in r.fits if f.lam == lam]))
                    for k in cell_list[0].lip.theta},
                converged=sum(f.stop == "converged" for f in fits if f.lam == lam),
                fits=sum(f.lam == lam for f in fits))
        lip = LipSummary(
            mae_inside_um=float(np.median([r.lip.mae[settings.inside]
                                           for r in cell_list])) * 1e6,
            mae_outside_um=float(np.median([r.lip.mae[ref] for r in cell_list])) * 1e6,
            error_beyond_rms_n=float(np.median([r.lip.error_beyond_rms_n for r in cell_list])),
            error_along_rms_n=float(np.median([r.lip.error_along_rms_n for r in cell_list])),
            need_along_rms_n=float(np.median([r.lip.need_along_rms_n for r in cell_list])))
        every = [f for f in fits]
        rho = scipy.stats.spearmanr([f.mae[ref] for f in every],
                                    [f.error_beyond_rms_n for f in every])
        worst = max(fits, key=lambda f: f.error_beyond_rms_n)
        worst_record = next(r.record for r in cell_list if any(f is worst for f in r.fits))
        p = _record_t(diff)
        pvals.append(p)
        boot = cluster_bootstrap(diff, settings.bootstrap, settings.confidence, rng)
        diff_summary = MaeDifference(
            mean=boot["mean"], ci=boot["ci"], per_record=[float(np.mean(d)) for d in diff],
            lam_lower=int(sum(x < 0 for d in diff for x in d)),
            n=int(sum(len(d) for d in diff)), p_records_t=p,
            ci_records_t=record_t_interval(diff, settings.confidence))
        boot_err = cluster_bootstrap(err, settings.bootstrap, settings.confidence, rng)
        out[case] = CaseSummary(
            effects=[e.as_config() for e in settings.cases[case]],
            truth_cubic=float(np.median([r.truth_cubic for r in cell_list])),
            truth_dwell_force_n=float(np.median([np.interp(max(r.y), r.y, r.truth)
                                                 for r in cell_list])),
            records=[r.record for r in cell_list], draws=settings.draws,
            mae_outside_diff=diff_summary,
            mae_outside_ratio=Ratio(ratio=float(np.exp(boot_lr["mean"])),
                                    ci=[float(np.exp(c)) for c in boot_lr["ci"]]),
            error_beyond_diff=ForceDifference(mean=boot_err["mean"], ci=boot_err["ci"],
                                              **paired_median(err)),
            spearman_mae_vs_force_error=float(rho.statistic),
            # the fit that carries a heavy tail, and on which side of the range its error is
            worst_error_beyond=WorstFit(
                record=worst_record, draw=worst.draw, lam=worst.lam,
                rms_n=worst.error_beyond_rms_n, sides_rms_n=worst.error_beyond_sides_rms_n,
                mae_outside_um=worst.mae[ref] * 1e6, error_along_rms_n=worst.error_along_rms_n),
            rows=rows, lip=lip, effects_beyond=dict(cell_list[0].effects_beyond),
            units=units_summary(settings, fits) if settings.near_linear is not None else None,
            prediction=(outcome(settings.prediction[case], diff_summary.mean,
                                diff_summary.ci_records_t,
                                tuple(r.error_beyond_rms_n for r in rows.values()))
                        if settings.prediction and case in settings.prediction else None))
    for case, p in zip(settings.cases, holm(pvals)):
        out[case] = replace(out[case], mae_outside_diff=replace(out[case].mae_outside_diff,
                                                                p_holm=p))
    return MechanismResult(out, settings)


def units_summary(settings: MechanismSettings, fits: list[Fit]) -> dict[str, UnitsRow]:
    """Per row: how many units the reading names (median, range), their share of the network's
    remainder force beyond the range, and the intervention against its control: medians of the
    static force error beyond and inside, the change of the error beyond per fit (arm minus
    none), and in how many fits the named arm changes it more (in absolute value) than the
    control."""
    out = {}
    for name, lam in (("lambda=0", 0.0), (f"lambda={settings.lam:g}", settings.lam)):
        rows = [f for f in fits if f.lam == lam]
        n_named = [len(f.units["intervention"]["named"]["units"]) for f in rows]

        def share(f):
            view, named = f.units["view"], f.units["intervention"]["named"]["units"]
            tot = sum(u["remainder_beyond_rms_n"] ** 2 for u in view)
            return (sum(view[j]["remainder_beyond_rms_n"] ** 2 for j in named) / tot
                    if tot > 0 else 0.0)

        def delta(f, arm):
            return (f.units["intervention"][arm]["error_beyond_rms_n"]
                    - f.error_beyond_rms_n)

        both = [f for f in rows if f.units["intervention"]["named"]["units"]]
        def arm_median(arm, key, scale=1.0):
            return (float(np.median([f.units["intervention"][arm][key] for f in both])) * scale
                    if both else None)

        out[name] = UnitsRow(
            named_median=float(np.median(n_named)), named_range=[min(n_named), max(n_named)],
            fits_with_named=len(both), fits=len(rows),
            named_share_beyond=float(np.median([share(f) for f in rows])),
            error_beyond_none_n=float(np.median([f.error_beyond_rms_n for f in rows])),
            error_beyond_named_n=arm_median("named", "error_beyond_rms_n"),
            error_beyond_control_n=arm_median("control", "error_beyond_rms_n"),
            error_inside_none_n=arm_median("none", "error_inside_rms_n"),
            error_inside_named_n=arm_median("named", "error_inside_rms_n"),
            error_inside_control_n=arm_median("control", "error_inside_rms_n"),
            delta_beyond_named_n=(float(np.median([delta(f, "named") for f in both]))
                                  if both else None),
            delta_beyond_control_n=(float(np.median([delta(f, "control") for f in both]))
                                    if both else None),
            mae_outside_named_um=arm_median("named", "mae_outside", 1e6),
            mae_outside_control_um=arm_median("control", "mae_outside", 1e6),
            mae_outside_none_um=(float(np.median([f.mae[settings.outside] for f in both]))
                                 * 1e6 if both else None),
            named_lowers_more=int(sum(delta(f, "named") < min(0.0, delta(f, "control"))
                                      for f in both)))
    return out


def outcome(pred: dict, mean_m: float, ci_m: list[float],
            error_beyond_n: tuple[float, float]) -> Outcome:
    """The pre-registered prediction ``pred`` (the config's numbers) beside what the run
    measured: the MAE difference lambda − 0 (m) and its t-interval on the per-record means, and
    the rows' static force errors beyond the range (N; lambda = 0, lambda). The sign holds when
    the interval lies wholly on the predicted side of zero; an amount holds when the measured
    value lies within ``factor`` of the predicted one (same sign)."""
    mean, ci = mean_m * 1e6, [c * 1e6 for c in ci_m]
    side = np.sign(pred["mae_diff_um"])
    f = pred["factor"]

    def within(measured, predicted):
        return bool(measured * predicted > 0 and 1 / f <= measured / predicted <= f)

    e0, e1 = error_beyond_n
    return Outcome(
        predicted=dict(pred), measured_mae_diff_um=mean, measured_ci_um=ci,
        sign_held=bool(side * ci[0] > 0 and side * ci[1] > 0),
        amount_held=within(mean, pred["mae_diff_um"]),
        measured_error_beyond_lambda0_n=e0, measured_error_beyond_lambda_n=e1,
        error_beyond_lambda0_held=within(e0, pred["error_beyond_lambda0_n"]),
        error_beyond_lambda_held=within(e1, pred[FILE_KEYS["error_beyond_lam_n"]]),
        calibrated_amount_held=(within(mean, pred["mae_diff_calibrated_um"])
                                if "mae_diff_calibrated_um" in pred else None))
