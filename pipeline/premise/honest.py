"""The honest premise: fitted so that every training sample satisfies it (docs/guarantee.md).

The perception error of each measured channel splits into a dense and a sparse part,
``e = d + o`` with ``d = clip_beta(e)`` on the measured velocity channels (``o`` the rest, zero
on positions). The premise the generalized theorem rests on is

- (ii) dense: ``|d_k|_e = ||W_e d_k||_inf <= eps + S dist(x_k)`` whenever ``dist(x_k) <= r``,
  ``dist(x) = min_i ||W_x (x - x_i)||_inf`` over the training states;
- (i) sparse: at most ``m`` nonzero ``o_k`` in any ``T`` consecutive steps, each
  ``||o_k||_inf <= eps_o``.

On a training sample ``dist = 0``, so (ii) only says ``|d_k|_e <= eps``: ``eps`` is the
training maximum and the slope ``S`` can only be tested on data left out. ``S`` is the
leave-one-flight-out slope: for every flight ``f``, the smallest ``S_f >= 0`` with
``|d_k|_e <= eps_{-f} + S_f dist_{-f}(x_k)`` for all its samples within ``r`` of the other
flights (``eps_{-f}`` and ``dist_{-f}`` from the other flights alone); ``S = max_f S_f``. The
distances ``dist_{-f}(x_k)`` are where the premise was actually tested: their largest value
within ``r`` is the *tested range* a certificate prints beside ``rho*``.

The outlier count ``m`` is read from the binomial risk of a window of ``T`` steps holding more
than ``m`` outliers at the outlier rate's one-sided 95 % Clopper-Pearson upper bound, and is
never below the largest count seen in a training window. ``eps_o`` is never the sample
maximum: it is given (a physical bound) or follows from a velocity gate ``V``
(``eps_o = 2 V - beta``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qsls.pipeline.core.plant import GROUPS, VELOCITY, measured_channels


def outlier_channels(measure: str, beta: float) -> tuple[int, ...]:
    """Channels that may carry a sparse part: the measured velocities when ``beta`` is finite."""
    return VELOCITY if measure == "full" and math.isfinite(beta) else ()


def split_errors(
    e: np.ndarray, beta: float, measure: str = "full"
) -> tuple[np.ndarray, np.ndarray]:
    """``(d, o)`` with ``e = d + o`` on the measured channels: ``d = clip(e, -beta, beta)`` on the
    measured velocity channels, ``d = e`` on positions; unmeasured channels are zero in both."""
    e = np.asarray(e, dtype=float)
    d = np.zeros_like(e)
    o = np.zeros_like(e)
    ch = list(measured_channels(measure))
    d[:, ch] = e[:, ch]
    oc = list(outlier_channels(measure, beta))
    if oc:
        d[:, oc] = np.clip(e[:, oc], -beta, beta)
        o[:, oc] = e[:, oc] - d[:, oc]
    return d, o


def weighted_norm(v: np.ndarray, weights: Sequence[float]) -> np.ndarray:
    """``||W v_k||_inf`` for each row (``W = diag(weights)``)."""
    return np.abs(np.asarray(v, float) * np.asarray(weights, float)).max(axis=1)


def other_flight_distances(
    x: np.ndarray,
    flight: np.ndarray,
    state_scale: Sequence[float],
    environment: np.ndarray | None = None,
) -> np.ndarray:
    """``dist_{-f}(x_k) = min over samples i of other flights of ||W_x (x_k - x_i)||_inf``
    (inf with a single flight). With ``environment`` (a code per sample), only flights of the
    sample's own environment count: states of another room or frame are another state space,
    and no distance is taken across them (inf for a flight alone in its environment)."""
    from scipy.spatial import cKDTree

    w = np.asarray(state_scale, float)
    xs = np.asarray(x, float) * w
    env = np.zeros(len(xs), dtype=np.int64) if environment is None else np.asarray(environment)
    out = np.full(len(xs), np.inf)
    for f in np.unique(flight):
        mine = flight == f
        others = ~mine & (env == env[mine][0])
        if not others.any():
            continue
        d, _ = cKDTree(xs[others]).query(xs[mine], k=1, p=np.inf)
        out[mine] = d
    return out


@dataclass(frozen=True)
class SlopeFit:
    """The leave-one-flight-out slope and where it was tested."""

    S: float
    """``max_f S_f`` (inf where a left-out sample exceeds ``eps_{-f}`` at distance 0; NaN with
    fewer than two flights, or no two in one environment: nothing was left out)."""
    per_flight: tuple[float, ...]
    tested_range: float
    """Largest ``dist_{-f}(x_k)`` within ``r`` (0 when no sample is within ``r`` of another flight)."""
    n_tested: int
    """Samples within ``r`` of another flight (the ones that test ``S``)."""


def lofo_slope(
    dense: np.ndarray, flight: np.ndarray, dist_other: np.ndarray, radius: float
) -> SlopeFit:
    """Leave-one-flight-out ``S`` (module docstring) from ``dense = |d_k|_e``."""
    flights = np.unique(flight)
    if len(flights) < 2 or not np.isfinite(dist_other).any():  # nothing to leave out
        return SlopeFit(math.nan, (), 0.0, 0)
    within = dist_other <= radius
    per = []
    for f in flights:
        mine = flight == f
        eps_other = float(dense[~mine].max())
        use = mine & within
        excess = dense[use] - eps_other
        dist = dist_other[use]
        if not np.any(excess > 0):
            per.append(0.0)
            continue
        pos = excess > 0
        with np.errstate(divide="ignore"):
            per.append(float(np.max(excess[pos] / dist[pos])))
    tested = float(dist_other[within].max()) if within.any() else 0.0
    return SlopeFit(float(max(per)), tuple(per), tested, int(within.sum()))


def group_norms(
    d: np.ndarray, error_scale: Sequence[float], measure: str = "full"
) -> dict[str, np.ndarray]:
    """``|d_k,g|_e = max_{j in g} w_e,j |d_k,j|`` for each measured channel group ``g``: the
    weighted dense norm is their maximum, ``|d_k|_e = max_g |d_k,g|_e``."""
    measured = measured_channels(measure)
    out = {}
    for name, channels in GROUPS.items():
        ch = [c for c in channels if c in measured]
        if ch:
            out[name] = weighted_norm(np.asarray(d)[:, ch], [error_scale[c] for c in ch])
    return out


def grouped_slope(
    groups: dict[str, np.ndarray], flight: np.ndarray, dist_other: np.ndarray, radius: float
) -> tuple[SlopeFit, dict[str, SlopeFit]]:
    """Leave-one-flight-out ``S_g`` per channel group, and the slope of the whole dense norm
    they imply, ``S = max_g S_g`` (per flight ``S_f = max_g S_g,f``).

    Fitted on ``|d|_e`` itself, a group clipped at its level (velocities at ``w_e,v beta``)
    ties every fold's ``eps_{-f}`` and makes ``S_f = 0`` whatever the other group does; per
    group it cannot. ``S`` is sound for the scalar premise: a left-out sample meets
    ``|d_k|_e = max_g |d_k,g|_e <= max_g (eps_g,-f + S_g dist) <= eps_{-f} + S dist``."""
    per = {g: lofo_slope(v, flight, dist_other, radius) for g, v in groups.items()}
    fits = list(per.values())
    first = fits[0]
    if math.isnan(first.S):
        return first, per
    per_flight = tuple(float(v) for v in np.max([f.per_flight for f in fits], axis=0))
    combined = SlopeFit(max(f.S for f in fits), per_flight, first.tested_range, first.n_tested)
    return combined, per


def window_counts(nonzero: np.ndarray, flight: np.ndarray, window: int) -> np.ndarray:
    """For every sample ``k``, the count of nonzero entries in the ``window`` steps ending at
    ``k`` within its flight (fewer at a flight's start)."""
    nz = np.asarray(nonzero, dtype=np.int64)
    out = np.zeros(len(nz), dtype=np.int64)
    for f in np.unique(flight):
        idx = np.flatnonzero(flight == f)
        c = np.concatenate([[0], np.cumsum(nz[idx])])
        k = np.arange(1, len(idx) + 1)
        out[idx] = c[k] - c[np.maximum(k - window, 0)]
    return out


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided Clopper-Pearson interval of a binomial rate ``k / n`` at ``level``."""
    from scipy.stats import beta

    if n <= 0:
        return 0.0, 1.0
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def rate_upper(k: int, n: int, level: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound of the rate ``k / n`` at ``level``."""
    from scipy.stats import beta

    if n <= 0 or k >= n:
        return 1.0
    return float(beta.ppf(level, k + 1, n - k))


def window_exceed_prob(m: int, window: int, p: float) -> float:
    """``P(Binomial(window, p) > m)``: one window holding more than ``m`` outliers."""
    from scipy.stats import binom

    return float(binom.sf(m, window, p))


def choose_m(observed_max: int, window: int, p_upper: float, risk: float) -> int:
    """The smallest ``m >= observed_max`` with ``P(Binomial(window, p_upper) > m) <= risk``."""
    m = max(int(observed_max), 0)
    while m < window and window_exceed_prob(m, window, p_upper) > risk:
        m += 1
    return m


def flight_risk(m: int, window: int, p: float, steps: int) -> float:
    """Union bound on a flight of ``steps`` steps holding a window of more than ``m``
    outliers: ``min(1, (steps - window + 1) P(Binomial(window, p) > m))``."""
    n_windows = max(steps - window + 1, 1)
    return min(1.0, n_windows * window_exceed_prob(m, window, p))


@dataclass(frozen=True)
class OutlierFit:
    """The sparse part on the training data."""

    n_outliers: int
    n_samples: int
    rate: float
    rate_upper: float
    """One-sided 95 % Clopper-Pearson upper bound of the rate."""
    max_in_window: int
    m: int
    largest: float
    """Largest ``||o_k||_inf`` seen (descriptive only: never used as ``eps_o``)."""


def fit_outliers(o: np.ndarray, flight: np.ndarray, window: int, risk: float) -> OutlierFit:
    """Count, rate, its upper bound, the largest window count and ``m`` (:func:`choose_m`;
    with no outlier seen ``m`` may still be positive: the rate's upper bound is not zero)."""
    mag = np.abs(np.nan_to_num(o)).max(axis=1) if len(o) else np.zeros(0)
    nz = mag > 0
    k, n = int(nz.sum()), len(nz)
    counts = window_counts(nz, flight, window)
    mx = int(counts.max()) if len(counts) else 0
    up = rate_upper(k, n)
    return OutlierFit(
        n_outliers=k, n_samples=n, rate=k / n if n else 0.0, rate_upper=up, max_in_window=mx,
        m=choose_m(mx, window, up, risk), largest=float(mag.max()) if n else 0.0,
    )  # fmt: skip
