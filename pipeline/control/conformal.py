"""The calibration's statistics (docs/calibration.md): the rank and the quantile of ``n``
exchangeable scores, and the status rule's counts.

With ``n`` exchangeable calibration flights and scores sorted ``s_(1) <= ... <= s_(n)``:

- split conformal (marginal): ``lambda_hat = s_(k)``, ``k = ceil((n + 1)(1 - alpha))``; a new
  flight of the same conditions satisfies ``P(lambda_hat)`` with probability at least
  ``1 - alpha`` (over the calibration draw and the new flight together); ``k > n`` means ``n``
  flights are too few for that ``alpha``;
- PAC (training-conditional): ``lambda_hat`` is the ``j``-th largest score with ``j`` the largest
  integer such that ``P[Bin(n, alpha) <= j - 1] <= delta``; with probability ``1 - delta`` over
  the calibration flights, a new flight breaks ``P(lambda_hat)`` with probability at most
  ``alpha``. ``j = 1`` (the maximum) needs ``(1 - alpha)^n <= delta``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

Method = Literal["conformal", "pac"]
MIN_FLIGHTS = 19
"""The fewest calibration flights behind a ``certified`` status (a 95 % marginal statement)."""
MAX_ALPHA = 0.1
"""The largest stated probability of breaking the premise behind a ``certified`` status."""


def conformal_rank(n: int, alpha: float) -> int:
    """``ceil((n + 1)(1 - alpha))``: the rank (1-based, ascending) of the split-conformal
    quantile; above ``n`` when ``n`` flights cannot support ``alpha``."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    # the small tolerance keeps (n + 1)(1 - alpha) integral where it is so in exact arithmetic
    return max(1, math.ceil((n + 1) * (1.0 - alpha) - 1e-9))


def pac_rank(n: int, alpha: float, delta: float) -> int:
    """The rank (1-based, ascending) of the PAC order statistic: ``n - j + 1`` for the largest
    ``j`` with ``P[Bin(n, alpha) <= j - 1] <= delta``; ``n + 1`` when even the maximum is not
    enough (``(1 - alpha)^n > delta``)."""
    from scipy.stats import binom

    if not (0.0 < alpha < 1.0 and 0.0 < delta < 1.0):
        raise ValueError(f"alpha and delta must lie in (0, 1), got {alpha}, {delta}")
    j = 0
    while j < n and float(binom.cdf(j, n, alpha)) <= delta:
        j += 1
    return n - j + 1


def calibration_rank(n: int, alpha: float, method: Method, delta: float = 0.05) -> int:
    """The rank of the calibrated score (:func:`conformal_rank` or :func:`pac_rank`)."""
    return conformal_rank(n, alpha) if method == "conformal" else pac_rank(n, alpha, delta)


def calibrated_quantile(
    scores: Sequence[float], alpha: float, method: Method, delta: float = 0.05
) -> float:
    """``lambda_hat``: the score at :func:`calibration_rank` (inf when the flights are too few)."""
    s = np.sort(np.asarray(scores, dtype=float))
    k = calibration_rank(len(s), alpha, method, delta)
    return float(s[k - 1]) if 1 <= k <= len(s) else math.inf


def smallest_flights(alpha: float, method: Method, delta: float = 0.05) -> int:
    """The fewest flights for which the calibrated score is finite at ``alpha``."""
    n = 1
    while calibration_rank(n, alpha, method, delta) > n:
        n += 1
    return n
