"""``table.json`` of a simulation run, written and read: its rows
(:class:`experiments.table.Row`), their comparisons
(:class:`experiments.stats.comparisons.ComparisonFamily`), the checks at an optimum and the
environment."""

from __future__ import annotations

import json

from clm_sim.errors import UserError
from experiments.stats.checks import optimum_checks
from experiments.stats.comparisons import ComparisonFamily, comparisons
from experiments.table import Row, lm_iterations, rows_entry, table_rows


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
    fits = [f for r in rows if r.kind == "pgnn" for f in (r.fits or ())]
    if fits:  # what the command ran (the CPU it cost is judged per iteration run)
        run, taken = lm_iterations(fits)
        doc["lm_iterations"] = {"run": run, "reused": taken}
    if environment is not None:
        doc["environment"] = environment
    return json.dumps(doc, indent=1)


def read(doc: dict, source) -> tuple[list, ComparisonFamily]:
    """The rows (:func:`experiments.table.read_row`) and comparisons of a ``table.json``
    document read from ``source``; ``UserError`` where it has no rows list or a row is not one."""
    rows = [rows_entry(row, i) for i, row in enumerate(table_rows(doc, source))]
    try:
        return rows, ComparisonFamily.from_json(doc.get("comparisons"))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{source}: comparisons: not a clm-sim comparison "
                        f"({type(exc).__name__}: {exc})") from None
