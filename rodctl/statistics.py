"""Paired comparisons of two methods over shared targets: a BCa bootstrap CI, a signed-rank test,
and Holm's correction for the many tests a benchmark makes (docs/statistics.md).

Why paired: every method runs the same targets from the same start, so the difference on each
target removes the target's own difficulty, which dominates the spread of raw step counts.

- The interval: the mean paired difference gets a 95 % BCa bootstrap confidence interval from
  `scipy.stats.bootstrap` (bias-corrected and accelerated; seeded, so a report is reproducible).
  All differences equal (a zero-width sample) give the point interval [mean, mean]; when BCa is
  undefined (its jackknife degenerate) the percentile interval is used and `ci_method` says so.
- The test: a two-sided Wilcoxon signed-rank test of the differences. Zero differences are ties
  that carry no evidence either way and are dropped first (Wilcoxon's own treatment, scipy's
  `zero_method="wilcox"`). Of the n non-zero differences: n <= 50 with no tied |d| gives the exact
  null distribution (`method="exact"`); tied |d| with n <= 13 the exact permutation distribution
  over all 2^n sign flips; otherwise the normal approximation with the tie-corrected variance and
  no continuity correction (`method="asymptotic"`). `p_method` records which. With fewer than 6
  non-zero differences no p-value below 0.05 is possible, and none is claimed.
- Multiplicity: a benchmark makes hundreds of tests; `holm` adjusts a family of p-values so that
  the chance of *any* false claim in the family stays below alpha, whatever the dependence
  between the tests (they share targets). `significant()` reads the adjusted p only. A
  difference computed alone is a family of one (adjusted = raw); `adjust` re-adjusts a family.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Fewest non-zero differences for which the signed-rank test can reach p < 0.05 (exact: 1/32).
MIN_NONZERO = 6


@dataclass(frozen=True)
class PairedDifference:
    """method - reference over the targets both have a value on.

    Attributes:
        n: number of paired targets.
        mean: mean difference (negative: the method needs fewer / less).
        ci_low, ci_high: bootstrap 95 % interval of the mean (not adjusted for multiplicity).
        p_value: raw Wilcoxon signed-rank p (two-sided), None when it cannot be computed.
        wins, ties, losses: targets where the method is lower, equal, higher.
        p_adjusted: p after Holm's correction over the family this test belongs to (alone:
            itself), None with `p_value`.
        p_method: how p was computed: "exact" or "normal" (None: no p).
        ci_method: "BCa", "percentile" (BCa undefined) or "point" (all differences equal).
    """

    n: int
    mean: float | None
    ci_low: float | None
    ci_high: float | None
    p_value: float | None
    wins: int
    ties: int
    losses: int
    p_adjusted: float | None = None
    p_method: str | None = None
    ci_method: str | None = None

    def significant(self, alpha: float = 0.05) -> bool:
        """The adjusted p is below alpha and the interval excludes 0."""
        if self.p_adjusted is None or self.ci_low is None or self.ci_high is None:
            return False
        return self.p_adjusted < alpha and (self.ci_low > 0 or self.ci_high < 0)

    @property
    def direction(self) -> int:
        """-1 (the method lower), +1 (higher) or 0 (no difference or no pairs)."""
        if self.mean is None or self.mean == 0:
            return 0
        return -1 if self.mean < 0 else 1

    def describe(self, unit: str = "steps") -> str:
        """e.g. "-0.96 steps [-1.3, -0.6], p = 2e-05, adj. 0.003 (47/44/9)"."""
        if self.n == 0 or self.mean is None:
            return "no paired targets"
        if self.p_value is None:
            p = "p n/a"
        else:
            p = f"p = {self.p_value:.2g}, adj. {_fmt_p(self.p_adjusted)}"
        return (
            f"{self.mean:+.2f} {unit} [{self.ci_low:+.2f}, {self.ci_high:+.2f}], {p} "
            f"({self.wins}/{self.ties}/{self.losses})"
        )


def _fmt_p(p: float | None) -> str:
    return "n/a" if p is None else f"{p:.2g}"


def paired_difference(
    method: Sequence[float | None],
    reference: Sequence[float | None],
    *,
    resamples: int = 10_000,
    seed: int = 0,
) -> PairedDifference:
    """Compare two per-target series; None (e.g. did not converge) drops that target."""
    pairs = [
        (a, b) for a, b in zip(method, reference, strict=True) if a is not None and b is not None
    ]
    if not pairs:
        return PairedDifference(0, None, None, None, None, 0, 0, 0)
    d = np.array([a - b for a, b in pairs], dtype=float)
    low, high, ci_method = bootstrap_ci(d, resamples=resamples, seed=seed)
    p, p_method = wilcoxon_test(d)
    return PairedDifference(
        n=len(d),
        mean=float(d.mean()),
        ci_low=low,
        ci_high=high,
        p_value=p,
        wins=int(np.sum(d < 0)),
        ties=int(np.sum(d == 0)),
        losses=int(np.sum(d > 0)),
        p_adjusted=p,
        p_method=p_method,
        ci_method=ci_method,
    )


def bootstrap_ci(
    d: np.ndarray, *, resamples: int = 10_000, seed: int = 0, level: float = 0.95
) -> tuple[float, float, str]:
    """(low, high, method) of the mean of `d`: scipy's BCa bootstrap, seeded.

    All values equal: the point interval. BCa undefined (NaN bounds): the percentile interval.
    """
    from scipy.stats import bootstrap

    d = np.asarray(d, dtype=float)
    mean = float(d.mean())
    if len(d) < 2 or np.all(d == d[0]):
        return mean, mean, "point"
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # DegenerateDataWarning: handled by the fallback
            res = bootstrap(
                (d,),
                np.mean,
                confidence_level=level,
                n_resamples=resamples,
                method=method,
                vectorized=True,
                rng=np.random.Generator(np.random.PCG64(seed)),
            )
        low, high = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if np.isfinite(low) and np.isfinite(high):
            return low, high, method
    return mean, mean, "point"  # pragma: no cover - the percentile interval is always finite


#: Up to this many non-zero differences the signed-rank p is exact, ties or not (`_exact_p`).
EXACT_MAX_N = 400


def _exact_p(d: np.ndarray) -> float:
    """Two-sided p of the signed-rank statistic from its exact null distribution given the
    observed |d| (midranks for ties): each difference's sign is + or − with probability 1/2,
    so the distribution of twice the positive rank sum (doubled midranks are integers) is a
    subset-sum distribution, built by one convolution per difference. O(n³) for n values:
    ~1 ms at n = 100. Without ties it is the classical exact distribution (scipy's "exact")."""
    from scipy.stats import rankdata

    r2 = np.rint(2.0 * rankdata(np.abs(d))).astype(np.int64)  # doubled midranks
    total = int(r2.sum())
    dist = np.zeros(total + 1)
    dist[0] = 1.0
    for r in r2.tolist():
        dist[r:] = 0.5 * (dist[r:] + dist[: total + 1 - r])  # right to left: uses the old values
        dist[:r] *= 0.5
    w = int(r2[d > 0].sum())
    cdf = np.cumsum(dist)
    low = cdf[w]
    high = 1.0 - (cdf[w - 1] if w > 0 else 0.0)
    return float(min(1.0, 2.0 * min(low, high)))


def wilcoxon_test(differences: np.ndarray) -> tuple[float | None, str | None]:
    """(two-sided Wilcoxon signed-rank p, how it was computed) of paired differences.

    Zeros are dropped (zero_method "wilcox"); then, for up to `EXACT_MAX_N` non-zero values,
    the exact null distribution given the observed |d| (ties handled by midranks: exact, not an
    approximation, `_exact_p`), else the normal approximation (tie-corrected variance, no
    continuity correction). (None, None) below 6 non-zero values.
    """
    d = np.asarray(differences, dtype=float)
    d = d[d != 0]
    n = len(d)
    if n < MIN_NONZERO:
        return None, None
    if n <= EXACT_MAX_N:
        return _exact_p(d), "exact"
    from scipy.stats import wilcoxon

    res = wilcoxon(d, zero_method="wilcox", alternative="two-sided", method="asymptotic")
    return float(res.pvalue), "normal"


def holm(p_values: Sequence[float | None]) -> list[float | None]:
    """Holm's step-down adjusted p-values of one family (None: not a test, stays None).

    With the m p-values sorted, p_(1) <= ... <= p_(m): adj_(i) = max_{j <= i} min(1,
    (m - j + 1) p_(j)). Rejecting every test whose adjusted p is below alpha keeps the
    family-wise error rate at alpha under any dependence between the tests.
    """
    idx = [i for i, p in enumerate(p_values) if p is not None]
    m = len(idx)
    out: list[float | None] = [None] * len(p_values)
    running = 0.0
    for rank, i in enumerate(sorted(idx, key=lambda i: (p_values[i], i))):
        running = max(running, min(1.0, (m - rank) * float(p_values[i])))  # type: ignore[arg-type]
        out[i] = running
    return out


def adjust(family: Sequence[PairedDifference]) -> list[PairedDifference]:
    """The family with `p_adjusted` set by Holm's correction over all of its tests."""
    adjusted = holm([d.p_value for d in family])
    return [dataclasses.replace(d, p_adjusted=a) for d, a in zip(family, adjusted, strict=True)]
