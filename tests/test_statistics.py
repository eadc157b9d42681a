"""Paired statistics: they find a real difference, not one in noise; Holm's correction gives the
hand-computed adjusted p; the interval is scipy's BCa; the signed-rank test says how it ran."""

from __future__ import annotations

import numpy as np
import pytest

from rodctl.statistics import paired_difference


def test_a_consistent_one_step_advantage_is_significant():
    rng = np.random.default_rng(0)
    ref = rng.integers(8, 20, size=100).astype(float)
    method = ref - 1 + rng.integers(-1, 2, size=100)  # mostly 1 step fewer
    d = paired_difference(list(method), list(ref))
    assert d.n == 100 and d.mean == pytest.approx(np.mean(method - ref))
    assert d.ci_high < 0 and d.p_value < 1e-6 and d.significant()
    assert d.wins > d.losses


def test_noise_alone_is_not_significant():
    rng = np.random.default_rng(1)
    ref = rng.integers(8, 20, size=100).astype(float)
    method = ref + rng.choice([-1.0, 0.0, 1.0], size=100)
    d = paired_difference(list(method), list(ref))
    assert d.ci_low < 0 < d.ci_high and not d.significant()


def test_unpaired_targets_are_dropped_and_tiny_samples_claim_nothing():
    d = paired_difference([10, None, 12, 9], [11, 10, None, 10])
    assert d.n == 2 and d.p_value is None and not d.significant()
    assert paired_difference([None], [1.0]).describe() == "no paired targets"


def test_holm_gives_the_hand_computed_adjusted_p_values():
    from rodctl.statistics import holm

    # Sorted: 0.005 x 4 = 0.02; 0.01 x 3 = 0.03; 0.03 x 2 = 0.06; 0.04 x 1 = 0.04 -> 0.06
    # (never below an earlier adjusted p); None is not a test and does not count in m.
    assert holm([0.01, 0.04, 0.03, None, 0.005]) == pytest.approx([0.03, 0.06, 0.06, None, 0.02])
    # Capped at 1; ties keep the same adjusted value.
    assert holm([0.5, 0.5, 0.001]) == pytest.approx([1.0, 1.0, 0.003])
    assert holm([]) == [] and holm([None]) == [None]


def test_significance_reads_the_adjusted_p_only():
    import dataclasses

    from rodctl.statistics import adjust

    # 10 wins and 2 losses of one step, 10 ties: exact p = 0.0386 (2^12 sign patterns).
    ref = [10.0] * 22
    method = [9.0] * 10 + [11.0] * 2 + [10.0] * 10
    alone = paired_difference(method, ref)
    assert alone.p_value == pytest.approx(0.03857421875) and alone.p_adjusted == alone.p_value
    assert alone.ci_high < 0 and alone.significant()  # a family of one
    # The same test among 199 others (all null): Holm multiplies the smallest p by 200.
    nulls = [dataclasses.replace(alone, p_value=0.5, p_adjusted=0.5)] * 199
    big = adjust([alone, *nulls])
    assert big[0].p_value == alone.p_value and big[0].p_adjusted == 1.0
    assert not big[0].significant() and big[0].ci_high < 0  # the raw interval is unchanged
    # Adjusted below alpha but the interval across 0: not significant either.
    odd = dataclasses.replace(alone, p_adjusted=0.01, ci_low=-0.5, ci_high=0.1)
    assert not odd.significant()


def test_the_interval_is_scipys_bca_bootstrap():
    from scipy.stats import bootstrap

    rng = np.random.default_rng(3)
    ref = rng.integers(8, 20, size=60).astype(float)
    method = ref + rng.integers(-3, 2, size=60)
    d = paired_difference(list(method), list(ref), resamples=2000, seed=7)
    res = bootstrap(
        (method - ref,),
        np.mean,
        method="BCa",
        n_resamples=2000,
        rng=np.random.Generator(np.random.PCG64(7)),
    )
    assert d.ci_method == "BCa"
    assert d.ci_low == pytest.approx(res.confidence_interval.low)
    assert d.ci_high == pytest.approx(res.confidence_interval.high)
    # A sample with no spread has the point interval, not NaN.
    flat = paired_difference([3.0] * 10, [2.0] * 10)
    assert (flat.ci_low, flat.ci_high, flat.ci_method) == (1.0, 1.0, "point")


def test_the_signed_rank_test_is_exact_when_it_can_be_and_says_so():
    from scipy.stats import rankdata, wilcoxon

    from rodctl.statistics import wilcoxon_test

    # 6 distinct positive differences: the exact two-sided p is 2 / 2^6.
    assert wilcoxon_test(np.array([1.0, 2, 3, 4, 5, 6])) == (pytest.approx(2 / 64), "exact")
    # Zeros are dropped before anything else: the same p with zeros added.
    assert wilcoxon_test(np.array([0.0, 1, 2, 0, 3, 4, 5, 6]))[0] == pytest.approx(2 / 64)
    # Tied |d|: still exact; all 7 of the same sign: 2 / 2^7.
    assert wilcoxon_test(np.array([1.0, 1, 1, 1, 2, 2, 2])) == (pytest.approx(2 / 128), "exact")
    # 14 equal |d|, 11 positive: the rank sum is 7.5 x (number positive), so P = P(Bin(14, 1/2)
    # >= 11) x 2 = 2 x 470 / 2^14 = 0.0574; the normal approximation said 0.0325 (significant).
    d = np.array([1.0] * 11 + [-1.0] * 3)
    assert wilcoxon_test(d) == (pytest.approx(2 * 470 / 2**14, rel=1e-12), "exact")
    assert wilcoxon(d, method="asymptotic").pvalue < 0.05 < wilcoxon_test(d)[0]
    # Ties against every one of the 2^n sign patterns, counted out.
    rng = np.random.default_rng(3)
    for _ in range(10):
        d = rng.choice([-3.0, -2.0, -1.0, 1.0, 2.0, 3.0], size=int(rng.integers(6, 12)))
        r = rankdata(np.abs(d))
        w = r[d > 0].sum()
        signs = ((np.arange(2 ** len(d))[:, None] >> np.arange(len(d))) & 1).astype(bool)
        sums = (signs * r).sum(axis=1)
        want = min(1.0, 2 * min((sums <= w + 1e-9).mean(), (sums >= w - 1e-9).mean()))
        assert wilcoxon_test(d)[0] == pytest.approx(want, rel=1e-12)
    # Past EXACT_MAX_N: the normal approximation with the tie correction (scipy's asymptotic).
    d = np.repeat([-1.0, 1.0, 2.0], [150, 200, 60])
    p, how = wilcoxon_test(d)
    assert how == "normal"
    assert p == pytest.approx(wilcoxon(d, method="asymptotic").pvalue)
    assert wilcoxon_test(np.array([1.0, 2, 3, 4, 5, 0, 0])) == (None, None)  # 5 non-zero
