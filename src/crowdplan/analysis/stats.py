"""Statistics of the report: intervals across seeds and paired tests on identical test cases.

- ``across_seeds``: mean of one number per training seed with a Student-t 95% interval.
- ``mcnemar``: exact McNemar test of two planners' binary outcomes (success, collision) on the
  same cases: under "no difference" the discordant cases split as a fair coin.
- ``paired_bootstrap``: mean difference of a per-case quantity (time to goal) over the cases both
  planners finished, with a seeded bootstrap interval and two-sided p-value.
- ``compare``: all three for two result folders' episodes, paired by seed.
- ``spearman``: rank correlation (ties share their mean rank).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crowdplan.evaluation import Z95, EpisodeRecord

# Two-sided 95% quantiles of Student's t with 1..30 degrees of freedom.
_T975 = (
    12.706204736,
    4.302652730,
    3.182446305,
    2.776445105,
    2.570581836,
    2.446911851,
    2.364624252,
    2.306004135,
    2.262157163,
    2.228138852,
    2.200985160,
    2.178812830,
    2.160368656,
    2.144786688,
    2.131449546,
    2.119905299,
    2.109815578,
    2.100922040,
    2.093024054,
    2.085963447,
    2.079613845,
    2.073873068,
    2.068657610,
    2.063898562,
    2.059538553,
    2.055529439,
    2.051830516,
    2.048407142,
    2.045229642,
    2.042272456,
)
BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


def t_quantile_975(df: int) -> float:
    """The 97.5% quantile of Student's t with ``df`` degrees of freedom (table up to 30, then
    the Cornish-Fisher expansion around the normal quantile, within 1e-5)."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be >= 1, got {df}")
    if df <= len(_T975):
        return _T975[df - 1]
    z = Z95
    return (
        z
        + (z**3 + z) / (4 * df)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * df**3)
    )


@dataclass(frozen=True)
class SeedSummary:
    """Mean over seeds, its 95% interval (None for one seed) and the per-seed values."""

    mean: float
    ci95: tuple[float, float] | None
    values: tuple[float, ...]

    def text(self, digits: int = 3) -> str:
        if self.ci95 is None:
            return f"{self.mean:.{digits}f} (1 seed)"
        lo, hi = self.ci95
        return (
            f"{self.mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}] ({len(self.values)} seeds)"
        )


def across_seeds(values, bounds: tuple[float, float] = (-math.inf, math.inf)) -> SeedSummary:
    """Mean of one value per seed with the Student-t 95% interval of the mean, clipped to the
    metric's ``bounds`` (a rate's interval from two seeds can reach far outside 0..1)."""
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if not x.size:
        return SeedSummary(math.nan, None, ())
    mean = float(x.mean())
    if x.size == 1:
        return SeedSummary(mean, None, tuple(x.tolist()))
    half = t_quantile_975(x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)
    ci = (max(bounds[0], mean - half), min(bounds[1], mean + half))
    return SeedSummary(mean, ci, tuple(x.tolist()))


@dataclass(frozen=True)
class McNemar:
    """Cases where only A had the outcome (``only_a``), only B (``only_b``), and the exact
    two-sided p-value of a difference."""

    only_a: int
    only_b: int
    p_value: float


def mcnemar(a, b) -> McNemar:
    """Exact McNemar test of paired binary outcomes ``a`` and ``b`` (same cases, same order)."""
    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"paired outcomes need equal lengths, got {a.shape} and {b.shape}")
    only_a, only_b = int((a & ~b).sum()), int((~a & b).sum())
    n = only_a + only_b
    tail = sum(math.comb(n, k) for k in range(min(only_a, only_b) + 1)) / 2**n
    return McNemar(only_a, only_b, min(1.0, 2 * tail))


@dataclass(frozen=True)
class PairedDifference:
    """Mean of A - B over ``n`` paired cases, its bootstrap 95% interval and p-value."""

    mean: float
    ci95: tuple[float, float] | None
    p_value: float
    n: int


def paired_bootstrap(
    a, b, resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> PairedDifference:
    """Paired bootstrap of mean(a - b): resample the cases with replacement ``resamples`` times
    (seeded); percentile interval; p-value = twice the smaller share of resampled means on either
    side of 0 (at least 1 / resamples unless all differences are 0)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if d.size < 2:  # no spread to resample
        return PairedDifference(float(d.mean()) if d.size else math.nan, None, math.nan, d.size)
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, d.size, size=(resamples, d.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    if not d.any():
        p = 1.0
    else:
        p = 2 * min((means <= 0).mean(), (means >= 0).mean())
        p = min(1.0, max(p, 1 / resamples))
    return PairedDifference(float(d.mean()), (float(lo), float(hi)), float(p), int(d.size))


@dataclass(frozen=True)
class Comparison:
    """Planner A against planner B on the same test cases."""

    a: str
    b: str
    cases: int
    success: McNemar
    collision: McNemar
    time_to_goal: PairedDifference

    def row(self) -> list[str]:
        """Cells of the report's comparison tables."""
        t = self.time_to_goal
        time = (
            f"n/a ({t.n} case(s) both reached)"
            if t.ci95 is None
            else f"{t.mean:+.2f} s [{t.ci95[0]:+.2f}, {t.ci95[1]:+.2f}], {format_p(t.p_value)} "
            f"(n = {t.n})"
        )
        return [
            self.a,
            self.b,
            str(self.cases),
            f"{self.success.only_a} / {self.success.only_b}, {format_p(self.success.p_value)}",
            f"{self.collision.only_a} / {self.collision.only_b}, "
            f"{format_p(self.collision.p_value)}",
            time,
        ]


COMPARISON_HEADER = [
    "A",
    "B",
    "cases",
    "success only A / only B (McNemar)",
    "collision only A / only B (McNemar)",
    "time to goal A - B, both reached (paired bootstrap)",
]


def format_p(p: float) -> str:
    """ "p = 0.034" with two significant digits; "p <= 0.0001" from 0.0001 down (the resolution
    of the bootstrap)."""
    if math.isnan(p):
        return "p n/a"
    return "p <= 0.0001" if p <= 1e-4 else f"p = {p:.2g}"


def compare(
    a: list[EpisodeRecord], b: list[EpisodeRecord], name_a: str = "A", name_b: str = "B"
) -> Comparison:
    """Paired comparison of two evaluations of the same cases (matched by seed)."""
    by_seed = {r.seed: r for r in b}
    if {r.seed for r in a} != set(by_seed):
        raise ValueError(
            f"{name_a} and {name_b} were not evaluated on the same cases "
            f"({len(a)} and {len(b)} episodes, {len({r.seed for r in a} ^ set(by_seed))} differ)"
        )
    pairs = [(r, by_seed[r.seed]) for r in a]
    both = [(x.time, y.time) for x, y in pairs if x.outcome == y.outcome == "goal"]
    return Comparison(
        name_a,
        name_b,
        len(pairs),
        mcnemar([x.outcome == "goal" for x, _ in pairs], [y.outcome == "goal" for _, y in pairs]),
        mcnemar(
            [x.outcome == "collision" for x, _ in pairs],
            [y.outcome == "collision" for _, y in pairs],
        ),
        paired_bootstrap([t for t, _ in both], [t for _, t in both]),
    )


def ranks(x) -> np.ndarray:
    """Ranks 1..n of ``x``; tied values share the mean of their ranks."""
    x = np.asarray(x, dtype=float)
    order = np.argsort(x, kind="mergesort")
    sorted_x = x[order]
    ranks = np.empty(x.size)
    starts = np.flatnonzero(np.concatenate([[True], sorted_x[1:] != sorted_x[:-1]]))
    ends = np.concatenate([starts[1:], [x.size]])
    for s, e in zip(starts, ends, strict=True):
        ranks[order[s:e]] = (s + e + 1) / 2
    return ranks


def spearman(x, y) -> float:
    """Spearman's rank correlation of paired samples (nan with fewer than 3 or no spread)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if x.size < 3:
        return math.nan
    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return math.nan
    return float(np.corrcoef(rx, ry)[0, 1])
