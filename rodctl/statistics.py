"""Paired comparisons of two methods over shared targets: a bootstrap CI and a signed-rank test.

Why paired: every method runs the same targets from the same start, so the difference on each
target removes the target's own difficulty, which dominates the spread of raw step counts. The
mean paired difference gets a percentile-bootstrap 95 % confidence interval (seeded, so a report
is reproducible) and a Wilcoxon signed-rank p-value (scipy; zero differences are ties that
carry no evidence either way, the "wilcox" zero method drops them). With fewer than 6 non-zero
differences no p-value below 0.05 is possible, and none is claimed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PairedDifference:
    """method - reference over the targets both have a value on.

    Attributes:
        n: number of paired targets.
        mean: mean difference (negative: the method needs fewer / less).
        ci_low, ci_high: bootstrap 95 % interval of the mean.
        p_value: Wilcoxon signed-rank p (two-sided), None when it cannot be computed.
        wins, ties, losses: targets where the method is lower, equal, higher.
    """

    n: int
    mean: float | None
    ci_low: float | None
    ci_high: float | None
    p_value: float | None
    wins: int
    ties: int
    losses: int

    def significant(self, alpha: float = 0.05) -> bool:
        """Both tests agree the difference is not zero."""
        if self.p_value is None or self.ci_low is None or self.ci_high is None:
            return False
        return self.p_value < alpha and (self.ci_low > 0 or self.ci_high < 0)

    def describe(self, unit: str = "steps") -> str:
        """e.g. "-0.96 steps [-1.3, -0.6], p = 2e-05 (47/44/9)"."""
        if self.n == 0 or self.mean is None:
            return "no paired targets"
        p = "p n/a" if self.p_value is None else f"p = {self.p_value:.2g}"
        return (
            f"{self.mean:+.2f} {unit} [{self.ci_low:+.2f}, {self.ci_high:+.2f}], {p} "
            f"({self.wins}/{self.ties}/{self.losses})"
        )


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
    rng = np.random.Generator(np.random.PCG64(seed))
    boots = d[rng.integers(0, len(d), size=(resamples, len(d)))].mean(axis=1)
    low, high = np.percentile(boots, [2.5, 97.5])
    return PairedDifference(
        n=len(d),
        mean=float(d.mean()),
        ci_low=float(low),
        ci_high=float(high),
        p_value=wilcoxon_p(d),
        wins=int(np.sum(d < 0)),
        ties=int(np.sum(d == 0)),
        losses=int(np.sum(d > 0)),
    )


def wilcoxon_p(differences: np.ndarray) -> float | None:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (zeros dropped)."""
    from scipy.stats import wilcoxon

    d = np.asarray(differences, dtype=float)
    if np.count_nonzero(d) < 6:
        return None
    return float(wilcoxon(d, zero_method="wilcox", alternative="two-sided").pvalue)
