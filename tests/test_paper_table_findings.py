"""Each finding of docs/results/paper_table.md keeps its conclusion in the stored run behind it
(``docs/results/paper_table.json``): which comparisons are starred (Holm below 0.05), on which
side of zero each quoted interval lies, how many fits converged in the rows at their optimum,
and that the optimum's checks hold. Digits are not compared: a rerun that rounds differently
and keeps every conclusion passes; one that moves an interval across zero, unstars a
comparison or loses a converged fit fails. ``conclusions`` takes any paper-table
``table.json``, so a fresh run can be held to the page the same way::

    from tests.test_paper_table_findings import conclusions, FINDINGS, CONVERGED
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STORED = ROOT / "docs" / "results" / "paper_table.json"
PAGE = ROOT / "docs" / "results" / "paper_table.md"

SEQ = "PGNN sequential, weight decay 1e-5, n_l={n}"
PAPER0 = "PGNN simultaneous, lambda=0, the paper's cost, n_l={n}"
PAPER1 = "PGNN simultaneous, lambda=0.01, the paper's cost, n_l={n}"
OPT0 = "PGNN simultaneous, lambda=0, weight decay 1e-5, best of starts, n_l={n}"
OPT1 = "PGNN simultaneous, lambda=0.01, weight decay 1e-5, best of starts, n_l={n}"

# (a, b, metric, reference) -> (side of zero of the 95 % interval: "+", "-" or "0" where it
# holds zero, starred after Holm). The page's findings, in its order.
FINDINGS: dict[tuple, tuple[str, bool]] = {
    # (1) every PGNN row improves on the LIP on r1
    **{(row.format(n=n), "LIP", "mae", "r1"): ("-", True)
       for n in (16, 8) for row in (SEQ, PAPER0, PAPER1, OPT0, OPT1)},
    # (2) lambda = 0.01 holds theta_phy nearer theta_LIP than lambda = 0 at the optimum
    **{(OPT1.format(n=n), OPT0.format(n=n), "theta_drift", None): ("-", False) for n in (16, 8)},
    # (3) on r2 lambda resolves no difference, at the optimum and on the paper's cost
    **{(a.format(n=n), b.format(n=n), "mae", "r2"): ("0", False)
       for n in (16, 8) for a, b in ((OPT1, OPT0), (PAPER1, PAPER0))},
    # (4) at n_l = 8, lambda = 0.01 at its optimum ahead of sequential on r1, not on r2
    (OPT1.format(n=8), SEQ.format(n=8), "mae", "r1"): ("-", False),
    (OPT1.format(n=8), SEQ.format(n=8), "mae", "r2"): ("0", False),
}

# rows at their optimum: fits converged (of 10)
CONVERGED: dict[str, int] = {OPT0.format(n=16): 6, OPT1.format(n=16): 10,
                             OPT0.format(n=8): 4, OPT1.format(n=8): 9}


def _side(ci) -> str:
    lo, hi = ci
    return "+" if lo > 0 else "-" if hi < 0 else "0"


def conclusions(doc: dict) -> tuple[dict, dict]:
    """``(findings, converged)`` of a paper-table ``table.json``, keyed as ``FINDINGS`` and
    ``CONVERGED``: every comparison's side of zero and star, every row's converged count."""
    found = {(c["a"], c["b"], c["metric"], c["reference"]): (_side(c["ci95"]), c["starred"])
             for c in doc["comparisons"] if c["ci95"] is not None}
    converged = {r["label"]: r["converged"] for r in doc["rows"] if "fits" in r}
    return found, converged


@pytest.fixture(scope="module")
def stored() -> dict:
    return json.loads(STORED.read_text(encoding="utf-8"))


def test_findings_are_declared():
    assert len(FINDINGS) >= 8 and len(CONVERGED) == 4


@pytest.mark.parametrize("key", list(FINDINGS), ids=lambda k: f"{k[2]} {k[3]}: {k[0]} − {k[1]}")
def test_each_finding_keeps_its_conclusion(stored, key):
    found, _ = conclusions(stored)
    assert found[key] == FINDINGS[key], key


def test_rows_at_their_optimum_keep_their_convergence_counts(stored):
    _, converged = conclusions(stored)
    assert {k: converged[k] for k in CONVERGED} == CONVERGED


def test_the_optimum_checks_hold_in_the_stored_run(stored):
    """What must hold at an optimum (``experiments.stats.checks.optimum_checks``), as the run
    wrote it and recomputed from its rows: the lambda = 0 bound, the mean data cost and no converged fit
    beaten by another start, for n_l = 16 and 8."""
    from experiments.report import table_json
    from experiments.stats.checks import optimum_checks

    assert stored["checks_passed"] is True
    rows, _ = table_json.read(stored, "paper_table.json")
    counted = [c.to_json() for c in optimum_checks(rows) if c.at_optimum]
    assert {(c["check"], c["hidden"]) for c in counted} >= {
        (check, n) for check in ("bound", "data_cost", "converged_beaten") for n in (16, 8)}
    assert all(c["passed"] for c in counted), [c["detail"] for c in counted if not c["passed"]]


def test_the_conclusions_fail_where_they_should(stored):
    """An interval moved across zero, or a star lost, is a changed conclusion."""
    key = (OPT1.format(n=16), OPT0.format(n=16), "mae", "r2")
    doc = {**stored, "comparisons": [dict(c) for c in stored["comparisons"]]}
    moved = next(c for c in doc["comparisons"]
                 if (c["a"], c["b"], c["metric"], c["reference"]) == key)
    moved["ci95"] = [0.001, 0.1]
    assert conclusions(doc)[0][key] != FINDINGS[key]


def test_the_page_quotes_the_findings():
    """The page's answer names the rows at their optimum and the checks it rests on."""
    page = PAGE.read_text(encoding="utf-8")
    head = "\n".join(page.splitlines()[:25])
    assert "at its optimum" in head and "(3)" in head and "checks" in page
