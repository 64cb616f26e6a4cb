"""``table.md`` and ``table.csv``: the results table and the fit report, rendered from typed rows.

:func:`results_table` is the table ``clm-sim compare`` reads (:mod:`experiments.stats.agreement`);
:func:`to_markdown` adds, for a run with PGNN rows, :func:`fit_report`
(costs, starts, the checks at an optimum, the fits that did not converge, θ_phy's paths and
every paired comparison).
"""

from __future__ import annotations

import csv
import io

import numpy as np

from clm_sim.plant import THETA_NAMES, THETA_UNITS
from controllers.pgnn.fit_record import VERDICT_MARGIN
from experiments.table import LAM, Row, Stat, lm_iterations
from experiments.stats.agreement import Cell
from experiments.stats.checks import at_optimum, check_lines, optimum_checks
from experiments.stats.comparisons import Comparison, ComparisonFamily, comparisons

SHORT = {"mass": "m", "viscous": "fv", "coulomb": "fc", "stiffness": "fk"}


def fmt(value) -> str:
    return "–" if value is None else f"{value:g}" if isinstance(value, float) else str(value)


def _um(stat: Stat) -> str:
    s = f"{stat.mean * 1e6:.3f}"
    return s + (f" ± {stat.std * 1e6:.3f}" if stat.std else "")


def _theta_cells(row: Row) -> list[str]:
    """theta_phy's mean over seeds per parameter, ``± std`` over seeds where the seeds differ
    by half a unit of the mean's last printed digit or more: the spread shows how far the data
    determine the parameter, and it is the spread that :mod:`experiments.stats.agreement`
    allows a fresh run's mean on another machine."""
    th = row.theta_phy
    if not th:
        return ["–"] * 4
    per_seed = row.theta_phy_per_seed or []
    cells = []
    for k in THETA_NAMES:
        mean = f"{th[k]:.4g}"
        std = float(np.std([t[k] for t in per_seed], ddof=1)) if len(per_seed) > 1 else 0.0
        cells.append(mean + (f" ± {std:.2g}" if std >= 0.5 * Cell.parse(mean).ulp else ""))
    return cells


def results_table(rows: list[Row], swept: list[str] = ()) -> str:
    """The Markdown results table alone, one line per row: the ``swept`` keys' values (sweeps),
    the feedforward, its seeds, MAE (µm, mean ± std over seeds) per reference, theta_phy (mean ±
    std over seeds) and (PGNN) how many fits converged, ⚠ when not all."""
    refs = rows[0].references if rows else []
    fits = any(row.fits is not None for row in rows)
    head = (list(swept) + ["feedforward", "seeds"] + [f"MAE {r} [µm]" for r in refs]
            + [f"{SHORT[k]} [{THETA_UNITS[k]}]" for k in THETA_NAMES]
            + (["fits converged"] if fits else []))
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = ([fmt(row.value(k)) for k in swept] + [row.label, str(row.n_seeds)]
                 + [_um(row.mae[r]) for r in refs] + _theta_cells(row))
        if fits:
            conv = "–"
            if row.fits is not None:
                conv = f"{row.converged}/{len(row.fits)}" + (
                    f" ({row.at_edge} at the edge)" if row.at_edge else "") + (
                    " ⚠" if row.converged < len(row.fits) else "")
            cells.append(conv)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def to_markdown(rows: list[Row], swept: list[str] = (),
                pairs: ComparisonFamily | None = None) -> str:
    """:func:`results_table`; then :func:`fit_report` for PGNN rows (not for a sweep, whose
    ``swept`` keys head the table; ``pairs``: the rows' :func:`comparisons` when the caller has
    them)."""
    text = results_table(rows, swept)
    if any(row.fits is not None for row in rows) and not swept:
        text += fit_report(rows, pairs)
    return text


def fmt_diff(metric: str, x: float) -> str:
    """A difference of ``metric`` with its unit (MAE in µm, θ drift in %, costs in N²)."""
    if metric == "mae":
        return f"{x * 1e6:+.3f} µm"
    if metric == "theta_drift":
        return f"{x * 100:+.2f} %"
    return f"{x:+.3g} N²"


def fit_report(rows: list[Row], pairs: ComparisonFamily | None = None) -> str:
    """For the PGNN rows: training cost, largest relative theta_phy drift and peak network force
    beyond the training range; the fits that did not converge; the paired comparisons."""
    pgnn = [r for r in rows if r.fits is not None]
    beyond = list(dict.fromkeys(ref for r in pgnn for ref in r.network_peak_beyond_n))
    head = (["PGNN", "data cost [N²]", "reg. cost [N²]", "max θ drift [%]",
             "median fk [N/m] (max)", "fits with fc < 0"]
            + [f"peak f_NN beyond training range, {ref} [N]" for ref in beyond])
    lines = ["", ("Training cost, largest relative drift of θ_phy from θ_LIP, peak network force "
                  "beyond the training range (mean ± std over seeds):"), "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in pgnn:
        cells = [r.label, f"{r.data_cost.mean:.5f} ± {r.data_cost.std:.5f}",
                 f"{r.reg_cost.mean:.3g}",
                 f"{r.theta_drift.mean * 100:.2f} ± {r.theta_drift.std * 100:.2f}"]
        cells += _stiffness_cells(r)
        peaks = r.network_peak_beyond_n
        cells += [f"{peaks[ref].mean:.2f} ± {peaks[ref].std:.2f}" if ref in peaks else "–"
                  for ref in beyond]
        lines.append("| " + " | ".join(cells) + " |")
    lines += start_report(pgnn)
    checks = optimum_checks(rows)
    if checks:
        lines += ["", "**What must hold at an optimum** (`checks` in table.json):", ""]
        lines += check_lines(checks)
    capped = [(r.label, f) for r in pgnn for f in r.fits if not f.converged]
    total = sum(len(r.fits) for r in pgnn)
    edge = sum(f.stop == "at_edge" for r in pgnn for f in r.fits)
    lines += ["", (f"**Fits:** {total - len(capped)} of {total} converged, {edge} at the edge "
                   "(converged: the Gauss-Newton model predicts at most a relative decrease "
                   "ftol of the training cost, and θ_phy has settled: over the last quarter of "
                   f"the iterations its force moved by at most theta_ftol / {VERDICT_MARGIN:g} "
                   "of the training force's rms; `theta_moving`: it moved more than "
                   f"theta_ftol × {VERDICT_MARGIN:g}; `at_edge`: a test within that factor of "
                   "its threshold, where the last bits decide it, or a fit at its iteration "
                   f"cap within {VERDICT_MARGIN:g} × ftol).")]
    if capped:
        lines += ["Not converged (⚠ above): " + "; ".join(
            f"{label} seed {f.seed} ({f.stop} after {f.iterations} iterations, "
            f"first-order measure {f.first_order:.1e}"
            + (f", θ force moved {100 * f.theta_moved:.1f} %"
               if f.theta_moved is not None else "")
            + ")" for label, f in capped) + "."]
    lines += theta_paths(pgnn)
    lines += ["", ("**Paired comparisons** (a − b over the same seeds, i.e. the same network "
                   "draw, between rows that differ in one setting, named after `varies`; mean "
                   "and 95 % t-interval; p-values of the paired t-test and of the Wilcoxon "
                   "signed-rank test; for MAE the geometric-mean ratio a/b with its interval; "
                   "* where the t-test stays below 0.05 after Holm's adjustment over every "
                   "comparison listed here):"), ""]
    for c in comparisons(rows) if pairs is None else pairs:
        lines.append(comparison_line(c))
    return "\n".join(lines) + "\n"


def _stiffness_cells(r: Row) -> list[str]:
    """The median stiffness over seeds (largest) and the fits with a negative Coulomb force."""
    per_seed = r.theta_phy_per_seed or []
    fk = [t['stiffness'] for t in per_seed]
    return [f"{np.median(fk):.4g} ({max(fk):.4g})" if fk else "–",
            f"{sum(t['coulomb'] < 0 for t in per_seed)}/{len(per_seed)}"]


def start_report(pgnn: list[Row]) -> list[str]:
    """For the PGNN rows fitted from several starts per draw: the start kept, how many starts
    agree with it (within ``start_rtol`` of its objective), the fits with multiple optima
    (two converged starts more than ``start_rtol`` apart) and the spread of the starts'
    objectives, and the iterations run and taken from other rows."""
    several = [r for r in pgnn if at_optimum(r)]
    if not several:
        return []
    lines = ["", ("**Starts** (rows at their optimum: per draw the lowest objective of its "
                  "starts is kept; a start agrees when its objective is within start_rtol of "
                  "the kept one; multiple optima: two starts that passed the optimizer's test "
                  "end more than start_rtol apart; iterations run, and taken from another "
                  "row's fits of the same draw):"), "",
             "| PGNN | start_rtol | kept (draws) | starts agreeing, median (min) of n | "
             "fits with multiple optima | spread of the starts' objectives, median (max) [%] | "
             "iterations run (taken) |", "|---|---|---|---|---|---|---|"]
    for r in several:
        fits = r.fits
        kept = [f.start or "draw" for f in fits]
        agree = [f.agree for f in fits]
        n = [len(f.starts) for f in fits]
        spread = [f.spread * 100 for f in fits]
        run, taken = lm_iterations(fits)
        lines.append(
            f"| {r.label} | {fits[0].start_rtol:g} | "
            + ", ".join(f"{k} {kept.count(k)}" for k in sorted(set(kept)))
            + f" | {np.median(agree):g} ({min(agree)}) of {np.median(n):g} "
            f"({min(n)}–{max(n)}) | {sum(f.multiple_optima for f in fits)}/{len(fits)} | "
            f"{np.median(spread):.2f} ({max(spread):.2f}) | {run} ({taken}) |")
    return lines


def fmt_p(p) -> str:
    return "–" if p is None else f"{p:.2g}"


def comparison_line(c: Comparison) -> str:
    """One paired comparison of a simulation table as a Markdown list item."""
    where = f" on {c.reference}" if c.reference else ""
    ci = (f"[{fmt_diff(c.metric, c.ci95[0])}, {fmt_diff(c.metric, c.ci95[1])}]"
          if c.ci95 else "(no interval)")
    ratio = c.ratio
    extra = (f"; ratio {ratio.ratio:.3f} [{ratio.low:.3f}, {ratio.high:.3f}]"
             if ratio else "")
    return (f"- {c.metric}{where}, varies {c.varies}: {c.a} − {c.b} = "
            f"{fmt_diff(c.metric, c.diff)} {ci} (n = {c.n}; p t {fmt_p(c.p_t)}, "
            f"Wilcoxon {fmt_p(c.p_wilcoxon)}, Holm {fmt_p(c.p_holm)}{extra})"
            + (" *" if c.starred else ""))


def theta_paths(pgnn: list) -> list[str]:
    """How θ_phy moves with the iterations in the rows where a fit did not converge: the median
    over seeds of the data cost and θ_phy at each checkpoint iteration reached by every seed."""
    out = []
    for r in pgnn:
        if r.training == "sequential" or all(f.converged for f in r.fits):
            continue
        paths = [f.theta_path for f in r.fits]
        if not all(paths):
            continue
        common = set.intersection(*({p.iteration for p in path} for path in paths))
        if not out:
            out += ["", "**θ_phy with the iterations** (median over seeds, at the iterations "
                    "every seed reached; rows with a fit that did not converge):", ""]
        out += [f"{r.label}:", "", "| iteration | data cost [N²] | "
                + " | ".join(f"{SHORT[k]} [{THETA_UNITS[k]}]" for k in THETA_NAMES) + " |",
                "|---|---|" + "---|" * len(THETA_NAMES)]
        for it in sorted(common):
            at = [next(p for p in path if p.iteration == it) for path in paths]
            out.append(f"| {it} | {np.median([a.data_cost for a in at]):.5f} | " + " | ".join(
                f"{np.median([a.theta[k] for a in at]):.4g}" for k in THETA_NAMES) + " |")
        out.append("")
    return out


def to_csv(rows: list[Row], swept: list[str] = ()) -> str:
    """CSV, one line per row: the swept keys' values, the row's settings, MAE (m) per
    reference, theta_phy, and for sweeps the task key."""
    refs = rows[0].references if rows else []
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    task = ["task"] if swept else []
    w.writerow(list(swept) + ["label", "kind", "training", LAM, "hidden",
                              "n_seeds"]
               + [f"mae_{r}_{s}_m" for r in refs for s in ("mean", "std")]
               + [f"theta_{k}" for k in THETA_NAMES] + ["fits_converged"] + task)
    for row in rows:
        th = row.theta_phy or {}
        w.writerow([row.value(k) for k in swept]
                   + [row.label, row.kind, row.training or "",
                      "" if row.lam is None else row.lam, row.hidden or "", row.n_seeds]
                   + [f"{getattr(row.mae[r], s):.6e}" for r in refs for s in ("mean", "std")]
                   + [f"{th[k]:.6g}" if th else "" for k in THETA_NAMES]
                   + ["" if row.converged is None else row.converged]
                   + [row.value(k) for k in task])
    return out.getvalue()
