"""Paired-by-seed statistics of the paper's findings: arrays in, numbers out.

A flight's seed fixes the emulator's randomness, so the same seed flown by two controllers
gives a paired sample. For one finding, each seed ``i`` gives one effect ``d_i`` (a
difference between controllers, or the log of a ratio); over ``n`` seeds

    mean   d_bar = (1/n) sum_i d_i
    sd     s     = sqrt( sum_i (d_i - d_bar)^2 / (n - 1) )
    95% CI d_bar -/+ t_{n-1, 0.975} s / sqrt(n)      (Student's t on the paired effects)

A ratio ``a_i / b_i`` is tested on ``log(a_i / b_i)`` and reported back as the geometric
mean ratio ``exp(d_bar)`` with the interval ``[exp(lo), exp(hi)]`` (no effect: 1).

Verdict against the paper's direction (the effect it claims is above, or below, "no
effect"): ``reproduced`` when the interval excludes no effect on the paper's side,
``contradicted`` when it excludes it on the other side, ``inconclusive`` otherwise (also
with fewer than two seeds, where no interval exists).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats as sps

Direction = Literal["greater", "less"]
Verdict = Literal["reproduced", "contradicted", "inconclusive"]
LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    """A mean over seeds with its confidence interval (``nan`` bounds when ``n < 2``)."""

    mean: float
    lo: float
    hi: float
    n: int

    @property
    def ci(self) -> list[float | None]:
        """``[lo, hi]`` for JSON (``None`` where undefined)."""
        return [_finite_or_none(self.lo), _finite_or_none(self.hi)]


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def t_interval(x: ArrayLike, level: float = LEVEL) -> Interval:
    """``d_bar -/+ t_{n-1,(1+level)/2} s / sqrt(n)`` over the finite entries of ``x``."""
    a = np.asarray(x, dtype=float).ravel()
    a = a[np.isfinite(a)]
    n = len(a)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    mean = float(a.mean())
    if n < 2:
        return Interval(mean, math.nan, math.nan, n)
    half = float(sps.t.ppf(0.5 + level / 2, n - 1)) * float(a.std(ddof=1)) / math.sqrt(n)
    return Interval(mean, mean - half, mean + half, n)


def paired_difference(a: ArrayLike, b: ArrayLike, level: float = LEVEL) -> Interval:
    """Interval of the mean of ``a_i - b_i`` (paired samples; no effect: 0)."""
    return t_interval(np.asarray(a, dtype=float) - np.asarray(b, dtype=float), level)


def paired_ratio(a: ArrayLike, b: ArrayLike, level: float = LEVEL) -> Interval:
    """Geometric mean of ``a_i / b_i`` with ``exp`` of the t-interval of ``log(a_i / b_i)``
    (no effect: 1). Pairs with a non-positive member are dropped."""
    a_, b_ = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = (a_ > 0) & (b_ > 0)
    return ratio_interval(a_[ok] / b_[ok], level)


def ratio_interval(r: ArrayLike, level: float = LEVEL) -> Interval:
    """``exp`` of the t-interval of ``log r_i`` (per-seed ratios ``r_i > 0``; no effect: 1)."""
    r_ = np.asarray(r, dtype=float).ravel()
    r_ = r_[np.isfinite(r_) & (r_ > 0)]
    iv = t_interval(np.log(r_), level)
    return Interval(math.exp(iv.mean), math.exp(iv.lo), math.exp(iv.hi), iv.n)


def verdict(iv: Interval, null: float, direction: Direction) -> Verdict:
    """``reproduced`` if ``[lo, hi]`` excludes ``null`` on the paper's side (``direction``:
    the paper claims the effect is ``greater`` or ``less`` than ``null``), ``contradicted``
    if it excludes it on the other side, else ``inconclusive``."""
    if not (math.isfinite(iv.lo) and math.isfinite(iv.hi)):
        return "inconclusive"
    above, below = iv.lo > null, iv.hi < null
    if direction == "greater":
        return "reproduced" if above else "contradicted" if below else "inconclusive"
    return "reproduced" if below else "contradicted" if above else "inconclusive"


__all__ = [
    "LEVEL",
    "Direction",
    "Interval",
    "Verdict",
    "paired_difference",
    "paired_ratio",
    "ratio_interval",
    "t_interval",
    "verdict",
]
