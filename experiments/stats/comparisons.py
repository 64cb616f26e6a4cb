"""Paired comparisons between the rows of a table, and the family they form.

A :class:`Comparison` is one paired difference ``a - b`` over seeds (same seed = same network
draw and training data in both rows) with its 95 % t-interval and tests
(:class:`experiments.stats.paired.Paired`); a :class:`ComparisonFamily` is every comparison of
one table with Holm's adjustment over the family, applied here and nowhere else. Their
``to_json``/``from_json`` are ``table.json``'s ``comparisons``.

:func:`comparisons` pairs the PGNN rows of a simulation table that differ in one setting
(:func:`varies`) and each PGNN row with the LIP; the measured-record rows pair their force
errors (:func:`experiments.records.fit.comparisons`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from experiments.table import LAM, LAM_DIAG, Row
from experiments.stats.paired import Paired, holm

# What a PGNN row is, setting by setting, for "one setting at a time". The regularizer that pulls
# theta_phy (training mode with its own weights: lambda, Lambda's diagonal, the orthogonal and
# PINN weights) is one factor: a sequential row has no lambda to compare.
REGULARIZER_KEYS = ("training", LAM, LAM_DIAG, "orthogonal_weight", "pinn_weight")
AGAINST_LIP = "model (PGNN row vs the LIP)"


def varies(a, b) -> tuple[str, dict] | None:
    """The one setting in which rows with settings ``a`` and ``b`` (:class:`Settings`)
    differ, with its values ``{key: [a's, b's]}``; None when they differ in none or in more
    than one (or in n_l)."""
    diff = {k: [a.get(k), b.get(k)] for k in dict.fromkeys([*a, *b]) if a.get(k) != b.get(k)}
    if not diff or "hidden" in diff:
        return None
    reg = {k: v for k, v in diff.items() if k in REGULARIZER_KEYS}
    rest = [k for k in diff if k not in REGULARIZER_KEYS]
    if reg and rest or len(rest) > 1:
        return None
    if reg:
        return (next(iter(reg)) if len(reg) == 1 else "regularizer"), diff
    return rest[0], diff


@dataclass(frozen=True)
class Ratio:
    """The paired geometric-mean ratio a/b with its 95 % interval."""

    ratio: float
    low: float
    high: float

    def to_json(self) -> dict:
        return {"ratio": self.ratio, "ci95": [self.low, self.high]}

    @classmethod
    def from_json(cls, d) -> Ratio | None:
        return None if d is None else cls(d["ratio"], *d["ci95"])


@dataclass(frozen=True)
class Comparison:
    """One paired difference ``a - b`` between rows ``a`` and ``b`` (labels): the ``metric``
    on a ``reference`` (simulation) or on a ``record`` and ``side`` of its window (measured
    records), the setting that ``varies`` and its ``values``, the mean difference with its
    95 % t-interval ``ci95`` (None for one seed), p-values, the ratio a/b (MAE and force
    errors), and Holm's ``p_holm`` over its family (``starred`` below 0.05)."""

    a: str
    b: str
    metric: str
    varies: str
    values: dict | None
    n: int
    diff: float
    ci95: tuple[float, float] | None
    excludes_zero: bool
    p_t: float | None
    p_wilcoxon: float | None
    ratio: Ratio | None = None
    reference: str | None = None
    record: str | None = None
    side: str | None = None
    mean_a: float | None = None
    mean_b: float | None = None
    median_diff: float | None = None
    a_lower: int | None = None
    p_holm: float | None = None
    starred: bool = False

    @classmethod
    def of(cls, pair: Paired, *, with_ratio: bool = True, **where) -> Comparison:
        """From the paired samples; ``with_ratio`` False: no ratio (a simulation table gives
        one for MAE only)."""
        lr = pair.log_ratio if with_ratio else None
        return cls(n=pair.n, diff=pair.diff, ci95=pair.ci, excludes_zero=pair.excludes_zero,
                   p_t=pair.p_t, p_wilcoxon=pair.p_wilcoxon, mean_a=pair.mean_a,
                   mean_b=pair.mean_b, median_diff=pair.median_diff, a_lower=pair.a_lower,
                   ratio=lr and Ratio(lr.ratio, lr.low, lr.high), **where)

    @property
    def on_records(self) -> bool:
        return self.record is not None

    def to_json(self) -> dict:
        ci = None if self.ci95 is None else list(self.ci95)
        ratio = self.ratio and self.ratio.to_json()
        if self.on_records:
            out = {"a": self.a, "b": self.b, "metric": self.metric, "record": self.record,
                   "side": self.side, "varies": self.varies, "values": self.values,
                   "n": self.n, "diff": self.diff, "median_diff": self.median_diff,
                   "a_lower": self.a_lower, "ci95": ci, "excludes_zero": self.excludes_zero,
                   "p_t": self.p_t, "p_wilcoxon": self.p_wilcoxon, "log_ratio": ratio}
        else:
            out = {"a": self.a, "b": self.b, "metric": self.metric,
                   "reference": self.reference, "varies": self.varies, "values": self.values,
                   "n": self.n, "mean_a": self.mean_a, "mean_b": self.mean_b,
                   "diff": self.diff, "ci95": ci, "excludes_zero": self.excludes_zero,
                   "p_t": self.p_t, "p_wilcoxon": self.p_wilcoxon}
            if self.metric == "mae":
                out["log_ratio"] = ratio
        return {**out, "p_holm": self.p_holm, "starred": self.starred}

    @classmethod
    def from_json(cls, d: dict) -> Comparison:
        ci = d["ci95"]
        return cls(d["a"], d["b"], d["metric"], d["varies"], d.get("values"), d["n"],
                   d["diff"], None if ci is None else tuple(ci), d.get("excludes_zero"),
                   d.get("p_t"), d.get("p_wilcoxon"), Ratio.from_json(d.get("log_ratio")),
                   reference=d.get("reference"), record=d.get("record"), side=d.get("side"),
                   mean_a=d.get("mean_a"), mean_b=d.get("mean_b"),
                   median_diff=d.get("median_diff"), a_lower=d.get("a_lower"),
                   p_holm=d.get("p_holm"), starred=bool(d.get("starred")))


@dataclass(frozen=True)
class ComparisonFamily:
    """Every comparison of one table, with Holm's step-down adjustment of one of their
    p-values (``on``: ``p_t`` or ``p_wilcoxon``) over the whole family."""

    comparisons: tuple[Comparison, ...] = ()
    on: str | None = None

    @classmethod
    def adjusted(cls, comparisons, on: str) -> ComparisonFamily:
        """``comparisons`` with ``p_holm`` (Holm over them, of their ``on`` p-values) and
        ``starred`` (``p_holm < 0.05``) set."""
        comparisons = list(comparisons)
        ps = holm([getattr(c, on) for c in comparisons])
        return cls(tuple(replace(c, p_holm=p, starred=bool(p is not None and p < 0.05))
                         for c, p in zip(comparisons, ps)), on)

    def __iter__(self):
        return iter(self.comparisons)

    def __len__(self) -> int:
        return len(self.comparisons)

    def to_json(self) -> list[dict]:
        return [c.to_json() for c in self.comparisons]

    @classmethod
    def from_json(cls, d) -> ComparisonFamily:
        return cls(tuple(Comparison.from_json(c) for c in d or ()))


def comparisons(rows: list[Row]) -> ComparisonFamily:
    """Paired differences over seeds between PGNN rows of the same n_l and seed count that
    differ in exactly one setting (:func:`varies`; ``b`` is the earlier row of the table), and
    every PGNN row against the LIP (one LIP per run, so a one-sample interval): MAE per
    reference (m), largest relative theta_phy drift, data cost (N**2). Holm's adjustment is of
    the t p-values over every comparison of the table. ``excludes_zero`` is the unadjusted
    interval's verdict."""
    out = []
    pgnn = [r for r in rows if r.kind == "pgnn" and r.fits is not None]
    lip = next((r for r in rows if r.kind == "lip"), None)

    def add(a, b, metric, ref, da, db, setting, values):
        out.append(Comparison.of(Paired.of(da, db), with_ratio=metric == "mae", a=a.label,
                                 b=b.label, metric=metric, reference=ref, varies=setting,
                                 values=values))

    for j, a in enumerate(pgnn):
        for b in pgnn[:j]:
            if a.n_seeds != b.n_seeds or a.settings is None or b.settings is None:
                continue
            one = varies(a.settings, b.settings)
            if one is None:
                continue
            setting, values = one
            for ref in a.mae_per_seed:
                add(a, b, "mae", ref, a.mae_per_seed[ref], b.mae_per_seed[ref], setting,
                    values)
            add(a, b, "theta_drift", None, [f.theta_drift for f in a.fits],
                [f.theta_drift for f in b.fits], setting, values)
            add(a, b, "data_cost", None, [f.data_cost for f in a.fits],
                [f.data_cost for f in b.fits], setting, values)
    if lip is not None:
        for a in pgnn:
            for ref in a.mae_per_seed:
                add(a, lip, "mae", ref, a.mae_per_seed[ref], [lip.mae[ref].mean] * a.n_seeds,
                    AGAINST_LIP, None)
    return ComparisonFamily.adjusted(out, "p_t")
