"""Paired-by-seed statistics (pipeline/fly/stats.py): intervals against hand-computed
values and every verdict reached from constructed paired samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qsls.pipeline.fly.stats import (
    Interval,
    paired_difference,
    paired_ratio,
    t_interval,
    verdict,
)


def test_t_interval_matches_hand_computation():
    # d = [1, 2, 3, 4, 5]: mean 3, s = sqrt(2.5), t_{4, 0.975} = 2.776445105
    iv = t_interval([1, 2, 3, 4, 5])
    half = 2.7764451051977987 * math.sqrt(2.5) / math.sqrt(5)
    assert iv.n == 5 and iv.mean == pytest.approx(3.0)
    assert (iv.lo, iv.hi) == pytest.approx((3 - half, 3 + half), rel=1e-12)
    assert iv.ci == pytest.approx([3 - half, 3 + half])
    # nan entries are dropped; one sample has no interval
    one = t_interval([2.0, math.nan])
    assert one.n == 1 and one.mean == 2.0 and one.ci == [None, None]
    assert t_interval([]).n == 0


def test_paired_difference_uses_pairs_not_groups():
    # large spread between seeds, constant paired difference 0.1 +- 0.01: a narrow interval
    # around 0.1 although the two groups overlap completely
    rng = np.random.default_rng(0)
    base = rng.uniform(1, 10, 12)
    a = base + 0.1 + rng.normal(0, 0.01, 12)
    iv = paired_difference(a, base)
    assert 0.09 < iv.lo < 0.1 < iv.hi < 0.11
    assert verdict(iv, 0.0, "greater") == "reproduced"


def test_paired_ratio_is_geometric_mean_with_exp_interval():
    a = np.array([2.0, 4.0, 8.0])
    b = np.array([1.0, 1.0, 2.0])  # ratios 2, 4, 4
    iv = paired_ratio(a, b)
    logs = np.log([2.0, 4.0, 4.0])
    ref = t_interval(logs)
    assert iv.mean == pytest.approx(math.exp(logs.mean()))
    assert (iv.lo, iv.hi) == pytest.approx((math.exp(ref.lo), math.exp(ref.hi)))
    assert iv.lo < iv.mean < iv.hi


@pytest.mark.parametrize(
    ("samples", "null", "direction", "want"),
    [
        ([0.9, 1.1, 1.0, 0.95, 1.05], 0.0, "greater", "reproduced"),
        ([0.9, 1.1, 1.0, 0.95, 1.05], 0.0, "less", "contradicted"),
        ([-0.9, -1.1, -1.0, -0.95, -1.05], 0.0, "less", "reproduced"),
        ([-0.9, -1.1, -1.0, -0.95, -1.05], 0.0, "greater", "contradicted"),
        ([-1.0, 1.0, -0.5, 0.5, 0.1], 0.0, "greater", "inconclusive"),
        ([-1.0, 1.0, -0.5, 0.5, 0.1], 0.0, "less", "inconclusive"),
        ([3.0], 0.0, "greater", "inconclusive"),  # one seed: no interval
    ],
)
def test_verdict_follows_from_the_interval(samples, null, direction, want):
    iv = t_interval(samples)
    assert verdict(iv, null, direction) == want
    # and the same verdict from the interval alone
    lo, hi = iv.ci
    if want == "reproduced":
        assert (lo > null) if direction == "greater" else (hi < null)
    elif want == "contradicted":
        assert (hi < null) if direction == "greater" else (lo > null)


def test_verdict_on_ratios_against_one():
    assert verdict(Interval(0.5, 0.4, 0.6, 10), 1.0, "less") == "reproduced"
    assert verdict(Interval(2.5, 2.2, 3.3, 10), 1.0, "less") == "contradicted"
    assert verdict(Interval(1.0, 0.8, 1.2, 10), 1.0, "less") == "inconclusive"
    # an interval touching no-effect does not exclude it
    assert verdict(Interval(1.1, 1.0, 1.2, 10), 1.0, "greater") == "inconclusive"
