"""The results table shared by every experiment: ``table.json`` and what a PGNN row's settings are.

``table.json`` is ``{"rows": [row, ...], "comparisons": [...], "checks": [...]}``: each row an
:class:`experiments.rows.Row` (built once by :class:`experiments.results.TableRow`; MAE in
metres, theta_phy per seed, a PGNN row's fits, settings and regularizers from
:func:`regularizers` and :func:`row_settings`), the comparisons an
:class:`experiments.stats.comparisons.ComparisonFamily` (paired differences over seeds with
Holm's adjustment) and the checks at an optimum (:mod:`experiments.stats.checks`). The Markdown
and CSV are :mod:`experiments.report.table_md`; the summaries over a sweep's seeds
:mod:`experiments.stats.seeds`.
"""

from __future__ import annotations

import dataclasses
import json
from typing import TYPE_CHECKING

from clm_sim.plant import THETA_UNITS  # noqa: F401 (re-exported for the studies)
from clm_sim.errors import UserError
from experiments.rows import CONTINUATION, LAM, LAM_DIAG, Row, rows_entry, table_rows
from experiments.stats.checks import optimum_checks
from experiments.stats.comparisons import ComparisonFamily, comparisons
from experiments.stats.paired import holm, t_interval  # noqa: F401 (re-exported for the studies)

if TYPE_CHECKING:  # the record type, for annotations only
    from controllers.pgnn.fit_record import FitRecord


def regularizers(spec, fits: list[FitRecord]) -> dict:
    """Every term and start that shaped a PGNN row besides the data: the pull toward theta_LIP
    (lambda and Lambda's diagonal), the network L2 (``weight_decay``), the other penalties, the
    continuation start (the lambda of the extra start where it applied, else 0), the
    initialization (``init``: ``lemma`` is the paper's least-squares start) and the starts whose
    best fit was kept (``starts_kept``, counted over seeds)."""
    pg = spec.pgnn
    kept = [f.start or "draw" for f in fits]
    return {LAM: spec.lam if spec.training != "sequential" else None,
            LAM_DIAG: pg.lam_diag,
            "weight_decay": pg.weight_decay,
            "orthogonal_weight": pg.orthogonal_weight,
            "pinn_weight": pg.pinn_weight if spec.training == "pinn" else 0.0,
            CONTINUATION: max((f.continuation_lam or 0.0 for f in fits), default=0.0),
            "init": "lemma" if pg.init == "optimized" else "random",
            "restarts": pg.restarts,
            "starts_kept": {k: kept.count(k) for k in sorted(set(kept))}}


# The optimizer's settings a PGNN row also compares by (PGNNSettings' names; the regularizer's
# are :data:`experiments.stats.comparisons.REGULARIZER_KEYS`).
OTHER_KEYS = ("weight_decay", "init", "restarts", "optimizer", "activation", "max_iter", "ftol",
              "theta_ftol", "decimation", "validation_fraction", "adam_lr", "starts",
              "start_rtol")


def row_settings(spec, fits: list[FitRecord]) -> dict:
    """The settings of a PGNN row that :func:`experiments.stats.comparisons.varies` compares:
    the regularizer's keys, the network weight decay, the continuation start as it ran (0
    where none did), and the optimizer's settings."""
    reg = regularizers(spec, fits)
    pg = dataclasses.asdict(spec.pgnn)
    out = {"training": spec.training, "hidden": spec.hidden}
    out.update({k: reg[k] for k in (LAM, LAM_DIAG, "orthogonal_weight", "pinn_weight",
                                    "weight_decay", CONTINUATION, "init")})
    out.update({k: pg[k] for k in OTHER_KEYS if k in pg and k not in out})
    if "starts" in out:
        out["starts"] = list(out["starts"])
    if spec.training == "sequential" and "exchange" in spec.pgnn.starts:
        # A sequential fit has no lambda to continue from; with the exchange it is compared
        # with the simultaneous rows that exchange, as one procedure applied to each.
        out[CONTINUATION] = spec.pgnn.continuation_lam
    return out


def to_json(rows: list[Row], environment: dict | None = None,
            pairs: ComparisonFamily | None = None) -> str:
    """``{"rows": ...}``, with ``"comparisons"`` when there are PGNN rows to compare, the checks
    at an optimum and ``"environment"`` (library versions, CPU, kernels:
    :func:`clm_sim.numerics.environment`) when given. ``pairs``: :func:`comparisons` of ``rows``
    when the caller has them (their Wilcoxon p-values cost up to 0.2 s each where a difference
    is zero)."""
    doc = {"rows": [row.to_json() for row in rows]}
    pairs = comparisons(rows) if pairs is None else pairs
    if pairs:
        doc["comparisons"] = pairs.to_json()
    checks = optimum_checks(rows)
    if checks:
        doc["checks"] = [c.to_json() for c in checks]
        doc["checks_passed"] = all(c.passed for c in checks if c.at_optimum)
    if environment is not None:
        doc["environment"] = environment
    return json.dumps(doc, indent=1)


def read(doc: dict, source) -> tuple[list, ComparisonFamily]:
    """The rows (:func:`experiments.rows.read_row`) and comparisons of a ``table.json``
    document read from ``source``; ``UserError`` where it has no rows list or a row is not one."""
    rows = [rows_entry(row, i) for i, row in enumerate(table_rows(doc, source))]
    try:
        return rows, ComparisonFamily.from_json(doc.get("comparisons"))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{source}: comparisons: not a clm-sim comparison "
                        f"({type(exc).__name__}: {exc})") from None
