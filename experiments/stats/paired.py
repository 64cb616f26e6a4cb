"""Paired comparisons over seeds, computed once: the difference ``a - b`` with its t-interval and
tests, the ratio ``a / b`` on the log scale, and Holm's adjustment over a family.

Two rows share a seed when they share the training data and the network's draw, so their
per-seed values are paired. :class:`Paired` is what the simulation table
(:func:`experiments.table.comparisons`), the measured-record rows
(:func:`experiments.records.fit.comparisons`) and the failure map's cells report; each writes the
fields its file has always had.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# scipy.stats is imported in the three functions that compute an interval or a p-value: it is
# half a second of imports that every importer of experiments.table (every worker of a sweep,
# `clm-sim run` refusing a config) would otherwise pay before it needs it.


def t_interval(d, confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean of paired differences ``d`` and its t-interval at ``confidence`` (infinite for one
    difference)."""
    import scipy.stats

    d = np.asarray(d, dtype=float)
    n = len(d)
    half = (scipy.stats.t.ppf(0.5 + confidence / 2, n - 1) * d.std(ddof=1) / np.sqrt(n)
            if n > 1 else np.inf)
    return float(d.mean()), float(d.mean() - half), float(d.mean() + half)


def paired_tests(d) -> tuple[float | None, float | None]:
    """Two-sided p-values of paired differences ``d``: the t-test (assumes roughly normal
    differences) and the Wilcoxon signed-rank test (ranks, so one exploded seed cannot carry it;
    exact for small n without ties). None where undefined (fewer than two differences, or all
    equal)."""
    d = np.asarray(d, dtype=float)
    if len(d) < 2 or not np.any(d != d[0]):
        return None, None
    import scipy.stats

    p_t = float(scipy.stats.ttest_1samp(d, 0.0).pvalue)
    p_w = float(scipy.stats.wilcoxon(d).pvalue) if np.any(d != 0) else None
    return p_t, p_w


def holm(pvalues: list[float | None]) -> list[float | None]:
    """Holm's step-down adjustment of a family of p-values (None: not part of the family)."""
    idx = [i for i, p in enumerate(pvalues) if p is not None]
    order = sorted(idx, key=lambda i: pvalues[i])
    out: list[float | None] = [None] * len(pvalues)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * pvalues[i]))
        out[i] = running
    return out


@dataclass(frozen=True)
class LogRatio:
    """The paired ratio ``a / b`` of positive values as the geometric mean
    ``exp(mean(ln a - ln b))``, its t-interval ``[low, high]`` on the log scale (heavy-tailed
    errors: a ratio of 100 weighs as much as one of 1/100), the two-sided p-value of
    ``mean(ln a - ln b) = 0``, the number of pairs and the mean and sample std of the log
    differences."""

    ratio: float
    low: float
    high: float
    p: float
    n: int
    log_mean: float
    log_sd: float

    @classmethod
    def of(cls, a, b, confidence: float = 0.95) -> LogRatio | None:
        """None where a value is not positive or there is one pair."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        if len(a) < 2 or np.any(a <= 0) or np.any(b <= 0):
            return None
        d = np.log(a) - np.log(b)
        mean, lo, hi = t_interval(d, confidence)
        import scipy.stats

        n, sd = len(d), float(np.std(d, ddof=1))
        se = sd / math.sqrt(n)
        p = (float(2 * scipy.stats.t.sf(abs(mean) / se, n - 1)) if se > 0
             else (0.0 if mean else 1.0))
        return cls(float(np.exp(mean)), float(np.exp(lo)), float(np.exp(hi)), p, n, mean, sd)

    def to_json(self) -> dict:
        """As a table's comparison gives it: ``{"ratio", "ci95": [low, high]}``."""
        return {"ratio": self.ratio, "ci95": [self.low, self.high]}


@dataclass(frozen=True)
class Paired:
    """Paired samples ``a`` and ``b`` (one value per seed; a single ``b`` stands for every
    seed): ``n`` pairs, the means, the mean difference ``diff = mean(a - b)`` with its
    t-interval ``ci`` (None for one pair), the median difference, the count of seeds where
    ``a < b``, the t and Wilcoxon p-values (None where undefined) and the log ratio (None where
    a value is not positive)."""

    n: int
    mean_a: float
    mean_b: float
    diff: float
    ci: tuple[float, float] | None
    median_diff: float
    a_lower: int
    p_t: float | None
    p_wilcoxon: float | None
    log_ratio: LogRatio | None

    @classmethod
    def of(cls, a, b, confidence: float = 0.95) -> Paired:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        if len(b) == 1 and len(a) > 1:
            b = np.repeat(b, len(a))
        d = a - b
        mean, lo, hi = t_interval(d, confidence)
        p_t, p_w = paired_tests(d)
        return cls(n=len(d), mean_a=float(np.mean(a)), mean_b=float(np.mean(b)), diff=mean,
                   ci=(lo, hi) if len(d) > 1 else None, median_diff=float(np.median(d)),
                   a_lower=int(np.sum(d < 0)), p_t=p_t, p_wilcoxon=p_w,
                   log_ratio=LogRatio.of(a, b, confidence))

    @property
    def excludes_zero(self) -> bool:
        """Whether the (unadjusted) interval lies on one side of zero."""
        return bool(self.ci and (self.ci[0] > 0 or self.ci[1] < 0))

    def difference_json(self) -> dict:
        """The difference's fields as the tables write them."""
        return {"diff": self.diff, "ci95": None if self.ci is None else list(self.ci),
                "excludes_zero": self.excludes_zero, "p_t": self.p_t,
                "p_wilcoxon": self.p_wilcoxon}
