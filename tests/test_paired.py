"""The one paired-comparison type against scipy's own paired tests (independent oracles)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from experiments.stats.paired import LogRatio, Paired, holm


def test_paired_difference_matches_scipy_ttest_rel_and_wilcoxon():
    rng = np.random.default_rng(5)
    b = rng.uniform(1.0, 2.0, 8)
    a = b + rng.normal(0.3, 0.2, 8)
    got = Paired.of(a, b, 0.9)
    ref = stats.ttest_rel(a, b)
    ci = ref.confidence_interval(0.9)
    # The same t statistic computed two ways: agreement to rounding.
    np.testing.assert_allclose(got.ci, [ci.low, ci.high], rtol=1e-12)
    np.testing.assert_allclose(got.p_t, ref.pvalue, rtol=1e-9)
    assert got.p_wilcoxon == pytest.approx(stats.wilcoxon(a, b).pvalue, rel=1e-12)
    assert got.diff == pytest.approx(np.mean(a - b), rel=1e-12)
    assert got.median_diff == pytest.approx(np.median(a - b), rel=1e-12)
    assert got.a_lower == int(np.sum(a < b))
    assert got.excludes_zero == (ci.low > 0 or ci.high < 0)


def test_one_b_stands_for_every_seed_and_one_pair_has_no_interval():
    a = [1.0, 2.0, 4.0]
    assert Paired.of(a, [2.0]) == Paired.of(a, [2.0, 2.0, 2.0])
    one = Paired.of([1.0], [2.0])
    assert one.ci is None and one.p_t is None and one.log_ratio is None
    assert not one.excludes_zero and one.difference_json()["ci95"] is None


def test_log_ratio_is_symmetric_and_refuses_non_positive_values():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(1, 3, 6), rng.uniform(1, 3, 6)
    ab, ba = LogRatio.of(a, b), LogRatio.of(b, a)
    # ln(a/b) = -ln(b/a): the interval flips exactly up to rounding.
    assert ab.ratio * ba.ratio == pytest.approx(1.0, rel=1e-12)
    assert ab.low * ba.high == pytest.approx(1.0, rel=1e-12)
    assert ab.p == pytest.approx(ba.p, rel=1e-12)
    assert LogRatio.of([1.0, 0.0], [1.0, 1.0]) is None
    assert Paired.of([1.0, -1.0], [1.0, 1.0]).log_ratio is None


def test_holm_keeps_none_out_of_the_family():
    # Family of two: 2 * 0.01, then max(0.02, 1 * 0.04).
    assert holm([None, 0.04, 0.01]) == [None, 0.04, 0.02]
