"""The calibrated premise: what a certificate promises for the next flight (docs/calibration.md).

A candidate controller has fixed taps and a nominal premise ``P = (eps, S, eps_w, Delta, m)``
fitted on design flights. Each calibration flight ``f``, flown by the candidate itself under
the stated conditions, gets a score ``lambda_f``: the smallest inflation of the premise that
the flight satisfies,

    lambda_f = max( max_k |d_k|_e / (eps + S dist(x_k))       over dist(x_k) <= r,
                    max_k ||H^-1 w_k||_inf / eps_w,
                    max_k dist(x_ref,k) / Delta,
                    max window count / m ),

so the flight satisfies ``P(lambda) = (lambda eps, lambda S, lambda eps_w, lambda Delta,
floor(lambda m))`` for every ``lambda >= lambda_f`` (the outlier magnitude is bounded by the gate,
``eps_o = 2V - beta``, and is not inflated). With ``n`` exchangeable calibration flights and
scores sorted ``s_(1) <= ... <= s_(n)``:

- split conformal (marginal): ``lambda_hat = s_(k)``, ``k = ceil((n + 1)(1 - alpha))``; a new
  flight of the same conditions satisfies ``P(lambda_hat)`` with probability at least
  ``1 - alpha`` (over the calibration draw and the new flight together); ``k > n`` means ``n``
  flights are too few for that ``alpha``;
- PAC (training-conditional): ``lambda_hat`` is the ``j``-th largest score with ``j`` the largest
  integer such that ``P[Bin(n, alpha) <= j - 1] <= delta``; with probability ``1 - delta`` over
  the calibration flights, a new flight breaks ``P(lambda_hat)`` with probability at most
  ``alpha``. ``j = 1`` (the maximum) needs ``(1 - alpha)^n <= delta``.

The certificate holds iff the fixed taps meet the robustness condition under ``P(lambda_hat)``
(:func:`qsls.pipeline.control.guarantee.guarantee` with ``G_m`` recomputed for the inflated
``m``, and the gate's ``rho_v <= V``). The tolerance of each premise quantity is the factor by
which it alone could grow before that condition fails.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from qsls.pipeline.control.guarantee import (
    Guarantee,
    Norms,
    PremiseNumbers,
    guarantee,
    sparse_gain,
    velocity_deviation,
)
from qsls.pipeline.errormodel.disturbance import ratio as ratio  # a score's parts read it
from qsls.pipeline.errormodel.honest import clopper_pearson as cp

Method = Literal["conformal", "pac"]
SCORED = ("dense", "disturbance", "reference", "outliers")
"""The premise quantities a flight's score inflates, in the order the score table lists them."""
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


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided Clopper-Pearson interval of ``k`` breaking flights out of ``n``."""
    return cp(k, n, level)


# --------------------------------------------------------------------------- scores
def set_by(rows: Sequence[Mapping[str, Any]], lambda_hat: float) -> str:
    """Which premise quantity set ``lambda_hat``: the largest part (:data:`SCORED`) of the
    flight whose score is ``lambda_hat`` (the quantile's flight; the first in ``rows`` on a
    tie), with its role, e.g. ``"reference (calibration flight)"``; ``''`` when no flight's
    score is ``lambda_hat`` (a hand-made record)."""
    for r in rows:
        score = float(r.get("score", math.nan))
        if math.isfinite(lambda_hat) and math.isclose(score, lambda_hat, rel_tol=1e-12):
            # a range flight's score leaves the reference's term out (its offset is the point)
            keys = [
                k for k in SCORED if k in r and not (k == "reference" and r.get("role") == "range")
            ]
            part = max(keys, key=lambda k: float(r[k]), default="")
            return f"{part} ({r.get('role', 'calibration')} flight)" if part else ""
    return ""


def outside_conditions(
    perception: str,
    flight_s: float,
    calibrated_perception: str,
    calibrated_s: float,
    estimator: str = "",
    calibrated_estimator: str = "",
) -> str:
    """Why a flight lies outside the conditions its certificate was calibrated under ('' when
    inside): another perception condition, another estimator (the camera loop against the VIO
    emulator: each errs its own way; ``''`` where not known), or a flight longer than the
    calibration flights (the promise ``P(lambda_hat)`` is about a new flight *of the same
    conditions*, and the premise's quantities grow with a flight's length:
    docs/calibration.md)."""
    why = []
    if calibrated_perception and perception != calibrated_perception:
        why.append(f"perception {perception}, calibrated in {calibrated_perception}")
    if estimator and calibrated_estimator and estimator != calibrated_estimator:
        why.append(f"estimator {estimator}, calibrated with {calibrated_estimator}")
    if flight_s > calibrated_s + 1e-6:
        why.append(f"a {flight_s:g} s flight, calibrated on {calibrated_s:g} s flights")
    return "; ".join(why)


def record_problems(
    *,
    flights: int,
    alpha: float,
    method: str,
    confidence: float | None,
    scores: Sequence[float],
    range_scores: Sequence[float],
    lambda_hat: float,
    holds: bool,
    rho_star: float | None,
    tested_range: float | None,
    shared_seeds: Sequence[int] = (),
) -> list[str]:
    """What keeps a recorded calibration from backing a ``certified`` status (empty when
    nothing does): at least :data:`MIN_FLIGHTS` flights, ``alpha <= MAX_ALPHA``, ``lambda_hat``
    at least the calibrated quantile of the recorded scores (and of the range flights'), the
    condition holding under it, the premise tested out to ``rho*``, and no calibration seed
    among the design flights' (``shared_seeds``). Read whenever a
    certificate is loaded, so a hand-edited record cannot claim what its flights do not."""
    why = []
    if flights < MIN_FLIGHTS or len(scores) != flights:
        why.append(f"{flights} calibration flights with {len(scores)} scores (needs {MIN_FLIGHTS})")
    if alpha > MAX_ALPHA:
        why.append(f"alpha {alpha:g} > {MAX_ALPHA:g}")
    m: Method = "pac" if method == "pac" else "conformal"
    # 1 - (1 - delta) may come back a hair below delta; never refuse on that rounding
    delta = 1.0 - confidence + 1e-12 if confidence is not None else 0.05
    lam = max(
        calibrated_quantile(scores, alpha, m, delta),
        calibrated_quantile(range_scores, alpha, m, delta) if len(range_scores) else 0.0,
    )
    if not lambda_hat >= lam * (1 - 1e-12):
        why.append(f"lambda_hat {lambda_hat:.6g} below its scores' quantile {lam:.6g}")
    if not holds:
        why.append("the condition fails under the calibrated premise")
    if rho_star is None or tested_range is None or tested_range < rho_star * (1 - 1e-9):
        why.append(f"tested to {tested_range} < rho* {rho_star}")
    if len(shared_seeds):
        why.append(f"calibration seeds {list(shared_seeds)[:5]} are design flights' seeds")
    return why


def flight_score(parts: dict[str, float]) -> float:
    """``lambda_f``: the largest of a flight's per-quantity ratios (module docstring)."""
    return max((float(parts[k]) for k in SCORED if k in parts), default=0.0)


# --------------------------------------------------------------------------- the condition
@dataclass(frozen=True)
class Responses:
    """What the condition needs of a controller's responses (``Phi_xy`` and ``Phi_xx H``)."""

    phi_xy: np.ndarray
    phi_xx_h: np.ndarray
    state_scale: tuple[float, ...]
    error_scale: tuple[float, ...]
    measured: tuple[int, ...]
    outlier: tuple[int, ...]
    norms: Norms
    """``N``, ``N_w``, ``G_b`` (``G_m`` is recomputed per ``m``)."""
    bias_dirs: np.ndarray | None = None
    """``D_w`` (:func:`qsls.pipeline.core.plant.bias_directions`), for the gate's ``g_b,i``."""


@dataclass(frozen=True)
class Check:
    """The robustness condition of a premise on fixed taps."""

    premise: PremiseNumbers
    guarantee: Guarantee
    G_m: float
    rho_v: float | None
    holds: bool


def inflate(p: PremiseNumbers, lam: float) -> PremiseNumbers:
    """``P(lambda)``: ``eps``, ``S``, ``eps_w``, ``eps_b``, ``Delta`` (and the paper's ``R0``, an
    error bound too) times ``lambda``, ``m -> floor(lambda m)``."""
    m = math.floor(lam * p.m + 1e-9) if math.isfinite(lam) else p.m
    R0 = None if p.R0 is None else p.R0 * lam
    return replace(
        p, eps=p.eps * lam, S=p.S * lam, eps_w=p.eps_w * lam, delta=p.delta * lam, m=m, R0=R0,
        eps_b=p.eps_b * lam,
    )  # fmt: skip


def check(p: PremiseNumbers, taps: Responses) -> Check:
    """The condition ``lhs <= 1``, ``rho* <= r`` and (with a gate) ``rho_v <= V`` under ``p``."""
    values = (p.eps, p.S, p.eps_w, p.delta)
    if not all(math.isfinite(v) for v in values):  # an infinite inflation: nothing holds
        inf = math.inf
        return Check(p, Guarantee(inf, -inf, inf, inf, inf, inf, inf), inf, None, False)
    gm = sparse_gain(taps.phi_xy, taps.state_scale, taps.outlier, p.m)
    norms = replace(taps.norms, G_m=gm)
    g = guarantee(p, norms)
    ok = g.robustness_lhs <= 1.0 and g.rho_star <= p.radius
    rho_v = None
    if p.gate is not None:
        rho_v = velocity_deviation(
            taps.phi_xy, taps.phi_xx_h, p, error_scale=taps.error_scale,
            measured=taps.measured, outlier_channels=taps.outlier, bias_dirs=taps.bias_dirs,
        )  # fmt: skip
        ok = ok and rho_v <= p.gate
    return Check(p, g, gm, rho_v, bool(ok))


Quantity = Literal["eps", "S", "eps_w", "delta", "m"]
QUANTITIES: tuple[Quantity, ...] = ("eps", "S", "eps_w", "delta", "m")


def tolerance(p: PremiseNumbers, taps: Responses, quantity: Quantity) -> float:
    """The factor by which ``quantity`` alone could grow before the condition fails (1 or less:
    it fails already; inf: it never fails from this quantity). ``m`` counts whole outliers:
    the largest ``m' / m`` that still holds (``m' >= m``); with ``m = 0``, ``m' + 1``."""
    base = check(p, taps)
    if not base.holds:
        return 0.0
    if quantity == "m":
        m = p.m
        while m < 10_000 and check(replace(p, m=m + 1), taps).holds:
            m += 1
            if m >= taps.phi_xy.shape[0]:
                return math.inf  # every tap may carry an outlier
        return m / p.m if p.m > 0 else float(m + 1)
    value = float(getattr(p, quantity))
    if value == 0.0:
        return math.inf

    def holds(f: float) -> bool:
        return check(_with(p, quantity, value * f), taps).holds

    return _largest(holds, 1.0)


def _with(p: PremiseNumbers, quantity: Quantity, value: float) -> PremiseNumbers:
    """``p`` with ``quantity`` (``eps``, ``S``, ``eps_w`` or ``delta``) set to ``value``."""
    g = {"eps": p.eps, "S": p.S, "eps_w": p.eps_w, "delta": p.delta} | {quantity: value}
    return replace(p, eps=g["eps"], S=g["S"], eps_w=g["eps_w"], delta=g["delta"])


def largest_value(p: PremiseNumbers, taps: Responses, quantity: Quantity) -> float:
    """The largest value ``quantity`` alone could take before the condition fails: what
    :func:`tolerance` cannot say of a quantity stated as 0 (its factor is inf, yet a small
    ``S`` may break the condition). 0 when the condition fails already."""
    if quantity == "m":
        raise ValueError("m counts whole outliers: tolerance() gives its largest count")
    if not check(p, taps).holds:
        return 0.0
    value = float(getattr(p, quantity))
    if value > 0.0:
        return value * tolerance(p, taps, quantity)

    def holds(v: float) -> bool:
        return check(_with(p, quantity, v), taps).holds

    lo = 1e-9
    return _largest(holds, lo) if holds(lo) else 0.0


def _largest(holds: Callable[[float], bool], lo: float) -> float:
    """The largest ``f >= lo`` with ``holds(f)`` (monotone: every quantity enters the condition
    with a non-negative coefficient), to 1e-6 relative."""
    hi = 2.0 * lo
    while holds(hi):
        lo, hi = hi, 2.0 * hi
        if hi > 1e12:
            return math.inf
    while hi - lo > 1e-6 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return lo
