"""What must hold at an optimum, checked on a table's PGNN rows (``table.json``'s ``checks``)."""

from __future__ import annotations

from dataclasses import dataclass

from experiments.table import LAM, Row
from experiments.stats.comparisons import varies

BOUND_RTOL = 1e-12  # the lambda = 0 bound holds by construction; this is rounding


def at_optimum(row: Row) -> bool:
    """Whether a PGNN row reports each draw at the lowest objective of several starts (its
    ``starts`` setting holds more than the draw), rather than where one start's budget ends."""
    return row.settings is not None and len(row.settings.starts) > 1


@dataclass(frozen=True)
class Check:
    """One check: its name, the row ``a`` (and ``b`` it is held against, None for one row),
    their n_l, whether both rows are at their optimum (a check of a fixed budget does not
    count), whether it ``passed``, the seeds that fail it, the means compared and one
    sentence."""

    check: str
    a: str
    b: str | None
    hidden: object
    at_optimum: bool
    passed: bool
    detail: str
    failing_seeds: list[int] | None = None
    mean_a: float | None = None
    mean_b: float | None = None

    def to_json(self) -> dict:
        out = {"check": self.check, "a": self.a, "b": self.b, "hidden": self.hidden,
               "at_optimum": self.at_optimum, "passed": self.passed}
        if self.failing_seeds is not None:
            out["failing_seeds"] = self.failing_seeds
        if self.mean_a is not None:
            out.update(mean_a=self.mean_a, mean_b=self.mean_b)
        out["detail"] = self.detail
        return out

    def __str__(self) -> str:
        """The check as a Markdown list item."""
        what = self.a if self.b is None else f"{self.a} against {self.b}"
        mark = "holds" if self.passed else "FAILS"
        budget = "" if self.at_optimum else " (a fixed budget, not an optimum: not counted)"
        return f"- {self.check}, {what}: {mark}: {self.detail}{budget}"


def optimum_checks(rows: list[Row]) -> list[Check]:
    """Per pair of PGNN rows that differ in lambda alone, one at lambda = 0: ``bound``, no
    lambda = 0 fit's objective (data cost and weight decay) ends above its draw's regularized
    fit's objective (pull included), since that fit is feasible at lambda = 0; ``data_cost``,
    the lambda = 0 row's mean data cost is no higher than the regularized row's. And per PGNN
    row, ``converged_beaten``: no fit is marked converged that another of its starts beats by
    more than its ``start_rtol``. A pair or row with one start per draw (the paper's cost: a
    fixed budget, no minimizer) is listed with ``at_optimum`` false and does not count."""
    out = []
    pgnn = [r for r in rows if r.kind == "pgnn" and r.fits is not None
            and r.settings is not None]
    for a in pgnn:
        for b in pgnn:
            one = varies(a.settings, b.settings)
            if (one is None or one[0] != LAM or a.lam != 0 or not b.lam
                    or a.n_seeds != b.n_seeds):
                continue
            optimum = at_optimum(a) and at_optimum(b)
            above = [fa.seed for fa, fb in zip(a.fits, b.fits)
                     if fa.objective > fb.objective * (1 + BOUND_RTOL)]
            out.append(Check("bound", a.label, b.label, a.hidden, optimum, not above,
                             f"{len(above)} of {a.n_seeds} lambda = 0 fits end above "
                             f"their draw's lambda = {b.lam:g} objective", failing_seeds=above))
            da, db = a.data_cost.mean, b.data_cost.mean
            out.append(Check("data_cost", a.label, b.label, a.hidden, optimum, da <= db,
                             f"mean data cost {da:.5f} against {db:.5f} N² "
                             f"({(da / db - 1) * 100:+.2f} %)", mean_a=da, mean_b=db))
    for r in pgnn:
        beaten = [f.seed for f in r.fits if f.converged
                  and f.start_rtol is not None and f.starts
                  and min(s.cost for s in f.starts) < f.objective * (1 - f.start_rtol)]
        out.append(Check("converged_beaten", r.label, None, r.hidden, at_optimum(r),
                         not beaten, f"{len(beaten)} fits marked converged that another of "
                         f"their starts beats by more than start_rtol", failing_seeds=beaten))
    return out


def check_lines(checks: list[Check]) -> list[str]:
    """The checks as Markdown list items, the rows at their optimum first."""
    return [str(c) for c in sorted(checks, key=lambda c: not c.at_optimum)]
