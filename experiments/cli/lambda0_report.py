"""The λ rows of a paper-table run and their comparisons (``docs/results/lambda0.md``).

    python -m experiments.cli.lambda0_report results/paper_table/table.json

Both come from the run's ``table.json`` (``clm-sim run experiments/configs/paper_table.yaml``):

* per PGNN row, MAE on r1 and r2 (mean ± std over draws, the largest draw), θ_phy's largest
  relative drift from θ_LIP (mean / largest over the draws, %), the median stiffness over the
  draws (smallest, largest) and how many fits converged;
* the paired comparisons on r2 between rows one setting apart in λ (and, where a run has them,
  the network weight decay or the continuation start; the run's own ``comparisons``: difference a − b with its 95 %
  t-interval, the draws in which a is lower, Wilcoxon p, Holm's p of the t-test, starred below
  0.05, and the paired ratio a/b).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from clm_sim.errors import UserError
from clm_sim.modelfile import read_json
from experiments.report import table_json
from experiments.table import CONTINUATION, LAM, Row
from experiments.stats.comparisons import Comparison, ComparisonFamily

VARIED = (LAM, "weight_decay", CONTINUATION)


def _short(label: str) -> str:
    return (label.replace("PGNN simultaneous, ", "").replace("PGNN ", "")
            .replace(f"{LAM}=", "λ = "))


def rows_table(rows: list[Row]) -> str:
    """Per PGNN row: MAE r1 and r2, θ drift, median stiffness and fits converged."""
    lines = ["| row | MAE r1 [µm] | MAE r2 [µm] | θ drift mean / max [%] | "
             "median fk [N/m] (min, max) | converged |", "|---|---|---|---|---|---|"]

    def mae(v) -> str:
        return f"{v.mean():.3f} ± {v.std(ddof=1):.3f} (max {v.max():.3f})"

    for row in rows:
        if row.kind != "pgnn":
            continue
        m = {ref: np.array(row.mae_per_seed[ref]) * 1e6 for ref in ("r1", "r2")}
        drift = np.array([f.theta_drift for f in row.fits]) * 100
        fk = np.array([t["stiffness"] for t in row.theta_phy_per_seed])
        lines.append(f"| {_short(row.label)} | {mae(m['r1'])} | {mae(m['r2'])} | "
                     f"{drift.mean():.2f} / {drift.max():.2f} | {np.median(fk):.4g} "
                     f"({fk.min():.4g}, {fk.max():.4g}) | {row.converged}/{len(row.fits)} |")
    return "\n".join(lines) + "\n"


def _name(c: Comparison, rows: dict[str, Row]) -> str:
    b = rows[c.b].settings
    n = f"n_l = {b.hidden}"
    if c.varies == LAM:
        lam_a, lam_b = c.values[LAM]
        cost = ("paper's cost" if b.weight_decay == 0
                else f"weight decay {b.weight_decay:g}".replace("e-0", "e-"))
        return f"λ = {lam_a:g} − λ = {lam_b:g}, {cost}, {n}"
    if c.varies == "weight_decay":
        return f"weight decay − paper's cost, λ = {b.lam:g}, {n}"
    return f"continuation − none, λ = {b.lam:g} with weight decay, {n}"


def comparisons_table(rows: list[Row], pairs: ComparisonFamily) -> str:
    """The run's paired comparisons on r2 that vary λ, the weight decay or the continuation."""
    rows = {r.label: r for r in rows}
    chosen = [c for c in pairs
              if c.metric == "mae" and c.reference == "r2" and c.varies in VARIED]
    chosen.sort(key=lambda c: VARIED.index(c.varies))  # stable: the run's order within
    lines = ["| a − b | varies | MAE r2 difference [µm] | lower | Wilcoxon p | Holm p (t) | "
             "ratio a/b |", "|---|---|---|---|---|---|---|"]
    for c in chosen:
        a = np.array(rows[c.a].mae_per_seed["r2"])
        b = np.array(rows[c.b].mae_per_seed["r2"])
        lo, hi = (x * 1e6 for x in c.ci95)
        lr = c.ratio
        lines.append(f"| {_name(c, rows)} | {c.varies} | {c.diff * 1e6:+.3f} [{lo:+.3f}, "
                     f"{hi:+.3f}] | {int(np.sum(a < b))}/{len(a)} | {c.p_wilcoxon:.2g} | "
                     f"{c.p_holm:.2g}{' *' if c.starred else ''} | {lr.ratio:.3f} "
                     f"[{lr.low:.3f}, {lr.high:.3f}] |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table", help="a paper-table run's table.json")
    args = ap.parse_args(argv)
    try:
        rows, pairs = table_json.read(read_json(args.table, "clm-sim table.json"), args.table)
        out = rows_table(rows) + "\n" + comparisons_table(rows, pairs)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyError, TypeError, ValueError) as exc:
        print(f"error: {args.table}: not a paper-table run's table.json ({type(exc).__name__}: "
              f"{exc})", file=sys.stderr)
        return 2
    print(out, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
