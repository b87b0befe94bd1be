"""The paper's findings as the paper states them: the pieces, arrays in, numbers out.

- **Metrics over the circle with 1 s smoothing** (the paper's figures: "averaged with a time
  constant of 1 second"). A signal ``s_k`` sampled at ``t_k`` is smoothed by the first-order
  low-pass ``m_k = m_{k-1} + (1 - exp(-(t_k - t_{k-1}) / tau)) (s_k - m_{k-1})``, ``m_0 = s_0``,
  run over the whole flight (so the filter is warm when the circle starts) and read only on
  the circle, ``t_k >= t_circle`` (the reference's pattern start, after take-off and approach):
  ``RMS = sqrt(mean m_k^2)`` and ``max = max m_k`` there. The whole flight's unsmoothed
  metrics are reported beside them.
- **The paper's strict bound** ``R0 / (1 - S ||Phi_xe||)`` (paper, eq. of the perception error
  bound; ``Phi_xe`` is qsls's ``Phi_xy``) is defined only when ``S ||Phi_xe|| < 1``; otherwise
  the robustness condition fails and there is no bound (``None``). Whenever
  ``||Phi_xe|| >= 1 / 11.7`` (the report shows each controller's norm; on this plant it is
  above 1), the formula has no value at the paper's ``S = 11.7``: the paper's 1.602 cannot
  come from it at that ``S``.
- **The two-group contrast** of the paper's degraded-perception finding: "the L1 quadratic
  cost robust and nominal controllers performed significantly better than the PD and L1
  robust imitation cost controllers". Per seed ``i``, with ``A`` = {l1_robust, l1_nominal} and
  ``B`` = {pd, l1_robust_imitation} (those flown),

      log r_i = mean_{c in B} log e_i(c) - mean_{c in A} log e_i(c)

  (``e_i(c)``: controller ``c``'s perception error RMS on seed ``i``), the ratio of the groups'
  geometric means (> 1: the quadratic-cost group errs less), tested like every ratio
  (:mod:`qsls.pipeline.fly.stats`).
- **The replication split**: the seeds, sorted, are cut into two halves (the first
  ``floor(n / 2)`` and the rest); a finding reads ``reproduced`` (or ``contradicted``) only
  when both halves say so on their own, else ``inconclusive``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from qsls.pipeline.control import guarantee

SMOOTHING_TAU_S = 1.0
"""The paper's figures' smoothing time constant (s)."""
PAPER_S_SIM = 11.7
"""The S-slope the paper measured in simulation (and found infeasible)."""
PAPER_BOUND_SIM = 1.602
"""The bound the paper states for its simulation ("calculated using the true S-slope")."""
QUADRATIC = ("l1_robust", "l1_nominal")
TUNED_FOR_IDEAL = ("pd", "l1_robust_imitation")


def smooth(t: np.ndarray, s: np.ndarray, tau: float = SMOOTHING_TAU_S) -> np.ndarray:
    """The first-order low-pass of the module docstring (``tau`` in s; ``t`` increasing)."""
    t, s = np.asarray(t, dtype=float), np.asarray(s, dtype=float)
    out = np.empty_like(s)
    if len(s) == 0:
        return out
    alpha = 1.0 - np.exp(-np.diff(t, prepend=t[0]) / tau)
    m = s[0]
    for k in range(len(s)):
        m = m + alpha[k] * (s[k] - m)
        out[k] = m
    return out


def window_stats(
    t: np.ndarray, s: np.ndarray, start_s: float, tau: float = SMOOTHING_TAU_S
) -> tuple[float, float]:
    """``(RMS, max)`` of the smoothed signal over ``t >= start_s`` (``nan`` if empty)."""
    m = smooth(t, s, tau)[np.asarray(t, dtype=float) >= start_s]
    if len(m) == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(m**2))), float(m.max())


def circle_metrics(
    t: np.ndarray,
    track_err: np.ndarray,
    t_vio: np.ndarray,
    e_norm: np.ndarray,
    start_s: float,
    tau: float = SMOOTHING_TAU_S,
) -> dict[str, float]:
    """Tracking ``||p - p_ref||_2`` (at ``t``) and perception error ``||e||_inf`` (at
    ``t_vio``), each smoothed and read over the circle (module docstring)."""
    tr, tm = window_stats(t, track_err, start_s, tau)
    er, em = window_stats(t_vio, e_norm, start_s, tau)
    return {
        "tracking_rms_m_circle": tr,
        "tracking_max_m_circle": tm,
        "perception_error_rms_circle": er,
        "perception_error_max_circle": em,
    }


def strict_bound(R0: float, S: float, norm_phi_xe: float) -> float | None:
    """``R0 / (1 - S ||Phi_xe||)``, or ``None`` when ``S ||Phi_xe|| >= 1`` (no bound)."""
    g = guarantee.gamma_strict_of(R0, S, norm_phi_xe)
    return g if math.isfinite(g) else None


def two_group_contrast(piv: pd.DataFrame, better: Sequence[str], worse: Sequence[str]) -> pd.Series:
    """Per seed (rows of ``piv``, a seed x controller table of positive errors), the ratio of
    the geometric mean over ``worse`` to that over ``better`` (module docstring; seeds where a
    member is missing or not positive are dropped)."""
    a = [c for c in better if c in piv.columns]
    b = [c for c in worse if c in piv.columns]
    if not a or not b:
        return pd.Series(dtype=float)
    sub = piv[[*a, *b]]
    sub = sub[(sub > 0).all(axis=1) & np.isfinite(sub).all(axis=1)]
    logs = np.log(sub)
    return np.exp(logs[b].mean(axis=1) - logs[a].mean(axis=1))


def halves(seeds: Sequence[int]) -> tuple[list[int], list[int]]:
    """The sorted seeds cut in two: the first ``floor(n / 2)`` and the rest."""
    s = sorted({int(x) for x in seeds})
    k = len(s) // 2
    return s[:k], s[k:]


def replicated(first: str, second: str) -> str:
    """``reproduced`` / ``contradicted`` only when both halves say it, else ``inconclusive``."""
    if first == second and first in ("reproduced", "contradicted"):
        return first
    return "inconclusive"


__all__ = [
    "PAPER_BOUND_SIM",
    "PAPER_S_SIM",
    "QUADRATIC",
    "SMOOTHING_TAU_S",
    "TUNED_FOR_IDEAL",
    "circle_metrics",
    "halves",
    "replicated",
    "smooth",
    "strict_bound",
    "two_group_contrast",
    "window_stats",
]
