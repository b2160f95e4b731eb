"""Report statistics against scipy (a dev dependency, for these tests only) and by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdplan.analysis.stats import (
    across_seeds,
    compare,
    mcnemar,
    paired_bootstrap,
    spearman,
    t_quantile_975,
)
from crowdplan.evaluation import EpisodeRecord

scipy_stats = pytest.importorskip("scipy.stats", reason="scipy is in the dev extra")


@pytest.mark.parametrize("df", [1, 2, 5, 10, 29, 30, 31, 45, 100, 1000])
def test_t_quantile_matches_scipy(df):
    assert math.isclose(t_quantile_975(df), scipy_stats.t.ppf(0.975, df), abs_tol=1e-5)


def test_across_seeds_interval_matches_scipy_and_keeps_the_rows():
    values = [0.99, 0.988, 0.996, 0.914, 0.726, 0.894]
    s = across_seeds(values)
    lo, hi = scipy_stats.t.interval(0.95, len(values) - 1, np.mean(values), scipy_stats.sem(values))
    assert math.isclose(s.ci95[0], lo, abs_tol=1e-6) and math.isclose(s.ci95[1], hi, abs_tol=1e-6)
    assert s.values == tuple(values)
    assert across_seeds([0.5]).ci95 is None and "1 seed" in across_seeds([0.5]).text()


@pytest.mark.parametrize(("only_a", "only_b"), [(0, 0), (1, 0), (3, 9), (10, 2), (25, 25), (0, 40)])
def test_mcnemar_exact_matches_scipy_binomial(only_a, only_b):
    n_both = 7
    a = [True] * only_a + [False] * only_b + [True] * n_both
    b = [False] * only_a + [True] * only_b + [True] * n_both
    result = mcnemar(a, b)
    assert (result.only_a, result.only_b) == (only_a, only_b)
    n = only_a + only_b
    expected = 1.0 if n == 0 else scipy_stats.binomtest(min(only_a, only_b), n, 0.5).pvalue
    assert math.isclose(result.p_value, expected, rel_tol=1e-12)


def test_mcnemar_by_hand():
    # 5 discordant cases all one way: p = 2 * (1/2)^5.
    assert mcnemar([1, 1, 1, 1, 1, 0], [0, 0, 0, 0, 0, 0]).p_value == 2 / 32


def test_paired_bootstrap_is_seeded_and_agrees_with_scipy():
    rng = np.random.default_rng(3)
    a = rng.normal(11.0, 1.0, 300)
    b = a - 0.2 + rng.normal(0, 0.5, 300)
    first, second = paired_bootstrap(a, b), paired_bootstrap(a, b)
    assert first == second
    assert math.isclose(first.mean, float(np.mean(a - b)))
    ref = scipy_stats.bootstrap(
        (a - b,), np.mean, n_resamples=10_000, method="percentile", rng=np.random.default_rng(0)
    ).confidence_interval
    assert abs(first.ci95[0] - ref.low) < 0.01 and abs(first.ci95[1] - ref.high) < 0.01
    assert first.p_value < 0.001  # a real 0.2 s difference
    same = paired_bootstrap(a, a)
    assert same.mean == 0 and same.ci95 == (0.0, 0.0) and same.p_value == 1.0


def _rec(seed, outcome, time=10.0):
    return EpisodeRecord(seed, outcome, 40, time, 0.5, 1.0, 9.0, 0.8, 0.1, 0, 0.0, 1.0)


def test_compare_pairs_by_seed():
    a = [_rec(1, "goal", 10.0), _rec(2, "goal", 11.0), _rec(3, "collision", 5.0)]
    b = [_rec(3, "goal", 12.0), _rec(2, "goal", 12.0), _rec(1, "timeout", 25.0)]
    c = compare(a, b, "a", "b")
    assert (c.success.only_a, c.success.only_b) == (1, 1)
    assert (c.collision.only_a, c.collision.only_b) == (1, 0)
    assert c.time_to_goal.n == 1 and c.time_to_goal.mean == -1.0  # only seed 2 both reached
    assert c.row()[0:3] == ["a", "b", "3"]
    with pytest.raises(ValueError, match="not evaluated on the same cases"):
        compare(a, b[:2], "a", "b")


def test_spearman_matches_scipy_with_ties_and_infinities():
    rng = np.random.default_rng(1)
    x = rng.integers(0, 5, 50).astype(float)
    y = x + rng.normal(0, 2, 50)
    y[:3] = np.inf
    assert math.isclose(spearman(x, y), scipy_stats.spearmanr(x, y).statistic, abs_tol=1e-12)
    assert math.isnan(spearman([1, 1, 1], [1, 2, 3]))


def test_across_seeds_interval_stays_in_the_metric_range():
    s = across_seeds([0.0, 0.924], (0.0, 1.0))
    assert s.ci95 == (0.0, 1.0) and s.mean == 0.462
